"""Tunes checked before anything is simulated, as sweeps are: a push its horizon cannot hold
(the training horizon or the held-out one), a generation, an evaluation grid or a held-out set
above the record limit; `tkujax tune --robot` checks its stages' pushes before the probe runs.
Each case: exit 2, one line naming the key, nothing simulated."""

from __future__ import annotations

import tomllib

import pytest
from hostile_helpers import refused

from tkujax.studies import robot_tune, robot_tune_specs
from tkujax.dialects.push_limits import MAX_RECORDS
from tkujax.studies.tune.tune_spec import parse_tune_spec
from tkujax.dialects.validation import SpecError

TUNE = """
[tune]
name = "hostile_tune"
iterations = 1
batch = 8
popsize = 3
duration_s = 1.0

[push]
impulse_ns = {uniform = [0.2, 1.0]}
onset_s = 0.5
duration_s = 0.02

[evaluate]
n = 8
"""


def _spec(**edits) -> dict:
    data = tomllib.loads(TUNE)
    for path, value in edits.items():
        table, key = path.split("__")
        data.setdefault(table, {})[key] = value
    return data


@pytest.mark.parametrize("edits, key", [
    # onset 0.5 s + a 0.6 s pulse ends after the 1 s horizon (the onset alone fits)
    (dict(push__duration_s=0.5, tune__duration_s=0.9), "push.onset_s + push.duration_s"),
    (dict(push__onset_s=2.0), "push.onset_s"),                       # onset after the horizon
    (dict(evaluate__duration_s=0.51), "evaluate.duration_s"),        # the held-out horizon
    (dict(evaluate__duration_s=0.52, push__duration_s=0.05), "evaluate.duration_s"),
    (dict(tune__batch=1 << 20, tune__popsize=9), "tune.popsize x tune.batch"),
    (dict(evaluate__impulse_ns={"start": 0.1, "stop": 2.0, "num": 1_000_000},
          evaluate__azimuth_deg={"start": 0.0, "stop": 350.0, "num": 1_000_000}),
     "evaluate.impulse_ns x evaluate.azimuth_deg"),
    (dict(evaluate__n=MAX_RECORDS + 1), "evaluate.n"),
])
def test_a_tune_spec_beyond_its_limits_is_refused(edits, key):
    with pytest.raises(SpecError, match=key.replace("+", r"\+")) as err:
        parse_tune_spec(_spec(**edits))
    if "x" in key or key == "evaluate.n":
        assert f"{MAX_RECORDS:,}" in str(err.value)
    else:
        assert "horizon" in str(err.value) or "no time after" in str(err.value)


def test_the_shipped_limits_leave_the_example_valid():
    assert parse_tune_spec(_spec()).eval_n == 8          # the checks do not refuse a sound spec


def test_cli_tune_refuses_before_simulating(capsys, tmp_path):
    spec = tmp_path / "t.toml"
    spec.write_text(TUNE.replace("onset_s = 0.5", "onset_s = 0.99"))
    out = tmp_path / "out"
    line = refused(capsys, "push.onset_s", "tune", spec, "--out", out)
    assert "tune.duration_s = 1" in line
    assert not out.exists() or not any(out.iterdir())


def test_tune_robot_checks_its_stages_before_the_probe(capsys, monkeypatch, tmp_path):
    """A stage whose pushes its horizon cannot hold (here the tune stage's horizon shortened
    below its onsets) is refused before the probe simulates anything."""
    from tkujax.robot.builtin import write_generated_robot

    robot_file = write_generated_robot(tmp_path / "robot", name="second")

    def no_probe(*args, **kwargs):
        raise AssertionError("the probe ran before the stages were checked")

    monkeypatch.setattr(robot_tune, "robot_pushes", no_probe)
    monkeypatch.setattr(robot_tune_specs, "TUNE_HORIZON_S", 0.42)
    out = tmp_path / "out"
    line = refused(capsys, "tune.duration_s = 0.42", "tune", "--robot", robot_file, "--out", out)
    assert "push.onset_s" in line and not (out / "pushes.json").exists()
    monkeypatch.setattr(robot_tune_specs, "TUNE_HORIZON_S", robot_tune_specs.HELDOUT_HORIZON_S)
    robot = robot_tune.robot_from_file(str(robot_file))
    robot_tune_specs.check_stages(str(robot_file), robot, 64)           # the shipped stages pass


def test_a_tune_into_another_specs_folder_is_refused(capsys, tmp_path):
    """Two tunes of different specs into one --out: the second is refused before it simulates,
    the first's outputs untouched; a rerun of the same spec passes the check."""
    import json

    from tkujax.studies.tune.tune_command import check_out

    out = tmp_path / "out"
    out.mkdir()
    first = json.dumps({"name": "t", "spec": _spec(tune__batch=6)})
    (out / "history.json").write_text(first)
    spec = tmp_path / "t.toml"
    spec.write_text(TUNE)
    line = refused(capsys, "holds another spec's tune", "tune", spec, "--out", out)
    assert str(out) in line
    assert (out / "history.json").read_text() == first and len(list(out.iterdir())) == 1
    (out / "history.json").write_text(json.dumps({"spec": _spec()}))
    check_out(out, parse_tune_spec(_spec()))


def test_tune_robot_refuses_the_stages_of_another_robot(capsys, monkeypatch, tmp_path):
    import json

    from tkujax.robot.builtin import write_generated_robot

    robot_file = write_generated_robot(tmp_path / "robot", name="second")
    out = tmp_path / "out"
    out.mkdir()
    held = dict(robot="other", robot_file="/elsewhere/other.toml", robot_sha256="0" * 64)
    (out / "robot.json").write_text(json.dumps(held))
    (out / "pushes.json").write_text("{}")

    def no_probe(*args, **kwargs):
        raise AssertionError("a stage ran on another robot's folder")

    monkeypatch.setattr(robot_tune, "robot_pushes", no_probe)
    monkeypatch.setattr(robot_tune, "choose_structure", no_probe)
    line = refused(capsys, "holds the stages of robot 'other'", "tune", "--robot", robot_file,
                   "--out", out)
    assert str(out) in line and "0" * 64 in line
    assert json.loads((out / "robot.json").read_text()) == held
    assert sorted(p.name for p in out.iterdir()) == ["pushes.json", "robot.json"]
