"""Hostile command lines: every command stops on bad input with exit 2 and one line naming the
key and its range, on an OS error with one line naming the path and what is wrong, and writes
no record. Parameter and model files, the multi-process arguments and the folders a sweep reads
or writes are the inputs here; the specs themselves are tests/test_hostile_spec.py's."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from hostile_helpers import TINY, nothing_written, refused, run

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def spec(tmp_path) -> Path:
    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


def _sweep(spec, out, *extra):
    return ("sweep", spec, "--out", out, "--backend", "mujoco", *extra)


# --params files: (case id, file content (str, or bytes), key the message must name)
PARAMS = [
    ("control_period_other", '{"control_period": 0.02}', "control_period"),
    ("control_period_off_by_a_hair", '{"control_period": 0.0300001}', "control_period"),
    ("control_period_nan", '{"control_period": NaN}', "control_period"),
    ("step_period_nan", '{"step_period": NaN}', "step_period"),
    ("step_period_inf", '{"step_period": Infinity}', "step_period"),
    ("step_period_text", '{"step_period": "x"}', "step_period"),
    ("step_period_null", '{"step_period": null}', "step_period"),
    ("lateral_steps_bool", '{"lateral_steps": true}', "lateral_steps"),
    ("unknown_key", '{"bogus": 1}', "bogus"),
    ("a_list", "[1, 2]", "expected a JSON object"),
    ("not_json", "{step_period: 1", "p.json"),
    ("latin1", '{"name": "h\xe9"}'.encode("latin-1"), "p.json"),
    ("empty", "", "p.json"),
]


@pytest.mark.parametrize("content, key", [c[1:] for c in PARAMS], ids=[c[0] for c in PARAMS])
def test_a_bad_params_file_is_refused(capsys, tmp_path, spec, content, key):
    params = tmp_path / "p.json"
    params.write_bytes(content if isinstance(content, bytes) else content.encode())
    refused(capsys, key, *_sweep(spec, tmp_path / "out", "--params", params))
    nothing_written(tmp_path / "out")


@pytest.mark.parametrize("option, content, key", [
    ("--model", '{"total_mass_kg": -1}', "total_mass_kg"),
    ("--model", '{"total_mass_kg": NaN}', "total_mass_kg"),
    ("--model", '{"bogus_m": 1}', "bogus_m"),
    ("--model", "[]", "m.json"),
])
def test_a_bad_model_file_is_refused(capsys, tmp_path, spec, option, content, key):
    model = tmp_path / "m.json"
    model.write_text(content)
    refused(capsys, key, *_sweep(spec, tmp_path / "out", option, model))
    nothing_written(tmp_path / "out")


@pytest.mark.parametrize("kind", ["folder", "missing"])
def test_a_params_path_that_is_no_file_is_named(capsys, tmp_path, spec, kind):
    params = tmp_path / "p.json"
    if kind == "folder":
        params.mkdir()
    line = refused(capsys, str(params), *_sweep(spec, tmp_path / "out", "--params", params))
    assert ("directory" in line.lower() or "folder" in line) if kind == "folder" else (
        "no such file" in line.lower() or "not found" in line)


# Multi-process arguments: (case id, extra options, environment, key)
PROCESSES = [
    ("num_zero", ["--num-processes", "0"], {}, "--num-processes"),
    ("num_negative", ["--num-processes", "-3"], {}, "--num-processes"),
    ("num_text", ["--num-processes", "two"], {}, "--num-processes"),
    ("num_huge", ["--num-processes", str(1 << 40)], {}, "--num-processes"),
    ("id_negative", ["--process-id", "-1"], {}, "--process-id"),
    ("id_past_num", ["--num-processes", "2", "--process-id", "2"], {}, "process_id"),
    ("id_equal_one", ["--process-id", "1"], {}, "process_id"),
    ("no_coordinator", ["--num-processes", "2", "--process-id", "0"], {}, "coordinator"),
    ("env_num_zero", [], {"TKUJAX_NUM_PROCESSES": "0"}, "TKUJAX_NUM_PROCESSES"),
    ("env_num_text", [], {"TKUJAX_NUM_PROCESSES": "many"}, "TKUJAX_NUM_PROCESSES"),
    ("env_id_text", [], {"TKUJAX_PROCESS_ID": "x"}, "TKUJAX_PROCESS_ID"),
    ("env_id_past", [], {"TKUJAX_PROCESS_ID": "1"}, "TKUJAX_PROCESS_ID"),
    ("max_chunks_zero", ["--max-chunks", "0"], {}, "--max-chunks"),
    ("backend_unknown", ["--backend", "cuda"], {}, "--backend"),
    ("decisions_unknown", ["--decisions", "soon"], {}, "--decisions"),
    ("decisions_early_on_c", ["--decisions", "early"], {}, "early"),
]


@pytest.mark.parametrize("extra, env, key", [c[1:] for c in PROCESSES],
                         ids=[c[0] for c in PROCESSES])
def test_bad_process_arguments_are_refused(capsys, monkeypatch, tmp_path, spec, extra, env, key):
    for name in ("TKUJAX_NUM_PROCESSES", "TKUJAX_PROCESS_ID", "TKUJAX_COORDINATOR"):
        monkeypatch.delenv(name, raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    refused(capsys, key, *_sweep(spec, tmp_path / "out", *extra))
    nothing_written(tmp_path / "out")


def _out_path(tmp_path: Path, kind: str) -> Path:
    if kind == "is_a_file":
        (tmp_path / "taken").write_text("a file")
        return tmp_path / "taken"
    if kind == "inside_a_file":
        (tmp_path / "taken").write_text("a file")
        return tmp_path / "taken" / "sub" / "out"
    return tmp_path / ("n" * 300)


@pytest.mark.parametrize("kind, says", [
    ("is_a_file", "not a folder"),
    ("inside_a_file", "not a folder"),
    ("name_too_long", "too long"),
])
def test_an_out_path_that_cannot_be_a_folder_is_named(capsys, tmp_path, spec, kind, says):
    out = _out_path(tmp_path, kind)
    line = refused(capsys, says, *_sweep(spec, out))
    assert ("taken" in line) if kind != "name_too_long" else ("nnnn" in line)
    if kind != "name_too_long":
        assert (tmp_path / "taken").read_text() == "a file"


@pytest.mark.parametrize("argv", [
    ("tune", ROOT / "specs/tune/tune_cpu.toml", "--out", "OUT"),
    ("compare", "SWEEP", "SWEEP", "--out", "OUT"),
    ("export", "SWEEP", "--format", "csv", "--out", "OUT/records.csv"),
], ids=["tune", "compare", "export"])
def test_other_commands_name_an_out_that_is_a_file(capsys, tmp_path, spec, argv):
    """Every command's --out (or its folder) where a file is: one line, "not a folder", the
    file untouched and nothing else written."""
    sweep = tmp_path / "sweep"
    assert run(capsys, *_sweep(spec, sweep))[0] == 0
    taken = _out_path(tmp_path, "is_a_file")
    argv = [str(a).replace("SWEEP", str(sweep)).replace("OUT", str(taken)) for a in argv]
    line = refused(capsys, "not a folder (a file has that name)", *argv)
    assert str(taken) in line and taken.read_text() == "a file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sweep", "taken", "tiny.toml"]


def test_a_bench_out_that_is_a_folder_is_named_before_any_stage(capsys, tmp_path):
    (tmp_path / "taken").mkdir()
    line = refused(capsys, "a folder has that name", "bench", "--out", tmp_path / "taken")
    assert str(tmp_path / "taken") in line and not any((tmp_path / "taken").iterdir())


def test_a_folder_that_refuses_writes_is_named(capsys, monkeypatch, tmp_path, spec):
    """A read-only --out (as root, which may write anywhere, the refusal is simulated where
    the folder is checked)."""
    out = tmp_path / "ro"
    out.mkdir()
    os.chmod(out, 0o555)
    if os.geteuid() == 0:
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == out
                            else real(p, mode))
    try:
        line = refused(capsys, "not writable", *_sweep(spec, out))
    finally:
        os.chmod(out, 0o755)
    assert str(out) in line
    nothing_written(out)


def test_a_model_and_a_robot_together_are_refused(capsys, tmp_path, spec):
    model = tmp_path / "m.json"
    model.write_text("{}")
    refused(capsys, "--model", *_sweep(spec, tmp_path / "out", "--model", model, "--robot",
                                       ROOT / "specs" / "robots" / "op3.toml"))


# Commands that read a sweep folder, given no sweep: (case id, argv builder, key)
def _readers(tmp_path: Path) -> dict:
    empty = tmp_path / "empty"
    empty.mkdir()
    (tmp_path / "file").write_text("x")
    return {
        "map_empty": (["map", empty], "holds no sweep"),
        "map_missing": (["map", tmp_path / "missing"], "holds no sweep"),
        "replay_empty": (["replay", empty, "--index", "0"], "holds no sweep"),
        "replay_file": (["replay", tmp_path / "file", "--index", "0"], "file"),
        "replay_index_text": (["replay", empty, "--index", "first"], "--index"),
        "compare_missing": (["compare", tmp_path / "a", tmp_path / "b", "--out",
                             tmp_path / "c"], str(tmp_path / "a")),
        "export_missing": (["export", tmp_path / "missing"], "missing"),
    }


READERS = ["map_empty", "map_missing", "replay_empty", "replay_file", "replay_index_text",
           "compare_missing", "export_missing"]


@pytest.mark.parametrize("case", READERS)
def test_reading_commands_name_what_is_missing(capsys, tmp_path, case):
    argv, key = _readers(tmp_path)[case]
    refused(capsys, key, *argv)


# Other commands' inputs: (case id, argv, key)
OTHERS = [
    ("paper_scale_zero", ["paper", "--impulse-scale", "0"], "impulse_scale"),
    ("paper_scale_nan", ["paper", "--impulse-scale", "nan"], "impulse_scale"),
    ("paper_variant", ["paper", "--variant", "guessed"], "--variant"),
    ("stand_engine", ["stand", "--engine", "bullet"], "--engine"),
    ("stand_perturb_nan", ["stand", "--perturb-deg", "nan"], "--perturb-deg"),
    ("stand_seed_negative", ["stand", "--seed", "-1"], "--seed"),
    ("stand_seed_65_bits", ["stand", "--seed", str(1 << 64)], "--seed"),
    ("tune_deadline_nan", ["tune", "specs/tune/tune_cpu.toml", "--out", "OUT", "--deadline-s",
                           "nan"], "--deadline-s"),
    ("islands_points_zero", ["islands", "--out", "OUT", "--points", "0"], "--points"),
    ("islands_refine_huge", ["islands", "--out", "OUT", "--refine", "99"], "--refine"),
    ("unknown_command", ["sweeps"], "sweeps"),
    ("tune_missing_spec", ["tune", "/no/such/tune.toml", "--out", "OUT"], "/no/such/tune.toml"),
    ("calibrate_missing_spec", ["calibrate", "/no/such/cal.toml", "--out", "OUT"],
     "/no/such/cal.toml"),
    ("converge_missing_spec", ["converge", "/no/such/conv.toml", "--out", "OUT"],
     "/no/such/conv.toml"),
    ("capture_missing_spec", ["capture", "/no/such/cap.toml", "--out", "OUT"],
     "/no/such/cap.toml"),
    ("fpga_missing_spec", ["fpga", "/no/such/fpga.toml", "--out", "OUT"], "/no/such/fpga.toml"),
]


@pytest.mark.parametrize("argv, key", [c[1:] for c in OTHERS], ids=[c[0] for c in OTHERS])
def test_other_commands_refuse_bad_input(capsys, tmp_path, argv, key):
    argv = [str(tmp_path / "out") if a == "OUT" else a for a in argv]
    refused(capsys, key, *argv)


# Other spec dialects with a bad key: (case id, dialect command, spec text, key)
DIALECTS = [
    ("tune_unknown_table", "tune", "[bogus]\na = 1\n", "bogus"),
    ("converge_unknown_table", "converge", "[bogus]\na = 1\n", "bogus"),
    ("calibrate_unknown_table", "calibrate", "[bogus]\na = 1\n", "bogus"),
    ("capture_seed_65_bits", "capture",
     TINY.replace("seed = 0", "seed = 18446744073709551616") + "[step.grid]\nx_m = [0.0]\n",
     "sweep.seed"),
    ("fpga_onset_past_horizon", "fpga", TINY.replace("onset_s = [0.1]", "onset_s = [0.5]"),
     "push.grid.onset_s"),
]


@pytest.mark.parametrize("command, text, key", [c[1:] for c in DIALECTS],
                         ids=[c[0] for c in DIALECTS])
def test_other_dialects_name_the_key(capsys, tmp_path, command, text, key):
    path = tmp_path / "spec.toml"
    path.write_text(text)
    refused(capsys, key, command, path, "--out", tmp_path / "out")
    nothing_written(tmp_path / "out")


def test_an_argparse_error_is_one_line(capsys, tmp_path, spec):
    line = refused(capsys, "--out", "sweep", spec)
    assert line.startswith("tkujax sweep: error:")


def test_the_params_file_control_period_message_names_both_periods(capsys, tmp_path, spec):
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"control_period": 0.02}))
    line = refused(capsys, "control_period", *_sweep(spec, tmp_path / "out", "--params", params))
    assert "0.02" in line and "0.03" in line


# Robot files through the command line (a few: the robot loader has its own tests):
# (case id, edit of specs/robots/op3.toml's text or a kind of file, key)
ROBOT_FILES = [
    ("missing_foot", lambda t: t.replace('foot = "l_ank_roll_link"', ""), "legs.left"),
    ("role_twice", lambda t: t.replace('knee = "l_knee"', 'knee = "l_hip_yaw"'), "legs.left.knee"),
    ("unknown_key", lambda t: t + "\nbogus = 1\n", "bogus"),
    ("folder", "folder", "is a folder"),
    ("latin1", "latin1", "not UTF-8"),
]


@pytest.mark.parametrize("edit, key", [c[1:] for c in ROBOT_FILES],
                         ids=[c[0] for c in ROBOT_FILES])
def test_a_bad_robot_file_is_named(capsys, tmp_path, spec, edit, key):
    models = ROOT.parent / "shared" / "models"
    if not (models / "robotis_op3").is_dir():
        pytest.skip("the OP3 model (shared/models/robotis_op3) is not on this machine")
    robot = tmp_path / "robot.toml"
    text = (ROOT / "specs/robots/op3.toml").read_text().replace(
        "${TKUJAX_MENAGERIE:-../../../shared/models}", str(models))
    for beside in (ROOT / "specs/robots").glob("*.json"):      # files the robot file names
        (tmp_path / beside.name).write_bytes(beside.read_bytes())
    if edit == "folder":
        robot.mkdir()
    elif edit == "latin1":
        robot.write_bytes(text.replace("robotis_op3", "robotis_\xe9").encode("latin-1"))
    else:
        robot.write_text(edit(text))
    refused(capsys, key, *_sweep(spec, tmp_path / "out", "--robot", robot))
    nothing_written(tmp_path / "out")
