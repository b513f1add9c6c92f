"""The walking recovery's late sideways pushes (`walk_recovery.late_push`,
`WalkCommand.recovery_late_swing_gain`, `[walk] recovery_late_swing_gain`).

A push whose sideways deviation, when it first passes its band, points inward for the swing
foot of the step that would take the offset (pushed left while the right foot swings) is late:
that step takes none, the other foot's next step does, and its swing foot moves by the gain x
its half of the offset (1: centred, 0: the support foot alone). Checked on a warmed recovery
state (every phase bin learned, the gait's capture point 0) and hand-made gait states, without
a rollout.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.control.gait import GaitState, WalkCommand, move_footstep
from tkujax.control.walk_recovery import (WARM_VISITS, RecoveryState, late_push,
                                          move_footsteps, recovery_update)
from tkujax.dialects.validation import SpecError
from tkujax.dialects.walk_table import parse_walk, resolve_walk
from tkujax.walking.walk_push import outward_step

PARAMS = dataclasses.replace(ControllerParams.paper(), lateral_steps=1.0)
PERIOD = float(PARAMS.control_period)


def _command(gain=None):
    extra = {} if gain is None else dict(recovery_late_swing_gain=gain)
    return WalkCommand.for_params(PARAMS, 0.1, recovery=1.0, **extra)


def _gait(swing_left, start_s):
    """A step of the walk at 0.1 m/s whose swing foot is the left one (1) or the right (0)."""
    d = 0.5 * 0.1 * float(PARAMS.step_period)
    swing, support = [d, 0.0], [-d, 0.0]
    to = support + swing if swing_left else swing + support
    return GaitState(count=jnp.asarray(20.0), start_s=jnp.asarray(start_s),
                     swing_left=jnp.asarray(float(swing_left)), feet_from=jnp.zeros(4),
                     feet_to=jnp.asarray(to, jnp.float32), yaw_from=jnp.zeros(2),
                     yaw_to=jnp.zeros(2), lead_s=jnp.asarray(0.0))


def _pushed(xi_y, time_s, command, state=None):
    """The warmed recovery state after one period with the capture point xi_y (m) sideways."""
    if state is None:
        state = dataclasses.replace(RecoveryState.init(),
                                    seen=jnp.full_like(RecoveryState.init().seen, WARM_VISITS))
    state, _ = recovery_update(state, jnp.asarray([0.0, xi_y], jnp.float32), time_s, command,
                               PARAMS, on=1.0, steady=True)
    assert float(state.armed) == 1.0
    return state


@pytest.mark.parametrize("pending_y, swing_left, in_reach, late", [
    (0.03, 0.0, True, 1.0),     # pushed left, the right foot swings: late
    (0.03, 1.0, True, 0.0),     # pushed left, the left foot swings: it steps outward
    (0.03, 0.0, False, 0.0),    # the right foot lands: the left foot's next step takes it
    (0.03, 1.0, False, 1.0),    # the left foot lands: the right foot's next step cannot
    (-0.03, 1.0, True, 1.0),    # pushed right, the left foot swings: late
    (-0.03, 0.0, True, 0.0),
])
def test_the_rule_given_the_swing_foot_and_the_side(pending_y, swing_left, in_reach, late):
    assert float(late_push(jnp.asarray(pending_y), jnp.asarray(swing_left),
                           jnp.asarray(in_reach))) == late


def _late_walk(gain):
    """Pushed left (capture point 3 cm left) in mid-swing of the right foot; that step, then
    the left foot's next one. Returns (the right step's gait, state; the left step's)."""
    command = _command(gain)
    step = float(PARAMS.step_period)
    state = _pushed(0.03, 10.1, command)
    right = _gait(0.0, 10.0)
    state, right_after, _ = move_footsteps(state, right, jnp.asarray(False), 10.1, command,
                                           PERIOD)
    # The left foot's step starts; the deviation still holds.
    state = _pushed(0.03, 10.0 + step, command, state)
    left = _gait(1.0, 10.0 + step)
    state, left_after, moved = move_footsteps(state, left, jnp.asarray(True), 10.0 + step,
                                              command, PERIOD)
    assert bool(moved)
    return right, right_after, left, left_after, state


@pytest.mark.parametrize("gain", [0.0, 0.5, 1.0])
def test_a_late_push_moves_the_swing_foot_by_the_gain(gain):
    right, right_after, left, left_after, state = _late_walk(gain)
    assert float(state.late) == 1.0 and float(state.side_open) == 0.0
    # The right foot cannot step left: its step takes no sideways offset.
    np.testing.assert_array_equal(np.asarray(right_after.feet_to)[[1, 3]],
                                  np.asarray(right.feet_to)[[1, 3]])
    # The left foot's step: the swing foot gain x half, the support foot the whole half back.
    y = float(state.applied[1])
    assert y > 0.01
    moved = np.asarray(left_after.feet_to) - np.asarray(left.feet_to)
    np.testing.assert_allclose(moved[[1, 3]], [-0.5 * y, gain * 0.5 * y], atol=1e-7)


def test_gain_one_is_the_centred_step_bit_for_bit():
    _, _, left, left_after, state = _late_walk(1.0)
    centred = move_footstep(left, state.applied)
    assert np.asarray(left_after.feet_to).tobytes() == np.asarray(centred.feet_to).tobytes()
    _, _, _, default_after, _ = _late_walk(None)
    assert (np.asarray(default_after.feet_to).tobytes()
            == np.asarray(left_after.feet_to).tobytes())


def test_an_outward_push_is_centred_whatever_the_gain():
    """Pushed left while the left foot swings: not late, its step centred with gain 0."""
    command = _command(0.0)
    state = _pushed(0.03, 10.1, command)
    left = _gait(1.0, 10.0)
    state, after, moved = move_footsteps(state, left, jnp.asarray(False), 10.1, command, PERIOD)
    assert bool(moved) and float(state.late) == 0.0
    y = float(state.applied[1])
    moved_y = np.asarray(after.feet_to)[[1, 3]] - np.asarray(left.feet_to)[[1, 3]]
    np.testing.assert_allclose(moved_y, [-0.5 * y, 0.5 * y], atol=1e-7)


def test_the_next_push_starts_undecided():
    """After the recovery is quiet (QUIET_CYCLES without a trigger) a new push's first trigger
    clears `late` and opens its side again."""
    _, _, _, _, state = _late_walk(0.0)
    later = float(state.quiet_until_s) + 1.0
    state = _pushed(0.03, later, _command(0.0), state)
    assert float(state.late) == 0.0 and float(state.side_open) == 1.0


def test_without_sideways_steps_no_push_is_late():
    params = dataclasses.replace(PARAMS, lateral_steps=0.0)
    command = _command(0.0)
    state = dataclasses.replace(RecoveryState.init(),
                                seen=jnp.full_like(RecoveryState.init().seen, WARM_VISITS))
    state, _ = recovery_update(state, jnp.asarray([0.03, 0.03], jnp.float32), 10.1, command,
                               params, on=1.0, steady=True)
    assert float(state.side_now) == 0.0
    state, _, _ = move_footsteps(state, _gait(0.0, 10.0), jnp.asarray(False), 10.1, command,
                                 PERIOD)
    assert float(state.late) == 0.0


def test_the_walk_table_key_is_checked_and_reaches_the_command():
    assert parse_walk({"walk": {"recovery_late_swing_gain": 0}}).recovery_late_swing_gain == 0.0
    assert parse_walk({"walk": {}}).recovery_late_swing_gain is None   # the robot's, else 1
    with pytest.raises(SpecError, match=r"walk\.recovery_late_swing_gain: 1\.5 is out of "
                                        r"range \[0\.0, 1\.0\]"):
        parse_walk({"walk": {"recovery_late_swing_gain": 1.5}})
    with pytest.raises(ValueError, match="recovery_late_swing_gain"):
        _command(-0.1).validate()
    # recovery_hurry, the step's timing, likewise (resolve_walk carries it into the command)
    walk = parse_walk({"walk": {"recovery_hurry": 0.2}})
    assert resolve_walk(walk, ControllerParams.paper()).command().recovery_hurry == 0.2
    with pytest.raises(SpecError, match=r"walk\.recovery_hurry: 0\.9 is out of range"):
        parse_walk({"walk": {"recovery_hurry": 0.9}})


def test_the_push_sets_split_sideways_pushes_by_the_step_they_arrive_in():
    """`walk_push.outward_step`: a push from the right (90 deg, pushing left) in the right
    foot's step (gait phases gamma / 4 to gamma / 4 + 1/2) arrives in the other foot's step."""
    command = _command()
    az = [90.0, 90.0, 270.0, 270.0, 45.0, 0.0, 180.0]
    phase = [0.25, 0.75, 0.25, 0.75, 0.02, 0.25, 0.75]
    np.testing.assert_array_equal(outward_step(az, phase, command), [0, 1, 1, 0, 1, -1, -1])
