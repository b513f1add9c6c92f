"""`tune.start_policy` (tkujax.studies.tune.start_policy): a tune that starts at a policy file.
The start latent is the file's schedule bit for bit and its controller to float32 rounding;
the controller alone (no physics) gives the file's leg targets at that latent; a file whose
layout is not the spec's, a [controller] beside it, a plain parameter file and a robot file
are refused naming the key; and specs/tune/tune_policy_current.toml parses as its header says.
Seconds on a CPU: nothing here compiles MJX."""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller import Sensors, controller_init, controller_step
from tkujax.control.params_files import recommended_policy, save_policy_json
from tkujax.dialects.sweep_spec import SpecError, read_toml
from tkujax.studies.tune import parse_tune_spec, sample_pushes
from tkujax.studies.tune.start_policy import schedule_latents, start_latent

ROOT = Path(__file__).resolve().parents[1]
SPEC = ROOT / "specs" / "tune" / "tune_policy_current.toml"


def _raw(**tune) -> dict:
    """The shipped spec without its ensemble (no file to read) and with `tune` keys set."""
    raw = copy.deepcopy(read_toml(SPEC))
    raw["randomize"].pop("ensemble")
    raw["tune"].update(tune)
    return raw


def _imu(n=20, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    gyro = np.stack([-0.9 + 0.3 * np.sin(t), 0.5 * np.cos(t), 0.0 * t], -1)
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.5, (n, 3))
    return jnp.asarray(gyro + rng.normal(0, 0.1, (n, 3))), jnp.asarray(accel)


def _targets(params, schedule):
    """(n, 12) leg targets of the controller alone over a synthetic push (float32)."""
    gyro, accel = _imu()
    state = controller_init(params, jnp.float32)

    def body(s, x):
        s, out = controller_step(s, Sensors(x[0].astype(jnp.float32), x[1].astype(jnp.float32)),
                                 params, 1.0, None, schedule)
        return s, out.leg_targets

    return np.asarray(jax.lax.scan(body, state, (gyro, accel))[1])


def test_the_start_is_the_recommended_policy():
    spec = parse_tune_spec(_raw())
    rep = spec.policy_reparam()
    z0 = start_latent(spec, rep)
    params, schedule = recommended_policy()
    assert rep.size == 80 and z0.shape == (80,)
    got = rep.schedule(z0)
    np.testing.assert_array_equal(np.asarray(got.table), np.asarray(schedule.table))
    np.testing.assert_array_equal(np.asarray(got.z_base), np.asarray(schedule.z_base))
    assert (got.fields, got.lo, got.hi, got.log, got.sharpness) == (
        schedule.fields, schedule.lo, schedule.hi, schedule.log, schedule.sharpness)
    values = dataclasses.asdict(rep.params_np(spec.base_params(), z0))
    for f, v in dataclasses.asdict(params).items():
        assert np.float32(values[f]) == pytest.approx(np.float32(v), rel=2.5e-7, abs=1e-12), f
    # The controller at the start latent (as the tuner runs it) against the file's policy.
    z32 = jnp.asarray(z0, jnp.float32)
    tuned = _targets(rep.apply(spec.base_params(), z32), rep.schedule(z32))
    shipped = _targets(params, schedule)
    # float32 rounding: measured 1.07e-6 rad (2.4e-7 with the policy before its re-tune)
    assert np.abs(tuned - shipped).max() < 2e-6
    # A correction of one sector entry moves the targets: the table is live.
    z1 = z0.copy()
    z1[rep.k] += 1.0
    z1 = jnp.asarray(z1, jnp.float32)
    assert np.abs(_targets(rep.apply(spec.base_params(), z1), rep.schedule(z1))
                  - shipped).max() > 1e-4


def test_without_start_policy_the_start_is_unchanged():
    """No start_policy: [controller] and zero corrections, as before."""
    raw = _raw()
    raw["tune"].pop("start_policy")
    params, _ = recommended_policy()
    raw["controller"] = {f: getattr(params, f) for f in raw["tune"]["params"]}
    spec = parse_tune_spec(raw)
    rep = spec.policy_reparam()
    np.testing.assert_array_equal(start_latent(spec, rep), rep.latent_of(spec.base_params()))
    assert spec.start_schedule is None and spec.start_policy is None


def test_a_policy_file_path_round_trips(tmp_path):
    params, schedule = recommended_policy()
    path = save_policy_json(params, schedule, tmp_path / "p.json")
    spec = parse_tune_spec(_raw(start_policy=str(path)))
    ref = parse_tune_spec(_raw())
    np.testing.assert_array_equal(start_latent(spec, spec.policy_reparam()),
                                  start_latent(ref, ref.policy_reparam()))
    assert schedule_latents(schedule).size == 64


@pytest.mark.parametrize("change, match", [
    (dict(policy="sectors4"), "size"),
    (dict(policy="mlp"), "kind"),
    (dict(sharpness=2.0), "sharpness"),
    (dict(schedule=["step_period", "cp_gain", "cp_trigger_forward_m", "cp_trigger_backward_m",
                    "cp_trigger_lateral_m", "stance_ankle_kp", "stance_roll_kp",
                    "stance_hip_kp"]), "fields"),
])
def test_another_layout_is_refused(change, match):
    with pytest.raises(SpecError, match=f"tune.start_policy: the policy file's {match}"):
        parse_tune_spec(_raw(**change))


def test_other_ranges_and_study_policies_are_refused():
    raw = _raw()
    raw["tune"]["ranges"]["cp_gain"] = [0.5, 5.0]
    with pytest.raises(SpecError, match="tune.start_policy: the policy file's hi"):
        parse_tune_spec(raw)
    raw = _raw()
    raw["study"]["policies"] = ["sectors8", "mlp"]
    with pytest.raises(SpecError, match=r"study.policies\[1\] = 'mlp'"):
        parse_tune_spec(raw)


def test_bad_values_name_the_key(tmp_path):
    raw = _raw()
    raw["controller"] = {"cp_gain": 2.0}
    with pytest.raises(SpecError, match=r"tune.start_policy: the policy file gives the whole"):
        parse_tune_spec(raw)
    with pytest.raises(SpecError, match="tune.start_policy: --params .*cannot read"):
        parse_tune_spec(_raw(start_policy=str(tmp_path / "missing.json")))
    plain = tmp_path / "plain.json"
    plain.write_text(json.dumps(dataclasses.asdict(recommended_policy()[0])))
    with pytest.raises(SpecError, match="holds no schedule"):
        parse_tune_spec(_raw(start_policy=str(plain)))
    with pytest.raises(SpecError, match="tune.start_policy: expected a policy file"):
        parse_tune_spec(_raw(start_policy=3))
    # A file whose controller is not its z_base mapped onto the range.
    params, schedule = recommended_policy()
    moved = save_policy_json(dataclasses.replace(params, cp_gain=params.cp_gain * 0.9),
                             schedule, tmp_path / "moved.json")
    with pytest.raises(SpecError, match="controller value of cp_gain"):
        parse_tune_spec(_raw(start_policy=str(moved)))


def test_a_robot_file_refuses_it():
    from tkujax.studies.tune.robot_table import on_robot

    spec = parse_tune_spec(_raw())

    class Robot:                        # the checks before the robot's values are read
        source = "robots/x.toml"
        builtin = False                 # a robot file

    with pytest.raises(SpecError, match="tune.start_policy: a policy file is TKU-X's"):
        on_robot(spec, Robot())


def test_the_shipped_spec(monkeypatch):
    """specs/tune/tune_policy_current.toml: today's default robot (no [model]), the 39-member
    ensemble, w_harm 2, impulses 0.2-2.8 N s, pushes from behind weighted twice, sep-CMA-ES and
    the line search at one budget with compile included, validation selection."""
    monkeypatch.chdir(ROOT)
    spec = parse_tune_spec(read_toml(SPEC))
    assert spec.model == {} and spec.robot is None
    assert spec.ensemble.n == 39 and spec.loss.w_harm == 2.0
    assert spec.push["impulse_ns"] == (0.2, 2.8) and spec.start_policy == "recommended"
    st = spec.study
    assert st["methods"] == ["sepcma", "linesearch"] and st["policies"] == ["sectors8"]
    assert st["budget_includes_compile"] and st["select"] == "validation"
    az = sample_pushes(spec, 9000, 5)["azimuth_deg"] % 360.0
    behind = np.mean((az < 22.5) | (az >= 337.5))
    side = np.mean((az >= 67.5) & (az < 112.5))
    assert behind == pytest.approx(2 / 9, abs=0.01) and side == pytest.approx(1 / 9, abs=0.01)


def test_the_outputs_record_the_file(tmp_path):
    import hashlib

    from tkujax.control.params_files import RECOMMENDED_POLICY_PATH
    from tkujax.studies.tune.start_policy import start_record

    rec = start_record(parse_tune_spec(_raw()))
    assert rec["value"] == "recommended" and Path(rec["resolved"]) == RECOMMENDED_POLICY_PATH
    assert rec["sha256"] == hashlib.sha256(RECOMMENDED_POLICY_PATH.read_bytes()).hexdigest()
    raw = _raw()
    raw["tune"].pop("start_policy")
    params, _ = recommended_policy()
    raw["controller"] = {f: getattr(params, f) for f in raw["tune"]["params"]}
    assert start_record(parse_tune_spec(raw)) is None
