"""Scheduled policies as files (`tkujax sweep --params POLICY.json`): the file's round trip and
validation, and the sweep running the schedule. The reference: an MLP schedule whose hidden
layer is zero corrects its fields by the constant b2, so it must run exactly like the plain
controller with those fields set to map(z_base + b2), computed here in numpy."""

from __future__ import annotations

import dataclasses
import json
import math

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.params_files import (load_controller_params_json, load_policy_json,
                                         save_policy_json)
from tkujax.control.controller_params import ControllerParams
from tkujax.control.policy import Schedule, schedule_to_dict
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.sweep import load, run_sweep

FIELDS = ("cp_gain", "step_period")
LO, HI = (0.5, 0.1), (4.0, 0.5)
B2 = (1.5, -1.0)                       # latent corrections: a larger gain, a shorter step


def _logit(v, lo, hi):
    u = (v - lo) / (hi - lo)
    return math.log(u / (1 - u))


def _constant_mlp(base: ControllerParams, b2=B2, width=3) -> Schedule:
    z_base = [_logit(getattr(base, f), lo, hi) for f, lo, hi in zip(FIELDS, LO, HI)]
    return Schedule(z_base=jnp.asarray(z_base, jnp.float32),
                    w1=jnp.zeros((4, width)), b1=jnp.zeros(width),
                    w2=jnp.zeros((width, len(FIELDS))), b2=jnp.asarray(b2, jnp.float32),
                    kind="mlp", fields=FIELDS, lo=LO, hi=HI, log=(False, False))


def _shifted_plain(base: ControllerParams, b2=B2) -> ControllerParams:
    """The plain controller the constant schedule must equal: map(z_base + b2), in numpy."""
    vals = {}
    for f, lo, hi, b in zip(FIELDS, LO, HI, b2):
        z = _logit(getattr(base, f), lo, hi) + b
        vals[f] = lo + (hi - lo) / (1 + math.exp(-z))
    return dataclasses.replace(base, **vals)


def test_round_trip_sectors_and_mlp(tmp_path):
    base = ControllerParams.recommended()
    rng = np.random.default_rng(0)
    sectors = Schedule(z_base=jnp.asarray([0.1, -0.2]), table=jnp.asarray(rng.normal(size=(4, 2))),
                       kind="sectors", fields=FIELDS, lo=LO, hi=HI, log=(False, False),
                       sharpness=3.0)
    for sched in (sectors, _constant_mlp(base)):
        path = save_policy_json(base, sched, tmp_path / f"{sched.kind}.json", source="a test")
        params, back = load_policy_json(path)
        assert params == base
        assert json.loads(path.read_text())["source"] == "a test"
        a, b = schedule_to_dict(sched), schedule_to_dict(back)
        assert a.keys() == b.keys()
        for k in a:
            if k in ("kind", "fields", "log"):
                assert a[k] == b[k], k
                continue
            np.testing.assert_allclose(np.asarray(a[k], float), np.asarray(b[k], float),
                                       rtol=1e-6, err_msg=k)
    # A plain parameter file loads as (params, None); a policy file is refused by the loader
    # that would drop its schedule.
    plain = save_policy_json(base, None, tmp_path / "plain.json")
    assert load_policy_json(plain) == (base, None)
    with pytest.raises(ValueError, match=r"holds a scheduled policy \(key 'schedule'\)"):
        load_controller_params_json(tmp_path / "mlp.json")
    with pytest.raises(ValueError, match="--params recommended: .* is scheduled"):
        load_controller_params_json("recommended")


@pytest.mark.parametrize("patch, match", [
    (dict(kind="tree"), r"schedule.kind: expected one of \['mlp', 'mlpr', 'sectors'\], got 'tree'"),
    (dict(fields=["kalman_q", "step_period"]), r"schedule.fields: 'kalman_q' cannot be sched"),
    (dict(b2=[1.0, 2.0, 3.0]), r"schedule.b2: expected a 1-d array, last axis 2, got shape"),
    (dict(w1=[[0.0] * 3] * 3), r"schedule.w1: expected shape \(4, H\)"),
    (dict(lo=[0.5, 0.6]), r"schedule: expected lo < hi"),
    (dict(z_base=[0.0, float("nan")]), r"schedule.z_base: every value must be finite"),
    (dict(table=[[0.0]]), r"schedule: unknown key\(s\) \['table'\]"),
    (dict(sharpness=0), r"schedule.sharpness: expected a number in \(0, 100\], got 0"),
])
def test_bad_policy_files_name_the_key(tmp_path, patch, match):
    data = dict(controller=dataclasses.asdict(ControllerParams.recommended()),
                schedule=schedule_to_dict(_constant_mlp(ControllerParams.recommended())))
    data["schedule"].update(patch)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=match):
        load_policy_json(path)


def _spec() -> dict:
    # Pushes the controller steps after (from behind and in front, control on), 1.5 s.
    return {"sweep": {"name": "policy", "seed": 0, "chunk_size": 4, "duration_s": 1.5,
                      "control": ["on"]},
            "push": {"grid": {"impulse_ns": [1.2, 1.8], "azimuth_deg": [0, 180],
                              "onset_s": [0.3]}}}


def test_mujoco_sweep_runs_the_schedule(tmp_path):
    """MuJoCo C backend: the constant schedule runs as the shifted plain controller (same
    falls, same steps to 1 mm), and unlike the unshifted one; the manifest records the schedule
    and a different policy is a different sweep."""
    base = ControllerParams.recommended()
    spec = parse_spec(_spec())
    sched = _constant_mlp(base)
    run_sweep(spec, tmp_path / "sched", params=base, schedule=sched, quiet=True,
              backend="mujoco")
    run_sweep(spec, tmp_path / "shifted", params=_shifted_plain(base), quiet=True,
              backend="mujoco")
    run_sweep(spec, tmp_path / "plain", params=base, quiet=True, backend="mujoco")
    s, sh, p = (load(tmp_path / n) for n in ("sched", "shifted", "plain"))
    np.testing.assert_array_equal(s["fell"], sh["fell"])
    np.testing.assert_allclose(s["step_length_m"], sh["step_length_m"], atol=1e-3)
    assert np.nanmax(np.abs(s["step_length_m"] - p["step_length_m"])) > 5e-3
    manifest = json.loads((tmp_path / "sched" / "manifest.json").read_text())
    assert manifest["schedule"]["kind"] == "mlp" and manifest["schedule"]["b2"] == list(B2)
    with pytest.raises(SpecError, match="holds another spec's sweep"):
        run_sweep(spec, tmp_path / "sched", params=base, schedule=_constant_mlp(base, (0.5, 0.5)),
                  quiet=True, backend="mujoco")
    fixed = parse_spec(_spec() | {"controller": {"arithmetic": "fixed"}})
    with pytest.raises(SpecError, match="no fixed-point controller twin"):
        run_sweep(fixed, tmp_path / "fx", params=base, schedule=sched, quiet=True)


@pytest.mark.slow
def test_mjx_sweep_runs_the_schedule(tmp_path):
    """MJX: the constant schedule runs as the shifted plain controller (same falls, steps to
    1 mm), and falls where MuJoCo C (an independent physics) falls with the same policy."""
    base = ControllerParams.recommended()
    spec = parse_spec(_spec())
    sched = _constant_mlp(base)
    run_sweep(spec, tmp_path / "mjx", params=base, schedule=sched, quiet=True, backend="mjx")
    run_sweep(spec, tmp_path / "shifted", params=_shifted_plain(base), quiet=True,
              backend="mjx")
    run_sweep(spec, tmp_path / "c", params=base, schedule=sched, quiet=True, backend="mujoco")
    m, sh, c = (load(tmp_path / n) for n in ("mjx", "shifted", "c"))
    np.testing.assert_array_equal(m["fell"], sh["fell"])
    np.testing.assert_allclose(m["step_length_m"], sh["step_length_m"], atol=1e-3)
    np.testing.assert_array_equal(m["fell"], c["fell"])


def test_recommended_policy_is_the_study_best_and_runs_by_name(tmp_path):
    """`recommended_policy()` / `--params recommended`: the shipped file is the re-tune's best
    policy (results/tune_policy_current/best_policy.json, whose held-out evaluation promoted
    it), an 8-sector schedule of 8 fields that really moves them; a sweep runs it by
    name (MuJoCo C) and records the schedule, and it steps differently from the scalar set."""
    from pathlib import Path

    from tkujax.cli import main
    from tkujax.control.params_files import recommended_policy
    from tkujax.control.policy import schedule_to_dict

    params, sched = recommended_policy()
    study_params, study_sched = load_policy_json(
        Path(__file__).parents[1] / "results/tune_policy_current/best_policy.json")
    assert dataclasses.asdict(params) == dataclasses.asdict(study_params)
    assert schedule_to_dict(sched) == schedule_to_dict(study_sched)
    assert sched.kind == "sectors" and np.shape(sched.table) == (8, 8)
    assert np.max(np.abs(np.asarray(sched.table))) > 0.1          # a real schedule, not zeros
    assert load_policy_json("recommended")[1].kind == "sectors"
    spec_path = tmp_path / "spec.toml"
    spec_path.write_text('[sweep]\nname = "t"\nseed = 0\nduration_s = 1.2\ncontrol = ["on"]\n'
                         '[push.grid]\nimpulse_ns = [1.9]\nazimuth_deg = [90, 270]\n'
                         'onset_s = [0.3]\n')
    assert main(["sweep", str(spec_path), "--out", str(tmp_path / "pol"), "--params",
                 "recommended", "--backend", "mujoco"]) == 0
    manifest = json.loads((tmp_path / "pol" / "manifest.json").read_text())
    assert manifest["schedule"]["kind"] == "sectors"
    run_sweep(parse_spec(_read(spec_path)), tmp_path / "scalar",
              params=ControllerParams.recommended(), quiet=True, backend="mujoco")
    pol, scalar = load(tmp_path / "pol"), load(tmp_path / "scalar")
    assert not np.allclose(np.nan_to_num(pol["step_length_m"]),
                           np.nan_to_num(scalar["step_length_m"]), atol=1e-3)
    # `tkujax replay` re-simulates a policy sweep's record with its schedule (from the
    # manifest), so it reproduces the record, also where the scalar set would step otherwise.
    from tkujax.sweeps.replay import replay

    for i in range(len(pol["fell"])):
        assert replay(tmp_path / "pol", i)["identical"], i


def _read(path):
    import tomllib

    return tomllib.loads(path.read_text())


def test_paper_cases_run_the_schedule():
    """`tkujax paper --params POLICY` path (run_cases -> simulate on MJX): the constant MLP
    schedule runs the paper's 8 cases exactly as the plain controller with its fields shifted
    (same falls, steps to 1 mm), and unlike the unshifted controller."""
    from tkujax.studies import paper

    base = ControllerParams.recommended()
    _, _, sched, _ = paper.run_cases(base, schedule=_constant_mlp(base))
    _, _, shifted, _ = paper.run_cases(_shifted_plain(base))
    _, _, plain, _ = paper.run_cases(base)
    np.testing.assert_array_equal(sched["fell"], shifted["fell"])
    np.testing.assert_allclose(sched["step_length_m"], shifted["step_length_m"], atol=1e-3)
    assert np.nanmax(np.abs(sched["peak_incl_deg"] - plain["peak_incl_deg"])) > 1e-3
