"""`[solver]` in a robot file (tkujax.robot.description, applied by tkujax.robot.loader): caps on
the constraint solver's iterations and line-search iterations.

On a generated robot: the caps reach the compiled model, a file without them keeps the model's
own, and bad values are refused naming the key and its range. On OP3 (skipped without the
shared models): MuJoCo C's Newton solver converges within caps of 10 and 20 on a kicked stand, so
those caps change nothing there, while caps that bind (1 and 1) change the motion.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.robot.description import RobotFileError, load_description
from tkujax.robot.loader import load_robot

from test_robot_file import REPO, needs_op3


def _with_solver(tmp_path, table: str):
    toml = write_generated_robot(tmp_path, GENERATED_SECOND, name="solver", keyframe=False)
    toml.write_text(toml.read_text() + "\n[solver]\n" + table + "\n")
    return toml


def test_the_solver_caps_reach_the_model(tmp_path):
    plain = load_robot(write_generated_robot(tmp_path / "a", GENERATED_SECOND, name="plain",
                                             keyframe=False))
    capped = load_robot(_with_solver(tmp_path / "b", "iterations = 3\nls_iterations = 5"))
    raw = mujoco.MjModel.from_xml_path(str(plain.description.mjcf_path))
    assert (plain.model.opt.iterations, plain.model.opt.ls_iterations) == \
        (raw.opt.iterations, raw.opt.ls_iterations)
    assert (capped.model.opt.iterations, capped.model.opt.ls_iterations) == (3, 5)
    only = load_robot(_with_solver(tmp_path / "c", "ls_iterations = 7"))
    assert (only.model.opt.iterations, only.model.opt.ls_iterations) == (raw.opt.iterations, 7)


@pytest.mark.parametrize("table, message", [
    ("iterations = 0", r"solver\.iterations: expected an integer in \[1, 1000\], got 0"),
    ("iterations = 2.5", r"solver\.iterations: expected an integer in \[1, 1000\], got 2\.5"),
    ("ls_iterations = true", r"solver\.ls_iterations: expected an integer in \[1, 1000\], "
                             r"got True"),
    ('ls_iterations = "8"', r"solver\.ls_iterations: expected an integer"),
    ("tolerance = 1e-6", r"solver: unknown key\(s\) \['tolerance'\]"),
])
def test_a_bad_solver_value_is_refused_naming_the_key(tmp_path, table, message):
    with pytest.raises(RobotFileError, match=message):
        load_description(_with_solver(tmp_path, table))


def _kicked_stand_qpos(model: mujoco.MjModel, seconds: float) -> np.ndarray:
    """MuJoCo C from the model's stand (qpos0 settled by tkujax's stand) with a velocity kick
    every 0.1 s; the joint positions over time."""
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    out = []
    for k in range(int(round(seconds / model.opt.timestep))):
        if k % 50 == 0:
            data.qvel[:] += rng.normal(0.0, 0.3, model.nv)
        mujoco.mj_step(model, data)
        out.append(data.qpos.copy())
    return np.array(out)


@needs_op3
def test_op3_caps_above_its_converged_iterations_change_nothing():
    """The caps of specs/robots/op3_fast.toml, bit for bit; 8 line searches, 1 iteration bind."""
    from tkujax.robot.simsetup import settled_data
    from tkujax.robot.stand import stand_pose

    robot = load_robot(REPO / "specs" / "robots" / "op3.toml")
    model = robot.model
    start = settled_data(robot, stand_pose(robot), 0.2)
    model.qpos0[:] = start.qpos
    runs = {}
    for caps in ((100, 50), (10, 20), (10, 8), (1, 1)):
        model.opt.iterations, model.opt.ls_iterations = caps
        runs[caps] = _kicked_stand_qpos(model, 0.5)
    assert np.max(np.abs(runs[(10, 20)] - runs[(100, 50)])) == 0.0
    assert np.max(np.abs(runs[(10, 8)] - runs[(100, 50)])) > 1e-7    # 8 line searches bind
    assert np.max(np.abs(runs[(1, 1)] - runs[(100, 50)])) > 1e-6
