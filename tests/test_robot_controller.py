"""The controller belongs to the robot (tkujax.robot.own_controller): a robot file names its
controller, sweeps use it (the spec's [robot] file through `run_sweep` as on the command line),
and a robot without one gets a conservative default that harms none of TKU-X, OP3 and Booster
T1 on push sets where control off falls (MuJoCo C)."""

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest

import tkujax
from tkujax.control.params_files import load_controller_params_json
from tkujax.robot.builtin import write_generated_robot
from tkujax.robot.robot_setup import robot_setup
from tkujax.robot.description import RobotFileError, load_description
from tkujax.robot.own_controller import CONSERVATIVE_SOURCE, NO_STEP_THRESHOLD_RAD
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.sweeps.sweep import run_sweep

REPO = Path(__file__).resolve().parents[1]
MODELS = Path(os.environ.get("TKUJAX_MENAGERIE") or REPO.parent / "shared" / "models")


def _robot_files(tmp_path_factory) -> dict:
    files = {"tkux": write_generated_robot(tmp_path_factory.mktemp("tkux"), name="tkux")}
    if (MODELS / "robotis_op3" / "op3.xml").is_file():
        files["op3"] = REPO / "specs" / "robots" / "op3.toml"
    if (MODELS / "booster_t1" / "t1.xml").is_file():
        files["t1"] = REPO / "specs" / "robots" / "t1.toml"
    return files


# (impulse range N s, push height m): where each robot standing still falls on some pushes.
PUSHES = {"tkux": (0.3, 3.0, 0.36), "op3": (0.3, 2.4, 0.262), "t1": (4.0, 24.0, 0.58)}


@pytest.mark.parametrize("name", ["tkux", "op3", "t1"])
def test_the_conservative_default_harms_no_robot(name, tmp_path_factory):
    files = _robot_files(tmp_path_factory)
    if name not in files:
        pytest.skip(f"no Menagerie model for {name}")
    setup = robot_setup(files[name])
    from tkujax.robot.own_controller import conservative_controller

    params = conservative_controller(setup.defaults)
    assert params.eps_forward == params.eps_backward == NO_STEP_THRESHOLD_RAD
    lo, hi, height = PUSHES[name]
    rng = np.random.default_rng(11)
    n = 64
    pushes = tkujax.stack_pushes([
        tkujax.make_push(float(j), azimuth_deg=float(a), height_m=height,
                         onset_s=0.75 + 0.03 * float(p))
        for j, a, p in zip(rng.uniform(lo, hi, n), rng.uniform(0, 360, n), rng.uniform(0, 1, n))])
    config = tkujax.RolloutConfig(duration_s=2.5)
    _, off = simulate_mujoco(pushes, np.zeros(n), params, robot=setup, config=config)
    _, on = simulate_mujoco(pushes, np.ones(n), params, robot=setup, config=config)
    assert off.fell.sum() >= 5, "the push set must make control off fall"
    assert on.fell.sum() <= off.fell.sum(), (on.fell.sum(), off.fell.sum())


def test_a_robot_without_a_controller_gets_the_conservative_default(tmp_path):
    setup = robot_setup(write_generated_robot(tmp_path, name="plain"))
    assert setup.controller == CONSERVATIVE_SOURCE
    assert setup.params.eps_forward == NO_STEP_THRESHOLD_RAD
    assert setup.defaults.eps_forward < 0.5


def test_a_robot_file_names_its_controller(tmp_path):
    path = write_generated_robot(tmp_path, name="named")
    params = dict(json.loads((REPO / "specs" / "robots" / "op3_widen.json").read_text()))
    (tmp_path / "mine.json").write_text(json.dumps(params))
    text = path.read_text().replace('imu = "imu"', 'imu = "imu"\ncontroller = "mine.json"')
    path.write_text(text)
    setup = robot_setup(path)
    assert setup.controller == "file mine.json"
    assert setup.params == load_controller_params_json(tmp_path / "mine.json")
    path.write_text(text.replace("mine.json", "missing.json"))
    with pytest.raises(RobotFileError, match=r"controller: file not found: .*missing\.json"):
        load_description(path)


def test_a_robot_file_names_its_walking_controller(tmp_path):
    """`walk_controller` is the controller walking runs (the walker and a [walk] sweep's
    parameters); standing keeps `controller`; neither line changes the robot's identity."""
    from tkujax.control.params_files import save_controller_params_json
    from tkujax.robot.robot_setup import file_digest
    from tkujax.dialects.sweep_spec import parse_spec
    from tkujax.sweeps.sweep import run_sweep
    from tkujax.walking.walk import walker

    path = write_generated_robot(tmp_path, name="walks")
    before = file_digest(path)
    standing = dataclasses.replace(robot_setup(path).defaults, stance_ankle_kp=0.5)
    walking = dataclasses.replace(standing, stance_ankle_kp=0.1)
    save_controller_params_json(standing, tmp_path / "stand.json")
    save_controller_params_json(walking, tmp_path / "walk.json")
    text = path.read_text().replace(
        'imu = "imu"', 'imu = "imu"\ncontroller = "stand.json"\nwalk_controller = "walk.json"')
    path.write_text(text)
    robot = robot_setup(path)
    assert file_digest(path) == before
    assert robot.params.stance_ankle_kp == pytest.approx(0.5)
    assert robot.walking_params.stance_ankle_kp == pytest.approx(0.1)
    assert robot.walk_controller == "file walk.json"
    assert walker(str(path)).params.stance_ankle_kp == pytest.approx(0.1)
    push = {"grid": {"impulse_ns": [0.2], "gait_phase": [0.25]}}
    walking = {"robot": {"file": str(path)}, "sweep": {"name": "w", "duration_s": 2.0},
               "walk": {"speed_mps": 0.1, "push_cycle": 1}, "push": push}
    manifest = run_sweep(parse_spec(walking), tmp_path / "walking", backend="mujoco",
                         quiet=True)
    assert manifest["controller_params"]["stance_ankle_kp"] == pytest.approx(0.1)
    path.write_text(text.replace("walk.json", "gone.json"))
    with pytest.raises(RobotFileError, match=r"walk_controller: file not found: .*gone\.json"):
        load_description(path)


def test_run_sweep_takes_a_spec_with_a_robot_file(tmp_path):
    robot = write_generated_robot(tmp_path / "robot", name="gen")
    spec = tmp_path / "spec.toml"
    spec.write_text(f"""[robot]
file = "{robot}"
[sweep]
name = "robot_file"
chunk_size = 4
duration_s = 1.0
control = ["off", "on"]
[push.grid]
impulse_ns = [0.2, 3.0]
azimuth_deg = [0.0]
height_m = [0.36]
onset_s = [0.3]
""")
    manifest = run_sweep(spec, tmp_path / "out", backend="mujoco", quiet=True)
    assert manifest["complete"] and manifest["n_pushes"] == 4
    data = tkujax.load(tmp_path / "out")
    assert data["fell"][data["impulse_ns"] == 3.0].all()
    assert not data["fell"][data["impulse_ns"] == 0.2].any()
