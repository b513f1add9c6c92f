"""`tkujax tune --robot` against the robot's own controller (tkujax.studies.robot_tune, step 7)
and on the built-in TKU-X (`--robot tkux`). On MuJoCo C; the search itself (MJX) is given by
its output file, as a resumed run finds it.

- A robot file that names a controller keeps it unless this run's verdict on the same held-out
  pushes is better: a harmful search result never replaces a good controller, and a good one
  replaces a harmful controller. A rerun judges the controller the file named when the run
  began, not the one the run wrote.
- `--robot tkux`: its specs name no robot file and pass the stage checks; its own controller
  is the package's recommended policy; a passing controller is written into the output folder,
  never into the package.
"""

import dataclasses
import json

import pytest

from tkujax.control.params_files import RECOMMENDED_POLICY_PATH, load_policy_json
from tkujax.robot.description import load_description
from tkujax.studies.robot_pushes import contact_heights_m
from tkujax.studies.robot_structure import structure_start
from tkujax.studies.robot_inputs import BUILTIN_ROBOT, is_builtin, tune_robot
from tkujax.studies.robot_tune import own_controller, robot_of, tune_robot_controller
from tkujax.studies.robot_tune_specs import check_stages, heldout_spec, tune_spec
from tkujax.studies.robot_verdict import name_controller, write_controller
from tkujax.studies.tune.robot_table import on_robot
from tkujax.studies.tune.tune_spec import parse_tune_spec
from tkujax.dialects.validation import SpecError
from tkujax.sweeps.sweep import TKUX_HEIGHT_M

from test_robot_tune import robot_copy_and_stance

# TKU-X's pushes as its probe gave them (results/robots/tkux/pushes.json).
TKUX_PUSHES = dict(impulse_ns=[0.3629, 3.6295], height_m=[0.25, 0.2887],
                   duration_s=[0.01, 0.08])


def _searched(out, pushes: dict, params: dict):
    """An output folder as a run that has finished its search leaves it (structure: stance)."""
    (out / "tune").mkdir(parents=True)
    (out / "pushes.json").write_text(json.dumps(pushes))
    (out / "structure.json").write_text(json.dumps(dict(chosen="stance", why="given")))
    (out / "tune" / "params_after.json").write_text(json.dumps(dict(params,
                                                                    recommended_from="tuned")))


@pytest.fixture
def small_cells(monkeypatch):
    """512 held-out pushes fill no cell of 100: cells of 4 pushes are judged here."""
    from tkujax.studies import robot_verdict

    monkeypatch.setattr(robot_verdict, "MIN_CELL_PUSHES", 4)


def _run(robot_file, out):
    return tune_robot_controller(robot_file, out, budget_s=30, heldout_n=512, retry=False,
                                 policy_method=False)


def test_a_named_controller_is_replaced_only_by_a_better_one(tmp_path, small_cells):
    """The file names a good controller, the search found a harmful one: the own controller
    is judged on the same held-out pushes and kept, the file left as it was."""
    copy, good, harmful = robot_copy_and_stance(tmp_path / "robot")
    named = name_controller(copy, good)
    before, text = named.read_text(), copy.read_text()
    _searched(tmp_path / "run", _pushes(copy), harmful)
    record = _run(copy, tmp_path / "run")
    stages = record["stages"]
    assert set(stages) == {"tune", "own"} and stages["own"]["where"] == f"file {named.name}"
    assert stages["own"]["on_fall"] < stages["tune"]["on_fall"]
    assert record["chosen_stage"] == "own" and record["on_fall"] == stages["own"]["on_fall"]
    assert record["n_params"] == 0 and "own controller" in record["method"]
    assert "controller_file" not in record
    assert named.read_text() == before and copy.read_text() == text
    own = json.loads((tmp_path / "run" / "own" / "compare" / "verdict.json").read_text())
    assert own["reference"]["path"] == str(tmp_path / "run" / "heldout")


def test_a_better_controller_replaces_a_harmful_one_and_a_rerun_judges_the_same(
        tmp_path, small_cells):
    copy, good, harmful = robot_copy_and_stance(tmp_path / "robot")
    name_controller(copy, harmful)
    _searched(tmp_path / "run", _pushes(copy), good)
    record = _run(copy, tmp_path / "run")
    stages = record["stages"]
    assert stages["tune"]["on_fall"] < stages["own"]["on_fall"]
    assert record["chosen_stage"] == "tune"
    written = json.loads(load_description(copy).controller_path.read_text())
    named = good if record["passed"] else harmful      # a failing run writes nothing
    assert written["stance_ankle_kp"] == pytest.approx(named["stance_ankle_kp"])
    # The rerun's own controller is the one named when the run began (harmful), kept in own/.
    again = _run(copy, tmp_path / "run")
    same = ("on_fall", "harmed_cells", "where")
    assert [again["stages"]["own"][k] for k in same] == [stages["own"][k] for k in same]
    assert again["chosen_stage"] == "tune"
    kept = json.loads((tmp_path / "run" / "own" / "controller.json").read_text())
    assert kept["stance_ankle_kp"] == pytest.approx(harmful["stance_ankle_kp"])


def _pushes(robot_file) -> dict:
    from tkujax.studies.robot_pushes import robot_pushes
    from tkujax.robot.robot_setup import robot_setup

    return robot_pushes(robot_setup(robot_file)).as_dict()


def test_tkux_is_the_builtin_robot_against_its_recommended_policy(tmp_path):
    robot, robot_file = robot_of(BUILTIN_ROBOT)
    assert robot.builtin and robot_file is None
    assert is_builtin("TKUX") and not is_builtin(tmp_path / "tkux.toml")
    (tmp_path / "tkux").write_text("")              # a file of that name is a robot file
    assert not is_builtin(tmp_path / "tkux")
    assert tune_robot({}, "tkux") is None                # a tune spec's --robot tkux: TKU-X
    check_stages(None, robot, 512)
    # TKU-X's CoM (0.244 m) is below its trunk: the pushes land on the trunk, as a sweep asks.
    lo, hi = contact_heights_m(robot)
    assert TKUX_HEIGHT_M[0] == lo < hi <= TKUX_HEIGHT_M[1]
    assert "robot" not in heldout_spec(None, robot, TKUX_PUSHES, 512)
    spec = tune_spec(None, robot, TKUX_PUSHES, "step", iterations=3)
    assert "robot" not in spec
    parsed = parse_tune_spec(spec)                     # the built-in Robot is the spec's TKU-X
    assert on_robot(parsed, robot) is parsed
    other = dataclasses.replace(robot, model_params=dataclasses.replace(
        robot.model_params, calf_length_m=robot.model_params.calf_length_m + 0.01))
    with pytest.raises(SpecError, match="built-in TKU-X with other model parameters"):
        on_robot(parsed, other)
    own, where = own_controller(robot, None)
    assert own == json.loads(RECOMMENDED_POLICY_PATH.read_text())
    assert where == "the recommended policy"
    path = write_controller(None, own, tmp_path)
    assert path == tmp_path / "controller.json"
    assert load_policy_json(path)[0] == load_policy_json(RECOMMENDED_POLICY_PATH)[0]
    assert json.loads(path.read_text())["schedule"] == own["schedule"]


def test_tkux_runs_the_stages_and_keeps_a_better_recommended_policy(tmp_path, small_cells):
    """`--robot tkux` through the held-out verdict and the own stage on MuJoCo C: a search
    result that harms (stance feedback with its signs reversed) loses to the recommended
    policy, which is kept; nothing is written."""
    robot, _ = robot_of(BUILTIN_ROBOT)
    reversed_signs = dict(stance_ankle_kp=-3.0, stance_hip_kp=-3.0, stance_roll_kp=-3.0)
    harmful = dataclasses.asdict(dataclasses.replace(
        robot.defaults, **(structure_start(robot, "stance") | reversed_signs)))
    _searched(tmp_path / "run", TKUX_PUSHES, harmful)
    record = _run(BUILTIN_ROBOT, tmp_path / "run")
    assert record["robot"] == "TKU-X" and record["n_pushes"] == 512
    stages = record["stages"]
    assert stages["own"]["where"] == "the recommended policy"
    assert stages["own"]["on_fall"] < stages["tune"]["on_fall"]
    assert record["chosen_stage"] == "own" and "controller_file" not in record
    held = json.loads((tmp_path / "run" / "own" / "heldout" / "manifest.json").read_text())
    assert held["schedule"]["table"] == json.loads(RECOMMENDED_POLICY_PATH.read_text())[
        "schedule"]["table"]
    assert "robot" not in json.loads((tmp_path / "run" / "heldout_spec.json").read_text())
