"""The recovery step's direction on a robot file: the chain IMU -> estimated lean -> step target
(x_Sup, y_Sup) -> leg map -> swing ankle keeps its signs, so a push from behind makes the robot
step forward and a push from the right (toward +y) makes it step left.

The paper's estimator fuses the accelerometer's angle, which reads the push's own acceleration
as a lean the other way: on a light robot without an accelerometer low-pass the first sample
after a 20 ms push fires the detector on the wrong side, and the latched step goes away from
the capture point (OP3 at 0.8 N s from behind: x_Sup = -10.9 cm). That is the estimator, not
the signs, so the direction is checked with `accel_gate` on (the accelerometer's weight drops
while |a| departs from g) and the wrong-side first detection is pinned with it off.

The generated second robot runs everywhere; OP3 when a Menagerie checkout is found."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import RECOMMENDED
from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.robot.robot_setup import robot_setup
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push
from tkujax.sim.rollout_mujoco import simulate_mujoco

from test_robot_file import REPO, needs_op3

AZIMUTHS_DEG = (0.0, 90.0, 180.0, 270.0)     # from behind, from the right, front, left
ONSET_S = 0.5


@pytest.fixture(scope="module")
def second(tmp_path_factory):
    return robot_setup(write_generated_robot(tmp_path_factory.mktemp("second"), GENERATED_SECOND,
                                             name="second", keyframe=False))


def _run(robot, impulse_ns: float, accel_gate_ms2: float):
    """(series, outcomes) of one push per azimuth, lateral steps on, MuJoCo C."""
    n = len(AZIMUTHS_DEG)
    f = lambda v: jnp.asarray(np.broadcast_to(v, (n,)), jnp.float32)  # noqa: E731
    pushes = Push(impulse_ns=f(impulse_ns), azimuth_rad=f(np.radians(AZIMUTHS_DEG)),
                  height_m=f(robot.defaults.com_height), duration_s=f(0.02), onset_s=f(ONSET_S))
    params = dataclasses.replace(robot.defaults, lateral_steps=1.0, accel_gate=accel_gate_ms2)
    return simulate_mujoco(pushes, np.ones(n), params, robot=robot,
                           config=RolloutConfig(duration_s=1.2))


def _swing_ankle_step_m(series, i: int, period_s: float) -> np.ndarray:
    """(x, y) of the swing ankle one step period after the trigger, against its place before the
    push (m); the swing foot is the left one when y_Sup >= 0, as the controller chooses."""
    t = series.t[i]
    k0 = int(np.argmax(series.step_weight[i] > 0.5))
    k1 = min(int(np.searchsorted(t, t[k0] + period_s)), t.size - 1)
    before = int(np.searchsorted(t, ONSET_S)) - 1
    ankle = series.l_ankle if series.y_sup[i, -1] >= 0.0 else series.r_ankle
    return np.asarray(ankle[i, k1, :2] - ankle[i, before, :2])


def _check_directions(robot, impulse_ns: float) -> None:
    series, _ = _run(robot, impulse_ns, RECOMMENDED["accel_gate"])
    assert (series.step_weight[:, -1] > 0.5).all()          # every push makes it step
    x_sup, y_sup = series.x_sup[:, -1], series.y_sup[:, -1]
    steps = np.array([_swing_ankle_step_m(series, i, robot.defaults.step_period)
                      for i in range(len(AZIMUTHS_DEG))])
    behind, right, front, left = range(4)
    # The targets are cm long; the ankle's world displacement is smaller sideways (the stance
    # foot and the body move too), so only its sign is asked for, beyond 5 mm.
    assert x_sup[behind] > 0.02 and steps[behind, 0] > 0.005
    assert x_sup[front] < -0.02 and steps[front, 0] < -0.005
    assert y_sup[right] > 0.02 and steps[right, 1] > 0.005
    assert y_sup[left] < -0.02 and steps[left, 1] < -0.005


def test_second_steps_toward_the_push(second):
    _check_directions(second, 2.0)


@needs_op3
def test_op3_steps_toward_the_push():
    _check_directions(robot_setup(REPO / "specs" / "robots" / "op3.toml"), 1.2)


def test_paper_estimator_reads_the_push_as_a_lean_the_other_way(second):
    """With accel_gate off (the paper's filter) and no accelerometer low-pass, a push from
    behind fires the detector on the first tick after it with the estimated pitch backward
    while the body leans forward: the latched step goes backward. If this starts failing, the
    estimator changed (then update docs/robots.md)."""
    series, _ = _run(second, 2.0, 0.0)
    k0 = int(np.argmax(series.step_weight[0] > 0.5))
    assert series.t[0, k0] < ONSET_S + 0.05
    assert series.pitch_est[0, k0] < series.pitch_est[0, 0] < series.pitch[0, k0]
    assert series.x_sup[0, -1] < 0.0
