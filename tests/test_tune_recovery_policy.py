"""The MLP policy with recovery inputs ("mlprH", tkujax.control.policy.recovery_inputs): its size,
its inputs in a known situation, its exact start at the unscheduled controller (the controller
alone and one tiny MJX batch), finite gradients through it, the policy file and the spec.

The controller-level checks run the controller alone over a fixed synthetic IMU sequence of a
forward fall (no physics: seconds on a CPU); the `slow` test compiles one tiny MJX batch."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller import (NOT_STARTED_S, Sensors, controller_init, controller_step,
                                       with_timing_gradient)
from tkujax.control.params_files import load_policy_json, save_policy_json
from tkujax.control.controller_params import ControllerParams
from tkujax.control.policy import (RECOVERY_TIME_MAX_S, RECOVERY_TIME_SCALE_S, recovery_inputs,
                                   schedule_to_dict)
from tkujax.dialects.sweep_spec import SpecError, read_toml
from tkujax.studies.tune import Reparam, parse_tune_spec
from tkujax.studies.tune.parameterisations import PolicyReparam, parse_policy

FIELDS = ("step_period", "cp_gain", "cp_trigger_forward_m", "cp_trigger_backward_m",
          "stance_ankle_kp", "stance_hip_kp", "stance_roll_kp")
RANGES = dict(step_period=(0.1, 0.5), cp_gain=(0.5, 4.0), cp_trigger_backward_m=(0.02, 0.3),
              stance_ankle_kp=(-0.5, 1.0), stance_hip_kp=(-1.0, 1.0),
              stance_roll_kp=(-0.5, 1.0))
SCHEDULE = ("step_period", "cp_gain", "stance_ankle_kp", "stance_hip_kp")
N_TICKS = 24


def _rep(policy: str = "mlpr4") -> PolicyReparam:
    return PolicyReparam.make(Reparam.make(FIELDS, RANGES), policy, SCHEDULE)


def _imu(n=N_TICKS):
    """A forward fall as the IMU would report it: a growing pitch rate (rad/s), gravity."""
    t = np.arange(n)
    gyro = np.stack([0.5 + 0.5 * t, 0.05 * np.sin(t), 0.0 * t], -1)
    accel = np.broadcast_to(np.array([0.0, 0.0, 9.81]), (n, 3))
    return jnp.asarray(gyro), jnp.asarray(accel)


def _run(params, schedule, dtype=jnp.float32):
    """(states before each tick, leg targets (n, 12)) of the controller alone."""
    gyro, accel = _imu()
    state = controller_init(params, dtype)

    def body(s, x):
        s2, out = controller_step(s, Sensors(x[0].astype(dtype), x[1].astype(dtype)), params,
                                  1.0, None, schedule)
        return s2, (s, out.leg_targets)

    return jax.lax.scan(body, state, (gyro, accel))[1]


def test_names_and_sizes():
    assert parse_policy("mlpr") == ("mlpr", 8)
    assert parse_policy("mlpr96") == ("mlpr", 96)
    for bad in ("mlpr0", "mlpr257", "mlprr"):
        with pytest.raises(ValueError):
            parse_policy(bad)
    spec = parse_tune_spec(read_toml("specs/tune/tune_dimension.toml"))
    # The default MLP keeps its layout; mlpr96 adds 4 inputs x 96 units.
    assert spec.policy_reparam("mlp96").size == 1272
    rep = spec.policy_reparam("mlpr96")
    assert (rep.k, len(rep.schedule_fields), rep.size) == (16, 8, 16 + 9 * 96 + 97 * 8) == (
        16, 8, 1656)
    z0 = rep.latent_of(spec.base_params())
    s0 = rep.schedule(jnp.asarray(z0))
    assert s0.kind == "mlpr" and s0.w1.shape == (8, 96)
    assert not np.any(np.asarray(s0.w2)) and not np.any(np.asarray(s0.b2))
    # The mlp start is unchanged by the new kind (the same seeded hidden layer).
    m0 = spec.policy_reparam("mlp96").schedule_init()
    assert m0.size == 1272 - 16 and np.all(np.abs(m0[:4 * 96]) > 0)


def test_recovery_inputs_in_a_known_situation():
    """Before the controller's detection: [0, 0, 1, 1]. After it: step weight 1, the time
    since the step started grows by one control period per tick, and during the swing exactly
    one foot's support drops below 1 (the swing foot)."""
    base = ControllerParams.recommended()
    # Direct values: not started; mid-swing of a left step; beyond the clip.
    x = np.asarray(recovery_inputs(0.3, NOT_STARTED_S, 0.0, 1.0, base))
    np.testing.assert_array_equal(x, [0.0, 0.0, 1.0, 1.0])
    mid = 0.5 * float(base.step_period)
    x = np.asarray(recovery_inputs(1.0 + mid, 1.0, 1.0, 1.0, base))
    np.testing.assert_allclose(x, [1.0, mid / RECOVERY_TIME_SCALE_S, 0.0, 1.0], atol=1e-5)
    x = np.asarray(recovery_inputs(9.0, 1.0, 1.0, 0.0, base))
    np.testing.assert_allclose(x, [1.0, RECOVERY_TIME_MAX_S / RECOVERY_TIME_SCALE_S, 1.0, 1.0])
    # A non-finite clock reads as "no time since the step, both feet down".
    np.testing.assert_array_equal(np.asarray(recovery_inputs(jnp.nan, 0.0, 1.0, 1.0, base)),
                                  [1.0, 0.0, 1.0, 1.0])

    # In the controller's own run of a forward fall.
    rep = _rep()
    states, _ = jax.jit(lambda: _run(rep.apply(base, rep.latent_of(base)), None))()
    feats = np.asarray(recovery_inputs(states.time_s, states.step_start_s, states.step_weight,
                                       states.steps.swing_left, base))
    detected = np.asarray(states.step_weight) >= 0.5
    assert 0 < detected.argmax() < N_TICKS - 4, "the fall must be detected mid-run"
    np.testing.assert_array_equal(feats[~detected], np.tile([0.0, 0.0, 1.0, 1.0],
                                                           ((~detected).sum(), 1)))
    after = feats[detected]
    assert np.all(after[:, 0] == 1.0)
    dt = float(base.control_period) / RECOVERY_TIME_SCALE_S
    assert after[0, 1] == pytest.approx(dt, rel=1e-5)
    steps = np.diff(after[:, 1])
    grow = steps > 0
    np.testing.assert_allclose(steps[grow], dt, rtol=1e-4)
    swing = np.minimum(after[:, 2], after[:, 3]) < 0.5
    assert swing.any()
    assert np.all(np.maximum(after[swing, 2], after[swing, 3]) == 1.0)


def test_start_is_the_unscheduled_controller():
    """Zero output layer: the same leg targets as no schedule (to float32 rounding: the two
    programs fuse differently), with a live hidden layer and the recovery inputs nonzero; a
    change of an output weight moves them."""
    base = ControllerParams.recommended()
    rep = _rep()
    z0 = jnp.asarray(rep.latent_of(base), jnp.float32)
    z0 = z0.at[rep.k + 8 * rep.width:rep.k + 9 * rep.width].set(0.3)     # b1: nonzero
    plain = jax.jit(lambda z: _run(rep.apply(base, z), None)[1])(z0)
    sched = jax.jit(lambda z: _run(rep.apply(base, z), rep.schedule(z))[1])(z0)
    np.testing.assert_allclose(np.asarray(sched), np.asarray(plain), rtol=0, atol=1e-7)
    j = SCHEDULE.index("stance_ankle_kp")
    z1 = z0.at[rep.k + 9 * rep.width + j].add(2.0)                        # w2[0, j]
    moved = jax.jit(lambda z: _run(rep.apply(base, z), rep.schedule(z))[1])(z1)
    assert float(jnp.max(jnp.abs(moved - plain))) > 1e-4


@pytest.mark.parametrize("timing", [False, True])
def test_gradient_is_finite_and_reaches_the_recovery_inputs(timing):
    """value_and_grad of a weighted sum of leg targets over the whole latent (with the step
    start's interpolated-crossing gradient too): finite, and nonzero on the first-layer weights
    of the recovery inputs (rows 4..7 of w1)."""
    base = ControllerParams.recommended()
    rep = _rep()
    z0 = jnp.asarray(rep.latent_of(base), jnp.float32)
    z0 = z0.at[rep.k + 9 * rep.width:].set(0.05)            # away from the all-zero output
    w = jnp.linspace(0.5, 1.5, 12)

    def f(z):
        params = rep.apply(base, z)
        params = with_timing_gradient(params) if timing else params
        return jnp.sum(_run(params, rep.schedule(z))[1] * w)

    v, g = jax.jit(jax.value_and_grad(f))(z0)
    g = np.asarray(g)
    assert np.isfinite(float(v)) and np.all(np.isfinite(g))
    w1 = g[rep.k:rep.k + 8 * rep.width].reshape(8, rep.width)
    assert np.max(np.abs(w1[4:])) > 1e-6, "the recovery inputs must carry gradient"


def test_policy_file_round_trip_and_validation(tmp_path):
    base = ControllerParams.recommended()
    rep = _rep("mlpr3")
    z = rep.latent_of(base) + np.random.default_rng(0).normal(0, 0.1, rep.size)
    sched = rep.schedule(jnp.asarray(z, jnp.float32))
    params = rep.params_np(base, z)
    path = save_policy_json(params, sched, tmp_path / "mlpr.json", source="a test")
    loaded, back = load_policy_json(path)
    assert loaded == params and back.kind == "mlpr" and back.w1.shape == (8, 3)
    a, b = schedule_to_dict(sched), schedule_to_dict(back)
    assert a.keys() == b.keys()
    for k in a:
        if k in ("kind", "fields", "log"):
            assert a[k] == b[k], k
        else:
            np.testing.assert_allclose(np.asarray(a[k], float), np.asarray(b[k], float),
                                       rtol=1e-6, err_msg=k)
    for patch, match in [(dict(w1=a["w1"][:4]), r"schedule.w1: expected shape \(8, H\)"),
                         (dict(kind="mlpx"), r"schedule.kind: expected one of \['mlp', 'mlpr'")]:
        data = json.loads(path.read_text())
        data["schedule"].update(patch)
        bad = tmp_path / "bad.json"
        bad.write_text(json.dumps(data))
        with pytest.raises(ValueError, match=match):
            load_policy_json(bad)


@pytest.mark.parametrize("patch, match", [
    ({"tune": {"policy": "mlpr0"}}, "tune.policy"),
    ({"study": {"policies": ["scalars", "mlpr300"]}}, r"study.policies\[1\]"),
])
def test_spec_accepts_and_validates_the_kind(patch, match):
    data = read_toml("specs/tune/tune_dimension_cpu.toml")
    ok = {**data, "tune": {**data["tune"], "policy": "mlpr4"},
          "study": {**data["study"], "policies": ["scalars", "mlp2", "mlpr2"]}}
    assert parse_tune_spec(ok).policy_reparam().kind == "mlpr"
    for table, values in patch.items():
        data[table] = {**data[table], **values}
    with pytest.raises(SpecError, match=match):
        parse_tune_spec(data)


@pytest.mark.slow
def test_mjx_start_gives_the_unscheduled_series():
    """A tiny MJX batch (2 pushes x 0.6 s, a step after one): the mlpr schedule at its start (zero
    output layer, live hidden layer) gives the series of no schedule."""
    from tkujax.sim import push as push_lib
    from tkujax.sim import rollout_mjx as sim

    spec = parse_tune_spec(read_toml("specs/tune/tune_dimension_cpu.toml"))
    base = spec.base_params()
    rep = spec.policy_reparam("mlpr2")
    params, sched = rep.split(base, jnp.asarray(rep.latent_of(base), jnp.float32))
    pushes = push_lib.stack_pushes([push_lib.make_push(2.0, 0.0, onset_s=0.1),
                                    push_lib.make_push(2.0, 180.0, onset_s=0.1)])
    config = sim.RolloutConfig(duration_s=0.6)
    plain, out_p = sim.simulate(pushes, 1.0, params, config=config)
    with_s, out_s = sim.simulate(pushes, 1.0, params, config=config, schedule=sched)
    # The push from behind triggers a step (the one in front stays inside this spec's wide
    # backward trigger), so the recovery inputs leave their resting values.
    assert plain["step_weight"][0, -1] >= 0.5 and plain["step_weight"][1, -1] < 0.5
    for key in plain:
        np.testing.assert_allclose(with_s[key], plain[key], rtol=1e-5, atol=1e-6, err_msg=key)
    np.testing.assert_array_equal(out_s["fell"], out_p["fell"])
