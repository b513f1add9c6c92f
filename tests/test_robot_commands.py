"""--robot on the commands that read sweeps (map, compare, replay), on capture, and on tune
([robot] file in a tune spec): the robot comes from the sweep's manifest (path and sha256),
and a --robot that is not that robot is an error naming both. On the generated second robot
(MuJoCo C sweeps: no compile), against a second file of TKU-X as the wrong robot."""

from __future__ import annotations

import tomllib

import mujoco
import pytest

from tkujax.cli import main
from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.robot.robot_setup import robot_setup
from tkujax.studies.capture import run_capture
from tkujax.analysis.compare import compare_runs
from tkujax.analysis.maps import make_maps
from tkujax.sweeps.replay import replay
from tkujax.studies.robot_inputs import robot_lip, sweep_robot, tune_robot
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.sweep import run_sweep
from tkujax.studies.tune.robot_table import on_robot
from tkujax.studies.tune.tune_spec import parse_tune_spec

from test_robot_file import REPO

SPEC = """
[sweep]
name = "robot_cmds"
chunk_size = 4
duration_s = 1.0
control = ["off", "on"]
[push.grid]
impulse_ns = [0.3, 6.0]
azimuth_deg = [0.0]
height_m = [0.32]
onset_s = [0.3]
"""

TUNE = """
[robot]
file = "{robot}"
[tune]
name = "robot_tune"
iterations = 1
batch = 4
params = ["step_period", "lift_height"]
[tune.ranges]
step_period = [0.1, 0.8]
lift_height = [0.005, 0.08]
[controller]
cp_gain = 1.25
[push]
impulse_ns = {{uniform = [0.2, 1.6]}}
azimuth_deg = [0, 180]
height_m = {{uniform = [0.30, 0.34]}}
[evaluate]
n = 4
impulse_ns = [1.0]
azimuth_deg = [0]
"""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("robots")
    second = write_generated_robot(root / "second", GENERATED_SECOND, name="second",
                                   keyframe=False)
    other = write_generated_robot(root / "tkux", name="tkux")
    return str(second), str(other)


@pytest.fixture(scope="module")
def setups(files):
    return tuple(robot_setup(f) for f in files)


@pytest.fixture(scope="module")
def sweep(files, tmp_path_factory):
    out = tmp_path_factory.mktemp("sweep") / "run"
    run_sweep(parse_spec(tomllib.loads(SPEC)), out, model_params=robot_setup(files[0]),
              backend="mujoco", quiet=True)
    return out


def test_map_takes_the_robots_lip(files, sweep):
    """The robot comes from the manifest; the maps' LIP is its: its mass by MuJoCo, its settled
    CoM height."""
    robot = sweep_robot(sweep)
    assert robot.source == files[0]
    lip = robot_lip(robot)
    assert lip.mass_kg == pytest.approx(mujoco.mj_getTotalmass(robot.setup.host_model))
    assert lip.com_height_m == pytest.approx(robot.settled.subtree_com[1][2])
    res = make_maps(sweep, robot=robot, lip=lip)
    assert f"m = {lip.mass_kg:.2f} kg, z0 = {lip.com_height_m:.3f} m" in open(
        res["summary"]).read()


def test_map_replay_compare_refuse_another_robot(files, setups, sweep, tmp_path):
    second, other = files
    wrong = setups[1]
    for call in (lambda: make_maps(sweep, robot=wrong, lip=robot_lip(wrong)),
                 lambda: replay(sweep, 0, robot=wrong),
                 lambda: compare_runs([f"{sweep}:off", f"{sweep}:on"], tmp_path, min_pushes=1,
                                      robot=wrong)):
        with pytest.raises(SpecError, match="--robot") as err:
            call()
        assert second in str(err.value) and other in str(err.value)


def test_replay_and_compare_on_the_robot(files, setups, sweep, tmp_path):
    with pytest.raises(SpecError, match="ran on the robot file"):
        replay(sweep, 1)                                  # the library needs the robot
    res = replay(sweep, 1, robot=setups[0])
    assert res["same_outcome"] and res["model_params"].source == files[0]
    out = compare_runs([f"{sweep}:off", f"{sweep}:on"], tmp_path, min_pushes=1,
                       robot=setups[0])
    assert out["verdict"]["reference"]["n"] == 2


def test_cli_map_names_both_robots(files, sweep, capsys):
    assert main(["map", str(sweep), "--robot", files[1]]) == 2
    err = capsys.readouterr().err
    assert "tkujax map: error: --robot" in err and files[1] in err


def test_cli_compare_and_replay_take_the_manifests_robot(sweep, tmp_path, capsys):
    assert main(["replay", str(sweep), "--index", "0"]) == 0
    assert main(["compare", f"{sweep}:off", f"{sweep}:on", "--out", str(tmp_path),
                 "--min-pushes", "1"]) == 0


def test_tkux_sweep_refuses_a_robot(setups, tmp_path):
    out = tmp_path / "tkux"
    spec = parse_spec(tomllib.loads(SPEC.replace("0.32", "0.36")))
    run_sweep(spec, out, backend="mujoco", quiet=True, max_chunks=1)
    with pytest.raises(SpecError, match="ran on tkujax's own robot"):
        make_maps(out, robot=setups[0], lip=robot_lip(setups[0]))


def test_capture_wants_a_robot_setup(files, tmp_path):
    """capture on a robot takes its Robot and geometry
    (tkujax.studies.robot_inputs.capture_robot), not a path (tests/test_capture_robot.py runs
    it)."""
    with pytest.raises(SpecError, match="--robot: expected a Robot"):
        run_capture(REPO / "specs" / "capture" / "capture_region_cpu.toml", tmp_path,
                    robot=files[0])


def test_tune_starts_from_the_robots_defaults(files):
    """[robot] file: the start is the robot's scaled controller with [controller] applied."""
    raw = tomllib.loads(TUNE.format(robot=files[0]))
    spec = parse_tune_spec(raw)
    robot = tune_robot(raw)
    resolved = on_robot(spec, robot)
    assert resolved.start.step_period == pytest.approx(robot.defaults.step_period)
    assert resolved.start.thigh_length == pytest.approx(robot.defaults.thigh_length)
    assert resolved.start.cp_gain == pytest.approx(1.25)
    assert resolved.model_params() is robot
    with pytest.raises(SpecError, match="robot.file: the spec names .* give its Robot"):
        on_robot(spec)


def test_tune_robot_errors_name_the_key(files, setups):
    spec = parse_tune_spec(tomllib.loads(TUNE.format(robot=files[0])))
    with pytest.raises(SpecError, match="robot.file: the spec names .* --robot gives"):
        on_robot(spec, setups[1])
    data = tomllib.loads(TUNE.format(robot=files[0]))
    data["robot"]["path"] = "x"
    with pytest.raises(SpecError, match=r"\[robot\]: expected exactly one key"):
        parse_tune_spec(data)
    data = tomllib.loads(TUNE.format(robot=files[0]))
    data["tune"]["ranges"]["step_period"] = [0.5, 0.8]
    with pytest.raises(SpecError, match="step_period: start value .* tune.ranges"):
        on_robot(parse_tune_spec(data), setups[0])
