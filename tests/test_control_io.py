"""ControllerParams from JSON and spec-style values (tkujax.control.params_files): ranges are
ControllerParams.validate's, and errors name the key and the range."""

import dataclasses
import json
import math

import pytest

from tkujax.control.params_files import (allowed_range, checked_value, controller_params_from,
                                         controller_params_from_dict, load_controller_params_json,
                                         save_controller_params_json)
from tkujax.control.controller_params import ControllerParams


def test_allowed_range_is_what_validate_says():
    assert allowed_range("step_period") == "(0, 2] s"
    assert allowed_range("eps_forward") == "[0, pi/2) rad"
    with pytest.raises(ValueError, match=r"step_period must be in \(0, 2\] s"):
        dataclasses.replace(ControllerParams(), step_period=3.0).validate()


def test_checked_value_degrees_and_errors():
    assert checked_value("w", "eps_forward_deg", 12) == 12.0
    with pytest.raises(ValueError, match=r"^w: 95 deg is out of range: .*eps_forward must be"):
        checked_value("w", "eps_forward_deg", 95)
    with pytest.raises(ValueError, match=r"^w: expected a number, .*step_period in \(0, 2\] s"):
        checked_value("w", "step_period", True)
    with pytest.raises(ValueError, match=r"^w: 'T_deg' names no ControllerParams field"):
        checked_value("w", "T_deg", 1.0)


def test_overrides_convert_degrees():
    p = controller_params_from(ControllerParams(), {"eps_forward_deg": 10.0, "cp_gain": 2.0})
    assert p.eps_forward == pytest.approx(math.radians(10.0)) and p.cp_gain == 2.0


def test_dict_and_json_round_trip(tmp_path):
    paper = ControllerParams.paper()
    tuned = dataclasses.replace(paper, step_period=0.25, kalman_q=1e-4)
    path = save_controller_params_json(tuned, tmp_path / "p.json")
    assert load_controller_params_json(path) == tuned
    partial = controller_params_from_dict({"step_period": 0.25}, "here")
    assert partial == dataclasses.replace(paper, step_period=0.25)     # the rest: the paper's
    base = ControllerParams()
    assert controller_params_from_dict({}, "here", base=base) == base
    with pytest.raises(ValueError, match=r"here: unknown field\(s\) \['T'\]"):
        controller_params_from_dict({"T": 0.3}, "here")
    with pytest.raises(ValueError, match=r"here: .*step_period must be in \(0, 2\] s, got 5.0"):
        controller_params_from_dict({"step_period": 5}, "here")
    (tmp_path / "bad.json").write_text("{")
    with pytest.raises(ValueError, match="cannot read JSON"):
        load_controller_params_json(tmp_path / "bad.json")
    assert json.loads(path.read_text())["step_period"] == 0.25


def test_a_params_file_restates_the_control_period_never_changes_it(tmp_path):
    """One source for the period: the controller ticks at the rollout's period
    (RolloutConfig.control_period_s), so a file giving another control_period is refused,
    naming the key and the period; the same period loads."""
    from tkujax.sim.options import RolloutConfig

    same = tmp_path / "same.json"
    same.write_text(json.dumps({"control_period": 0.03, "cp_gain": 1.5}))
    loaded = load_controller_params_json(same)
    assert loaded.control_period == RolloutConfig().control_period_s == 0.03
    assert loaded.cp_gain == 1.5
    for period in (0.02, 0.0300001, 0.06):
        other = tmp_path / "other.json"
        other.write_text(json.dumps({"control_period": period}))
        with pytest.raises(ValueError, match=r"other.json: .*control_period must be in \{0.03\}"):
            load_controller_params_json(other)
    with pytest.raises(ValueError, match="controller: 0.02 is out of range: .*control_period"):
        checked_value("controller", "control_period", 0.02)


def _shipped_params_files():
    """(path, {field: value}) of every parameter or policy file in specs/, results/ and the
    package (a JSON object whose keys, or whose policy's "controller" keys, are fields)."""
    from pathlib import Path

    from tkujax.control.params_files import PARAMS_NOTE_KEYS, RECOMMENDED_POLICY_PATH, is_policy

    repo = Path(__file__).resolve().parents[1]
    fields = {f.name for f in dataclasses.fields(ControllerParams)}
    paths = [*repo.glob("specs/**/*.json"), *repo.glob("results/**/*.json"),
             RECOMMENDED_POLICY_PATH]
    for path in sorted(paths):
        data = json.loads(path.read_text())
        values = data.get("controller") if is_policy(data) else data
        if isinstance(values, dict) and values and \
                set(values) - set(PARAMS_NOTE_KEYS) <= fields:
            yield path, {k: v for k, v in values.items() if k in fields}


def test_every_shipped_params_file_loads_as_written():
    """Parameter files keep loading (the period among them restated as 0.03): each field
    the file gives is its number, the others the paper's."""
    from tkujax.control.params_files import load_policy_json

    found = list(_shipped_params_files())
    assert len(found) >= 8, [str(p) for p, _ in found]
    paper = ControllerParams.paper()
    for path, values in found:
        params, _ = load_policy_json(path)
        for f in dataclasses.fields(ControllerParams):
            want = values.get(f.name, getattr(paper, f.name))
            assert getattr(params, f.name) == float(want), (path, f.name)


def test_the_field_groups_partition_the_params_by_meaning():
    """Each field in one group; the geometry is what the model gives (two models' paper
    controllers differ there only); the modes are discrete (validate refuses a blend)."""
    from tkujax.control.controller_params import (GAIN_FIELDS, GEOMETRY_FIELDS, MODE_FIELDS,
                                                  PHYSICAL_FIELDS, TIMING_FIELDS)
    from tkujax.model import ModelParams

    groups = TIMING_FIELDS + PHYSICAL_FIELDS + GEOMETRY_FIELDS + MODE_FIELDS + GAIN_FIELDS
    assert sorted(groups) == sorted(f.name for f in dataclasses.fields(ControllerParams))
    longer = dataclasses.replace(ModelParams(), thigh_length_m=0.125, calf_length_m=0.12)
    a, b = ControllerParams.paper(), ControllerParams.paper(longer)
    changed = {f.name for f in dataclasses.fields(a) if getattr(a, f.name) != getattr(b, f.name)}
    assert changed and changed <= set(GEOMETRY_FIELDS), changed
    for name in MODE_FIELDS:
        with pytest.raises(ValueError, match=f"ControllerParams.{name} must be in {{"):
            dataclasses.replace(ControllerParams(), **{name: 1.5}).validate()
