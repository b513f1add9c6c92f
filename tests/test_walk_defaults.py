"""A robot file's gait defaults from its stand (tkujax.robot.walk_defaults, docs/walking.md): the
waist's shift that centres the CoM over the support polygon and the lift's cap, against closed
forms; the gait's feet with the shift; Booster T1 (31.6 kg) stepping in place 6 s with them and
falling without them (MuJoCo C; skips without the shared model)."""

from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.control.gait import WalkCommand, advance, gait_feet, gait_init, shift_ramp
from tkujax.robot.walk_defaults import LIFT_TOL_M, WALK_LIFT_MAX_M, walk_defaults
from tkujax.walking.walk import run_walk, walker

ROOT = Path(__file__).resolve().parent.parent
T1_FILE = ROOT / "specs/robots/t1.toml"
T1_MODEL = ROOT.parent / "shared/models/booster_t1"
PARAMS = ControllerParams.paper()


def test_the_shift_centres_the_com_and_the_lift_is_capped():
    margins = dict(front_m=0.084, back_m=0.139, left_m=0.15, right_m=0.15, least_m=0.084)
    tall = ControllerParams(lift_height=0.07)
    assert dict(walk_defaults(margins, tall)) == {"lift_m": WALK_LIFT_MAX_M,
                                                  "com_shift_m": pytest.approx(-0.0275)}
    # A lift at the cap to within LIFT_TOL_M stays; no polygon, no shift.
    near = ControllerParams(lift_height=WALK_LIFT_MAX_M + 0.5 * LIFT_TOL_M)
    assert walk_defaults(None, near) == ()
    # The shift stays inside WalkCommand's range.
    far = dict(margins, front_m=0.5, back_m=0.01)
    assert dict(walk_defaults(far, near))["com_shift_m"] == 0.1


def test_the_shift_moves_both_feet_back_as_it_ramps_in():
    """With com_shift_m s the feet's x are the gait's minus s x the ramp (0 at start_s, 1 after
    (ramp_steps + 1) T); y and z unchanged; s = 0 changes nothing, bit for bit."""
    plain = WalkCommand.for_params(PARAMS, 0.1)
    shifted = WalkCommand.for_params(PARAMS, 0.1, com_shift_m=0.02)
    state = gait_init(plain)
    for t in (0.1, 0.5, 0.9, 3.0):
        state, _ = advance(state, t, plain)
        base = np.asarray(gait_feet(state, t, plain, PARAMS))
        moved = np.asarray(gait_feet(state, t, shifted, PARAMS))
        ramp = float(shift_ramp(jnp.float32(t), plain))
        assert ramp == pytest.approx(np.clip((t - 0.3) / (5 * 0.3), 0.0, 1.0), abs=1e-6)
        np.testing.assert_allclose(moved[:, 0], base[:, 0] - 0.02 * ramp, atol=1e-7)
        np.testing.assert_array_equal(moved[:, 1:], base[:, 1:])
        zero = WalkCommand.for_params(PARAMS, 0.1, com_shift_m=0.0)
        np.testing.assert_array_equal(np.asarray(gait_feet(state, t, zero, PARAMS)), base)


@pytest.mark.skipif(not T1_MODEL.is_dir(), reason="the shared Booster T1 model is absent")
def test_t1_steps_in_place_with_its_defaults_and_falls_without(monkeypatch):
    """T1 in place for 6 s: with its defaults (the waist 2.8 cm back, a 3 cm lift) it stands and
    its feet leave the floor; with the scaled gait (7 cm lift, no shift) it falls."""
    monkeypatch.setenv("TKUJAX_MENAGERIE", str(T1_MODEL.parent))
    who = walker(str(T1_FILE))
    assert who.gait["com_shift_m"] < -0.01 and who.gait["lift_m"] == WALK_LIFT_MAX_M
    with_defaults = WalkCommand.for_params(who.gait_params, 0.0, **who.gait)
    scaled = WalkCommand.for_params(who.gait_params, 0.0)
    series, outcomes = run_walk(who, [with_defaults, scaled], 6.0, "mujoco")
    fell = np.asarray(outcomes.fell, bool)
    assert not fell[0] and fell[1]
    lift = np.asarray(series.l_ankle[0])[:, 2]
    assert lift.max() - lift[0] > 0.005
