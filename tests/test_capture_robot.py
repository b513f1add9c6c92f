"""`tkujax capture` on a robot file: the generated second robot (its `stand` keyframe; MuJoCo
C, no compile) runs a tiny capture, the commanded step lands where asked (MuJoCo's kinematics
of the final state), the theory is the robot's, and the checks name the key and the range.
OP3's capture specs are checked against its reach when a Menagerie checkout is found."""

from __future__ import annotations

import math
import tomllib

import mujoco
import numpy as np
import pytest

from tkujax.cli import main
from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.studies.robot_inputs import capture_feet, capture_robot, robot_lip
from tkujax.analysis.capturability import step_reach_m
from tkujax.studies.capture import run_capture
from tkujax.studies.capture.on_robot import check_capture_robot
from tkujax.sweeps.replay import replay
from tkujax.dialects.sweep_spec import SpecError, load_spec, parse_spec

from test_robot_file import REPO, needs_op3

SPEC = """
[robot]
file = "{robot}"
[sweep]
name = "capture_robot"
chunk_size = 16
duration_s = 1.2
control = ["on"]
[push.grid]
impulse_ns = [0.0]
azimuth_deg = [90]
height_m = [0.3]
onset_s = [0.3]
[step]
reference = true
[step.grid]
x_m = [-0.05, 0.05]
y_m = [{y0}, 0.05]
"""


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    path = write_generated_robot(tmp_path_factory.mktemp("second"), GENERATED_SECOND,
                                 name="second")
    return capture_robot(REPO / "specs" / "capture" / "capture_region_cpu.toml", str(path))


def _spec(robot, y0=-0.05, path=None):
    text = SPEC.format(robot=robot[0].source, y0=y0)
    if path is not None:
        path.write_text(text)
    return parse_spec(tomllib.loads(text))


@pytest.fixture(scope="module")
def captured(robot, tmp_path_factory):
    out = tmp_path_factory.mktemp("capture")
    res = run_capture(_spec(robot), out, robot=robot[0], feet=robot[1], backend="mujoco")
    return out, res


def test_capture_runs_on_the_robot(robot, captured):
    out, res = captured
    assert res["complete"] and res["optimise"] == []
    assert res["manifest"]["model_params"]["robot_sha256"] == robot[0].digest
    (row,) = res["regions"]
    assert row["n_targets"] == 4 and row["controller_fell"] == 0.0
    # No push: standing still is captured, and so are these short steps.
    assert row["n_captured"] == 4 and row["icp_in_region"] == 1.0
    assert (out / "capture" / "summary.md").exists()


def test_theory_is_the_robots(robot, captured):
    setup, feet = robot
    assert feet.lip.mass_kg == pytest.approx(mujoco.mj_getTotalmass(setup.setup.host_model))
    assert feet.lip.com_height_m == pytest.approx(robot_lip(setup).com_height_m)
    assert feet.reach_m == pytest.approx(step_reach_m(setup.params))
    # The stand ankles are the settled stand's, hip_offset_y apart from the middle.
    assert feet.ankle["l"][1] - feet.ankle["r"][1] == pytest.approx(
        2 * GENERATED_SECOND.hip_offset_y_m, abs=0.01)
    (j1,) = captured[1]["j1"]
    assert j1["j1_theory"] > 0 and math.isfinite(j1["dt_s"])


def test_forced_step_lands_where_asked(robot, captured):
    """The swing ankle (the left one for y >= 0, else the right one) ends (x, y) from its stand
    place relative to the stance ankle (StepOverride): measured on MuJoCo's kinematics of the
    replayed final state, within 3 cm (TKU-X itself: 1.7 cm; the CPG has no lateral weight
    shift, so the feet slide sideways a little on straight steps)."""
    setup = robot[0]
    model = setup.setup.host_model
    data = mujoco.MjData(model)
    right, left = setup.setup.index.ankle_sites
    out = captured[0]
    for i in range(5):
        res = replay(out, i, robot=setup)
        apart = []
        for q in (res["qpos"][0], res["qpos"][-1]):
            data.qpos[:] = q
            mujoco.mj_kinematics(model, data)
            apart.append(data.site_xpos[left][:2] - data.site_xpos[right][:2])
        s = res["stored"]
        moved = (apart[1] - apart[0]) * (1.0 if s["step_y_m"] >= 0 else -1.0)
        target = np.array([s["step_x_m"], s["step_y_m"]]) if s["step_active"] else np.zeros(2)
        print(f"record {i}: target {target}, feet moved {np.round(moved, 4)}")
        assert np.linalg.norm(moved - target) < 0.03, (i, target, moved)


def test_cli_capture_with_the_robot(robot, captured, tmp_path, capsys):
    """`tkujax capture SPEC` with the spec's [robot] file: the same sweep (resumed: complete),
    the capture summary printed."""
    spec = tmp_path / "spec.toml"
    _spec(robot, path=spec)
    assert main(["capture", str(spec), "--out", str(captured[0]), "--backend", "mujoco"]) == 0
    assert "Capture regions `capture_robot`" in capsys.readouterr().out


def test_targets_beyond_the_reach_name_the_key(robot, tmp_path):
    setup, feet = robot
    far = -round(feet.reach_m + 0.01, 3)
    with pytest.raises(SpecError, match=r"step.grid.x_m, step.grid.y_m: the target .* beyond "
                                        r"second's leg reach l_max = 0\.\d+ m"):
        run_capture(_spec(robot, y0=far), tmp_path, robot=setup, feet=feet, backend="mujoco")
    assert not list(tmp_path.iterdir())      # refused before the sweep


def test_mismatches_are_refused(robot, tmp_path):
    setup, feet = robot
    spec = _spec(robot)
    with pytest.raises(SpecError, match="--robot: expected a Robot"):
        run_capture(spec, tmp_path, robot=setup.source, feet=feet)
    with pytest.raises(SpecError, match="need its capture geometry"):
        run_capture(spec, tmp_path, robot=setup)
    with pytest.raises(SpecError, match="robot.file: the spec runs on .*capture_robot loads both"):
        run_capture(spec, tmp_path)
    tkux = load_spec(REPO / "specs" / "capture" / "capture_region_cpu.toml")
    with pytest.raises(SpecError, match="without its robot"):
        run_capture(tkux, tmp_path, feet=feet)
    other = spec.__class__(**{**spec.__dict__, "robot_file": "/elsewhere/robot.toml"})
    with pytest.raises(SpecError, match="robot.file: the spec names /elsewhere/robot.toml"):
        run_capture(other, tmp_path, robot=setup, feet=feet)


@needs_op3
def test_op3_capture_specs_fit_its_reach():
    setup, feet = capture_robot(REPO / "specs" / "robots" / "op3_capture.toml")
    assert 0.12 < feet.reach_m < 0.22 and 2.5 < feet.lip.mass_kg < 4.0
    for name in ("op3_capture.toml", "op3_capture_cpu.toml"):
        spec = load_spec(REPO / "specs" / "robots" / name)
        assert check_capture_robot(spec, setup, feet, setup.params).reach_m == feet.reach_m
    assert capture_feet(setup).sole.shape == (4, 2)
