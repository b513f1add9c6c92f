"""The policy method of `tkujax tune --robot` (tkujax.studies.robot_policy) and a robot file
that names a scheduled policy as its controller. On TKU-X's generated robot file and MuJoCo C;
the line search itself (MJX gradients) is given by its output file, as a resumed run finds it.

- The policy's study spec parses, starts exactly at the CMA-ES result and schedules only the
  schedulable tuned fields, for the CMA-ES search's compile plus search time.
- A policy that beats a harmful CMA-ES controller on the same held-out pushes is judged with
  its schedule (the sweep's manifest records it), kept, written beside the robot file as a
  policy file and named there; the Robot then carries the schedule and a sweep without
  --params runs it.
- `walk_controller` naming a policy is refused, naming the key.
"""

import dataclasses
import json

import pytest

from tkujax.control.params_files import RECOMMENDED_POLICY_PATH
from tkujax.robot.builtin import write_generated_robot
from tkujax.robot.description import RobotFileError
from tkujax.robot.robot_setup import robot_setup
from tkujax.studies.robot_policy import (POLICY, POLICY_METHOD, policy_budget_s, policy_size,
                                         policy_spec, scheduled_fields)
from tkujax.studies.robot_pushes import robot_pushes
from tkujax.studies.robot_structure import STRUCTURES, structure_start
from tkujax.studies.robot_tune import tune_robot_controller
from tkujax.studies.robot_tune_specs import tune_spec
from tkujax.studies.tune.reparam import check_start
from tkujax.studies.tune.tune_spec import parse_tune_spec
from tkujax.sweeps.sweep import run_sweep

from test_robot_tune import robot_copy_and_stance


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    folder = tmp_path_factory.mktemp("robot")
    robot_file = write_generated_robot(folder, name="gen")
    return robot_file, robot_pushes(robot_setup(robot_file)).as_dict()


@pytest.mark.parametrize("structure", sorted(STRUCTURES))
def test_the_policy_spec_starts_at_the_cma_result(generated, structure):
    robot_file, pushes = generated
    robot = robot_setup(robot_file)
    tuned = dataclasses.asdict(dataclasses.replace(
        robot.defaults, **(structure_start(robot, structure) | {"stance_ankle_kp": 0.123})))
    start = tune_spec(str(robot_file), robot, pushes, structure, 100, retry_from=tuned)
    spec = policy_spec(tune_spec(str(robot_file), robot, pushes, structure, 100),
                       start["controller"], 77.0)
    parsed = parse_tune_spec(spec)
    check_start(parsed)
    assert parsed.policy == POLICY and parsed.study["methods"] == [POLICY_METHOD]
    assert parsed.study["budget_s"] == 77.0 and parsed.study["budget_includes_compile"]
    assert parsed.schedule == tuple(scheduled_fields(parsed.params))
    assert "accel_gate" in parsed.params and "accel_gate" not in parsed.schedule
    assert policy_size(spec) == len(parsed.params) + 8 * len(parsed.schedule)
    assert parsed.base_params().stance_ankle_kp == pytest.approx(0.123, rel=1e-6)


def test_the_budget_is_the_cma_searchs_compile_and_search_time():
    history = {"run": {"compile_s": 12.5, "curve": [{"wall_s": 0.0}, {"wall_s": 40.25}]}}
    assert policy_budget_s(history) == 52.75


def _resumed(out, pushes, params: dict, policy: dict):
    """A folder as a run leaves it after its CMA-ES search and its policy's study."""
    (out / "tune").mkdir(parents=True)
    (out / "policy" / "study").mkdir(parents=True)
    (out / "pushes.json").write_text(json.dumps(pushes))
    (out / "structure.json").write_text(json.dumps(dict(chosen="stance", why="given")))
    (out / "tune" / "params_after.json").write_text(json.dumps(params))
    (out / "tune" / "history.json").write_text(json.dumps(
        {"run": {"compile_s": 10.0, "curve": [{"wall_s": 25.0}]}}))
    (out / "policy" / "study" / "best_policy.json").write_text(json.dumps(policy))


def test_a_better_policy_is_kept_named_and_run(tmp_path, generated, monkeypatch):
    """The CMA-ES result harms (stance feedback with its signs reversed); the policy (the
    robot's stance scalars under the recommended policy's 8-sector schedule) is judged on the
    same held-out pushes with its schedule and kept. (512 held-out pushes fill no cell of 100:
    cells of 4 pushes are judged here.)"""
    from tkujax.studies import robot_verdict

    monkeypatch.setattr(robot_verdict, "MIN_CELL_PUSHES", 4)
    _, pushes = generated
    folder = tmp_path / "robot"
    copy, good, harmful = robot_copy_and_stance(folder)
    schedule = json.loads(RECOMMENDED_POLICY_PATH.read_text())["schedule"]
    policy = {"controller": good, "schedule": schedule}
    _resumed(tmp_path / "run", pushes, harmful, policy)
    record = tune_robot_controller(copy, tmp_path / "run", budget_s=30, heldout_n=512,
                                   retry=False, policy_method=True)
    stages = record["stages"]
    assert set(stages) == {"tune", "policy"} and stages["policy"]["budget_s"] == 35.0
    held = json.loads((tmp_path / "run" / "policy" / "heldout" / "manifest.json").read_text())
    assert held["schedule"]["table"] == schedule["table"]
    assert stages["policy"]["on_fall"] < stages["tune"]["on_fall"]
    assert len(stages["policy"]["harmed_cells"]) < len(stages["tune"]["harmed_cells"])
    assert record["chosen_stage"] == "policy" and record["method"].startswith(POLICY_METHOD)
    if record["passed"]:
        written = json.loads((folder / "gen_controller.json").read_text())
        assert written["schedule"]["table"] == schedule["table"]
        assert robot_setup(copy).schedule is not None


def test_a_robot_file_runs_the_policy_it_names(tmp_path):
    folder = tmp_path / "robot"
    copy = write_generated_robot(folder, name="gen")
    schedule = json.loads(RECOMMENDED_POLICY_PATH.read_text())["schedule"]
    params = dataclasses.asdict(robot_setup(copy).params)
    (folder / "gen_policy.json").write_text(json.dumps({"controller": params,
                                                        "schedule": schedule}))
    copy.write_text(copy.read_text().replace('imu = ', 'controller = "gen_policy.json"\nimu = ',
                                             1))
    robot = robot_setup(copy)
    assert robot.schedule is not None and robot.controller == "file gen_policy.json"
    spec = tmp_path / "tiny.toml"
    spec.write_text(f'[robot]\nfile = "{copy}"\n[sweep]\nname = "t"\nchunk_size = 2\n'
                    'duration_s = 0.6\ncontrol = ["on"]\n[push.grid]\nimpulse_ns = [0.3]\n'
                    'azimuth_deg = [0, 180]\nonset_s = [0.3]\n')
    manifest = run_sweep(spec, tmp_path / "out", backend="mujoco", quiet=True)
    assert manifest["complete"] and manifest["schedule"]["table"] == schedule["table"]
    # The gait runs no schedule: a walking controller that is a policy is refused.
    copy.write_text(copy.read_text().replace(
        'controller = "gen_policy.json"\n',
        'controller = "gen_policy.json"\nwalk_controller = "gen_policy.json"\n', 1))
    with pytest.raises(RobotFileError, match="walk_controller: .* scheduled policy"):
        robot_setup(copy)


def test_a_policy_that_returned_its_start_is_not_judged(tmp_path, generated, monkeypatch):
    """The line search found no step (a zero table at its start, the CMA-ES result nudged
    inside its ranges): `returned_start` says so, and the command reports it without a
    verdict of its own, keeping the CMA-ES controller; a moved scalar or a non-zero table is
    a policy of its own."""
    from tkujax.studies import robot_verdict
    from tkujax.studies.robot_policy import returned_start

    monkeypatch.setattr(robot_verdict, "MIN_CELL_PUSHES", 4)
    robot_file, pushes = generated
    copy, good, _ = robot_copy_and_stance(tmp_path / "robot")
    robot = robot_setup(copy)
    start = tune_spec(str(copy), robot, pushes, "stance", iterations=10,
                      retry_from=good)["controller"]
    spec = policy_spec(tune_spec(str(copy), robot, pushes, "stance", iterations=10), start,
                       60.0)
    schedule = json.loads(RECOMMENDED_POLICY_PATH.read_text())["schedule"]
    zero = dict(schedule, table=[[0.0] * len(row) for row in schedule["table"]])
    policy = {"controller": dict(good, **start), "schedule": zero}
    assert returned_start(policy, spec)
    assert not returned_start(dict(policy, schedule=schedule), spec)
    moved = dict(policy["controller"], stance_hip_kp=start["stance_hip_kp"] + 1e-3)
    assert not returned_start(dict(policy, controller=moved), spec)
    _resumed(tmp_path / "run", pushes, good, policy)
    record = tune_robot_controller(copy, tmp_path / "run", budget_s=30, heldout_n=512,
                                   retry=False, policy_method=True)
    assert record["stages"]["policy"]["returned_start"] is True
    assert record["chosen_stage"] == "tune" and record["method"] == "cma"
    assert not (tmp_path / "run" / "policy" / "heldout").exists()
