"""`tkujax tune --robot` (tkujax.studies.robot_tune): the pushes from the robot, the structure
chosen on it, the verdict on held-out pushes and the controller named in the robot file when it
passes. On TKU-X's generated robot file and MuJoCo C; the search itself (MJX) is given by its
output file, as a resumed run finds it."""

import dataclasses
import json
import re

import numpy as np
import pytest

from tkujax.cli import main
from tkujax.robot.builtin import write_generated_robot
from tkujax.robot.robot_setup import file_digest, robot_setup
from tkujax.robot.description import load_description
from tkujax.studies.robot_pushes import FALL_TARGET, IMPULSE_LO_FRAC, robot_pushes
from tkujax.studies.robot_structure import STRUCTURES, choose_structure, structure_start
from tkujax.studies.robot_tune import tune_robot_controller
from tkujax.studies.robot_verdict import name_controller


@pytest.fixture(scope="module")
def robot_file(tmp_path_factory):
    return write_generated_robot(tmp_path_factory.mktemp("robot"), name="gen")


@pytest.fixture(scope="module")
def pushes(robot_file):
    return robot_pushes(robot_setup(robot_file))


def test_pushes_reach_where_standing_still_falls(pushes):
    fell = np.array(pushes.ladder_fell)
    top = pushes.ladder_ns.index(pushes.fall80_ns)
    assert fell[top] >= FALL_TARGET and (fell[:top] < FALL_TARGET).all()
    assert fell[0] == 0.0                     # the ladder starts below any fall
    assert pushes.impulse_ns == pytest.approx((IMPULSE_LO_FRAC * pushes.fall80_ns,
                                               pushes.fall80_ns), rel=1e-3)
    assert pushes.height_m[0] < pushes.height_m[1]


def test_structure_is_chosen_by_the_harm_weighted_loss(robot_file, pushes):
    robot = robot_setup(robot_file)
    record = choose_structure(robot, pushes.as_dict())
    losses = {k: v["loss"] for k, v in record["structures"].items()}
    assert record["chosen"] == min(losses, key=losses.get)
    for v in record["structures"].values():
        assert v["loss"] == v["falls"] + 2.0 * v["harmed"]
    stance = structure_start(robot, "stance")
    assert stance["cp_trigger"] == 0.0 and stance["lateral_steps"] == 0.0
    assert set(STRUCTURES["stance"]["tuned"]) < set(STRUCTURES["step"]["tuned"])


def robot_copy_and_stance(folder):
    """A generated robot file written into `folder` (made), and two stance controllers as
    parameter dicts: its start (good), and the same with its stance signs reversed (harmful)."""
    folder.mkdir()
    copy = write_generated_robot(folder, name="gen")
    robot = robot_setup(copy)
    good = dataclasses.asdict(dataclasses.replace(
        robot.defaults, **structure_start(robot, "stance")))
    return copy, good, dict(good, stance_ankle_kp=-3.0, stance_hip_kp=-3.0, stance_roll_kp=-3.0)


def _resumable_run(out, pushes, params: dict, retry: dict | None = None,
                   recommended_from: str = "tuned"):
    """An output folder as a run that has finished its search (and its retry's) leaves it."""
    (out / "tune").mkdir(parents=True)
    (out / "pushes.json").write_text(json.dumps(pushes.as_dict()))
    (out / "structure.json").write_text(json.dumps(dict(chosen="stance", why="given")))
    (out / "tune" / "params_after.json").write_text(json.dumps(
        dict(params, recommended_from=recommended_from)))
    if retry is not None:
        (out / "retry" / "tune").mkdir(parents=True)
        (out / "retry" / "tune" / "params_tuned.json").write_text(json.dumps(retry))


def test_a_failed_controller_is_retried_then_falls_back_and_a_passing_one_written(
        tmp_path, robot_file, pushes, monkeypatch):
    """A first controller that harms (stance feedback with its signs reversed) fails its
    verdict; the retry's search found nothing better (the same controller) and fails on the
    same held-out pushes, against the same control-off run; then the conservative default is
    judged there too, and its stance gains halved when it fails, the best reported, and written
    when it passes. (512 held-out pushes
    fill no cell of 100: cells of 4 pushes are judged here.)"""
    from tkujax.studies import robot_verdict

    from tkujax.studies import robot_tune

    monkeypatch.setattr(robot_verdict, "MIN_CELL_PUSHES", 4)
    monkeypatch.setattr(robot_tune, "FALLBACK_SCALES", (1.0, 0.5))    # the ladder's first two
    folder = tmp_path / "robot"
    copy, good, harmful = robot_copy_and_stance(folder)
    _resumable_run(tmp_path / "run", pushes, harmful, retry=harmful)
    before = file_digest(copy)
    record = tune_robot_controller(copy, tmp_path / "run", budget_s=30, heldout_n=512)
    assert set(record) >= {"robot", "n_pushes", "off_fall", "on_fall", "ratio", "harmed_cells",
                           "method", "n_params", "wall_s", "device"}
    assert record["n_pushes"] == 512
    first = json.loads((tmp_path / "run" / "first_verdict.json").read_text())
    assert not first["passed"] and first["on_fall"] > first["off_fall"]
    assert first["cells_checked"] > 0 and first["n_params"] == 7
    second = json.loads((tmp_path / "run" / "retry" / "compare" / "verdict.json").read_text())
    assert second["reference"]["path"] == str(tmp_path / "run" / "heldout")
    assert record["stages"]["retry"]["on_fall"] == pytest.approx(
        second["runs"]["tuned"]["fall_rate"], abs=1e-5)
    assert record["stages"]["retry"]["on_fall"] == pytest.approx(first["on_fall"])
    third = json.loads((tmp_path / "run" / "fallback" / "compare" / "verdict.json").read_text())
    assert third["reference"]["path"] == str(tmp_path / "run" / "heldout")
    assert record["off_fall"] == first["off_fall"]
    chosen = record["chosen_stage"]
    assert chosen in ("fallback", "fallback_0.5")            # far fewer harmed cells
    # The ladder goes on past a failing conservative default, and stops at a passing one.
    assert ("fallback_0.5" in record["stages"]) == (not record["stages"]["fallback"]["passed"])
    assert record["n_params"] == 0 and "conservative" in record["method"]
    assert record["on_fall"] == record["stages"][chosen]["on_fall"] < first["on_fall"]
    assert record["passed"] == (record["on_fall"] < record["off_fall"]
                                and not record["harmed_cells"] and record["cells_checked"] > 0)
    if record["passed"]:
        assert load_description(copy).controller_path == folder / "gen_controller.json"
        assert robot_setup(copy).controller == "file gen_controller.json"
        assert file_digest(copy) == before          # naming a controller is the same robot
        written = json.loads((folder / "gen_controller.json").read_text())
        scale = 0.5 if chosen == "fallback_0.5" else 1.0
        assert written["stance_ankle_kp"] == pytest.approx(scale * good["stance_ankle_kp"])
    else:
        assert load_description(copy).controller_path is None
    saved = json.loads((tmp_path / "run" / "verdict.json").read_text())
    assert saved["ratio"] == record["ratio"]
    held = json.loads((tmp_path / "run" / "heldout" / "manifest.json").read_text())
    assert record["device"] == held["runs"][-1]["device_kind"]


def test_the_verdict_names_the_devices_that_computed_the_heldout_sweep():
    """A held-out sweep resumed elsewhere (computed on a GPU, judged on a CPU) is reported with
    the device its chunks came from, not the judging process's."""
    from tkujax.sweeps.sweep_folder import computed_on

    manifest = {"runs": [{"device_kind": "NVIDIA H100 80GB HBM3", "chunks_computed": 1},
                         {"device_kind": "NVIDIA H200", "chunks_computed": 1},
                         {"device_kind": "cpu (MuJoCo C)", "chunks_computed": 0}]}
    assert computed_on(manifest) == "NVIDIA H100 80GB HBM3, NVIDIA H200"
    assert computed_on({"runs": [{"run_id": "before-run-history"}]}) == ""


def test_the_retry_starts_at_the_tuned_controller_with_the_harm_weight(robot_file, pushes):
    """The retry's spec: the first search's parameters and ranges, started at the tuned
    values (nudged strictly inside a range they sit on), a harmed push weighing
    RETRY_HARM_WEIGHT, twice the tuning pushes."""
    from tkujax.studies.robot_tune_specs import (RETRY_BATCH, RETRY_HARM_WEIGHT,
                                                 TUNE_BATCH, TUNE_HARM_WEIGHT, tune_spec)
    from tkujax.studies.tune.tune_spec import parse_tune_spec

    robot = robot_setup(robot_file)
    first = tune_spec(str(robot_file), robot, pushes.as_dict(), "step", iterations=5)
    lo, hi = first["tune"]["ranges"]["cp_gain"]
    tuned = dict(structure_start(robot, "step"), cp_gain=hi, stance_hip_kp=0.123)
    again = tune_spec(str(robot_file), robot, pushes.as_dict(), "step", iterations=5,
                      retry_from=tuned)
    assert (first["tune"]["loss"]["w_harm"], first["tune"]["batch"]) == (TUNE_HARM_WEIGHT,
                                                                         TUNE_BATCH)
    assert (again["tune"]["loss"]["w_harm"], again["tune"]["batch"]) == (RETRY_HARM_WEIGHT,
                                                                         RETRY_BATCH)
    assert again["tune"]["ranges"] == first["tune"]["ranges"]
    assert again["tune"]["params"] == first["tune"]["params"]
    assert again["controller"]["stance_hip_kp"] == 0.123
    assert lo < again["controller"]["cp_gain"] < hi
    assert again["controller"]["cp_gain"] == pytest.approx(hi, rel=1e-5)
    parse_tune_spec(again)                       # a start strictly inside its ranges


def test_every_structure_starts_inside_its_ranges(robot_file):
    """Every structure's start (and a retry from it) lies strictly inside its search ranges,
    as the stage checks ask before anything runs; the sideways gain keeps its sign."""
    from tkujax.studies.robot_tune_specs import check_stages, ranges_for

    robot = robot_setup(robot_file)
    check_stages(str(robot_file), robot, 8192)
    for name in STRUCTURES:
        start = structure_start(robot, name)
        for key, (lo, hi) in ranges_for(robot, start, STRUCTURES[name]["tuned"]).items():
            assert lo < start[key] < hi, (name, key)
    step, shift = (ranges_for(robot, structure_start(robot, n), STRUCTURES[n]["tuned"])
                   for n in ("step", "shift_step"))
    assert step["cp_gain_lateral"][1] <= 0.5 and shift["cp_gain_lateral"][0] > 0.0


def test_a_default_clamped_onto_its_cap_starts_inside_the_search(robot_file):
    """A robot whose scaled default is clamped onto its allowed range's edge (a tall robot's
    lift height at the 0.1 m cap) still passes the stage checks, and the first search starts
    inside its ranges by at least START_MARGIN of their width."""
    from tkujax.studies.robot_tune_specs import START_MARGIN, check_stages, tune_spec

    robot = robot_setup(robot_file)
    tall = dataclasses.replace(robot, defaults=dataclasses.replace(robot.defaults,
                                                                   lift_height=0.1))
    check_stages(str(robot_file), tall, 8192)
    widest = {"impulse_ns": (1.0, 10.0), "height_m": (0.2, 0.3), "duration_s": (0.01, 0.08)}
    for name in ("step", "shift_step"):
        spec = tune_spec(str(robot_file), tall, widest, name, iterations=10)
        lo, hi = spec["tune"]["ranges"]["lift_height"]
        assert hi == pytest.approx(0.1)
        assert spec["evaluate"]["impulse_ns"]["stop"] == pytest.approx(10.0)   # the robot's
        lift = spec["controller"]["lift_height"]
        margin = START_MARGIN * (hi - lo)
        assert lo + margin - 1e-12 <= lift <= hi - margin + 1e-12


def test_a_search_that_kept_its_start_is_reported_as_no_tuning():
    """When the search's result fell more on the tune's own held-out pushes, the tune keeps
    its start: the verdict then names no method and no tuned parameter."""
    from tkujax.studies.robot_tune import tuned_method

    method, n = tuned_method({"recommended_from": "start", "stance_ankle_kp": 0.1}, 7)
    assert n == 0 and method.startswith("none")
    assert tuned_method({"recommended_from": "tuned"}, 7) == ("cma", 7)


def test_which_verdict_is_retried_and_reported():
    from tkujax.studies.robot_tune import better_verdict, should_retry

    base = dict(passed=False, ratio=0.7, cells_checked=64, harmed_cells=[{}], on_fall=0.2)
    assert should_retry(base)
    assert not should_retry(dict(base, passed=True, harmed_cells=[]))
    assert not should_retry(dict(base, ratio=None))          # control off never fell
    assert not should_retry(dict(base, cells_checked=0))     # no cell to judge
    passing = dict(base, passed=True, harmed_cells=[], on_fall=0.25)
    assert better_verdict(base, passing) is passing
    fewer = dict(base, harmed_cells=[], on_fall=0.3)
    assert better_verdict(base, fewer) is fewer
    assert better_verdict(base, dict(base, on_fall=0.1))["on_fall"] == 0.1
    assert better_verdict(base, dict(base)) is base


def test_name_controller_replaces_an_existing_line(tmp_path):
    copy = write_generated_robot(tmp_path, name="gen")
    params = dataclasses.asdict(robot_setup(copy).defaults)
    name_controller(copy, params)
    text = copy.read_text().replace('"gen_controller.json"', '"old.json"')
    copy.write_text(text)
    name_controller(copy, params)
    assert copy.read_text().count("controller =") == 1
    assert 'controller = "gen_controller.json"' in copy.read_text()


def test_tune_without_spec_or_robot_is_refused(capsys):
    assert main(["tune", "--out", "unused"]) == 2
    assert "--robot FILE" in capsys.readouterr().err


def test_a_given_structure_replaces_the_probe_and_must_match_a_kept_run(tmp_path, robot_file,
                                                                       pushes, capsys):
    """--structure: one of STRUCTURES (the command line offers exactly those); a folder whose
    kept structure is another is refused before anything is simulated."""
    from tkujax.dialects.sweep_spec import SpecError

    with pytest.raises(ValueError, match="structure must be one of"):
        tune_robot_controller(robot_file, tmp_path / "a", budget_s=30, structure="hop")
    with pytest.raises(SystemExit):
        main(["tune", "--robot", str(robot_file), "--out", str(tmp_path / "b"),
              "--structure", "hop"])
    offered = re.search(r"choose from ([^)]*)\)", capsys.readouterr().err).group(1)
    assert sorted(n.strip(" '") for n in offered.split(",")) == sorted(STRUCTURES)
    _resumable_run(tmp_path / "run", pushes, {})
    with pytest.raises(SpecError, match="holds a run of structure 'stance'"):
        tune_robot_controller(robot_file, tmp_path / "run", budget_s=30, structure="step")


class _Swept(Exception):
    """Stands for the held-out sweep: raised once it has its spec."""


def test_the_heldout_spec_records_the_robot_file_relative_to_its_folder(tmp_path, monkeypatch):
    """heldout_spec.json names the robot file relative to its own folder (not by a path of
    the machine it was made on) and still runs when that folder moves with the robot file;
    absolute only where no relative path exists (another drive)."""
    import os
    import shutil
    from types import SimpleNamespace

    from tkujax.dialects.sweep_spec import parse_spec
    from tkujax.studies import robot_verdict
    from tkujax.studies.robot_tune_specs import heldout_spec

    robot_file = write_generated_robot(tmp_path / "here" / "robots", name="gen")
    out = tmp_path / "here" / "runs" / "gen_tune"
    out.mkdir(parents=True)
    swept = []

    def sweep(spec, *args, **kwargs):
        swept.append(spec.robot_file)
        raise _Swept

    monkeypatch.setattr(robot_verdict, "run_sweep", sweep)
    pushes = dict(impulse_ns=[0.1, 1.0], height_m=[0.3, 0.36], duration_s=[0.01, 0.08])
    spec = heldout_spec(str(robot_file.resolve()), SimpleNamespace(name="gen"), pushes, 64)
    with pytest.raises(_Swept):
        robot_verdict.heldout_verdict(out, None, spec, {}, method="cma", n_params=1)
    record = json.loads((out / "heldout_spec.json").read_text())
    assert record["robot"]["file"] == "../../robots/gen.toml"
    assert swept == [str(robot_file.resolve())]              # the sweep ran on the robot file
    assert {k: v for k, v in record.items() if k != "robot"} == {
        k: v for k, v in spec.items() if k != "robot"}
    shutil.move(tmp_path / "here", tmp_path / "there")       # the folder with the robot file
    moved = tmp_path / "there" / "runs" / "gen_tune" / "heldout_spec.json"
    assert parse_spec(robot_verdict.read_spec_record(moved)).robot_file == str(
        (tmp_path / "there" / "robots" / "gen.toml").resolve())

    def other_drive(path, start=None):
        raise ValueError("path is on mount 'D:', start on mount 'C:'")

    monkeypatch.setattr(os.path, "relpath", other_drive)
    far = robot_verdict.spec_record(spec, tmp_path / "there")
    assert far["robot"]["file"] == str(robot_file.resolve())


def test_a_harmed_verdict_names_the_cell_that_lost_the_most():
    """The reason a verdict fails names the harmed cell with the largest excess, its impulse
    band and phase (it printed "at None N s", naming the first cell listed)."""
    from tkujax.studies.robot_verdict import verdict_reason

    cell = dict(sector="behind", impulse_ns=[0.738, 1.249], phase="0.00-0.33", diff_pp=5.6)
    worse = dict(cell, phase="0.67-1.00", diff_pp=9.0)
    v = dict(cells_checked=64, ratio_to_reference=0.68, fall_rate=0.156,
             reference_fall_rate=0.231, harmed_cells=[cell, worse])
    assert verdict_reason(v) == ("2 harmed cell(s), the worst behind at 0.74-1.25 N s, "
                                 "phase 0.67-1.00: +9.0 points")
    assert verdict_reason(dict(v, harmed_cells=[])).startswith("passed")


def test_the_fallback_ladder_stops_at_the_first_gentler_controller_that_passes(
        robot_file, monkeypatch, tmp_path):
    """When the conservative default harms a cell, its stance gains halved, then quartered,
    are judged on the same held-out pushes (FALLBACK_SCALES), and the first that passes is
    reported with its parameters. The held-out verdicts are stand-ins here: one that harms
    while the ankle gain exceeds a limit between the half and the full default."""
    from tkujax.studies import robot_tune

    robot = robot_setup(robot_file)
    full = robot_tune.fallback_params(robot, 1.0)["stance_ankle_kp"]
    judged = []

    def verdict(folder, robot, held, params, method, n_params, reference):
        judged.append((folder.name, params["stance_ankle_kp"], method))
        harms = params["stance_ankle_kp"] > 0.75 * full
        return dict(passed=not harms, harmed_cells=[{"cell": 1}] if harms else [],
                    on_fall=0.40 if harms else 0.45, off_fall=0.5, ratio=0.9,
                    cells_checked=64, why="harm" if harms else "passed", wall_s=1.0,
                    method=method)

    monkeypatch.setattr(robot_tune, "heldout_verdict", verdict)
    first = dict(passed=False, harmed_cells=[{"cell": 1}] * 3, on_fall=0.3, off_fall=0.5,
                 ratio=0.6, cells_checked=64, why="first", wall_s=1.0,
                 stages={"tune": {}}, chosen_stage="tune")
    record, params = robot_tune._stage_fallback(tmp_path, robot, {}, lambda msg: None, first,
                                                {"from": "tune"})
    assert [j[0] for j in judged] == ["fallback", "fallback_0.5"]          # stopped there
    assert judged[1][1] == pytest.approx(0.5 * full)
    assert record["passed"] and record["chosen_stage"] == "fallback_0.5"
    assert "x 0.5" in record["method"] and params["stance_ankle_kp"] == pytest.approx(0.5 * full)
    assert set(record["stages"]) == {"tune", "fallback", "fallback_0.5"}
    # Scale 1 is the conservative default itself, as the robot without a controller gets it.
    assert robot_tune.fallback_params(robot, 1.0) == dataclasses.asdict(dataclasses.replace(
        robot.defaults, **structure_start(robot, "stance")))


def test_a_verdict_runs_on_the_engine_of_its_reference(robot_file, monkeypatch, tmp_path):
    """A held-out sweep judged against a reference folder runs on the engine that computed the
    reference (MJX here), whatever this machine would choose: the pairs then differ by the
    controller only. Two engines in one folder pin nothing."""
    from tkujax.studies import robot_verdict
    from tkujax.sweeps.sweep_folder import computed_with

    reference = tmp_path / "heldout"
    reference.mkdir()
    runs = [{"backend": "mjx", "chunks_computed": 1}, {"backend": "mujoco", "chunks_computed": 0}]
    (reference / "manifest.json").write_text(json.dumps({"backend": "mujoco", "runs": runs}))
    assert computed_with(reference) == "mjx"
    assert computed_with(tmp_path / "nothing") is None
    chosen = []

    class Stop(Exception):
        pass

    def run_sweep(*args, backend="auto", **kwargs):
        chosen.append(backend)
        raise Stop

    monkeypatch.setattr(robot_verdict, "run_sweep", run_sweep)
    robot = robot_setup(robot_file)
    spec = {"robot": {"file": str(robot_file)}, "sweep": {"name": "h", "control": ["off", "on"]},
            "push": {"grid": {"impulse_ns": [0.5]}}}
    params = dataclasses.asdict(robot.defaults)
    (tmp_path / "stage").mkdir()
    with pytest.raises(Stop):
        robot_verdict.heldout_verdict(tmp_path / "stage", robot, spec, params, "m", 0,
                                      reference=reference)
    (reference / "manifest.json").write_text(json.dumps({"runs": [
        {"backend": "mjx", "chunks_computed": 1}, {"backend": "mujoco", "chunks_computed": 1}]}))
    with pytest.raises(Stop):
        robot_verdict.heldout_verdict(tmp_path / "stage", robot, spec, params, "m", 0,
                                      reference=reference)
    assert chosen == ["mjx", "auto"]
