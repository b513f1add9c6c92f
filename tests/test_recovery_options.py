"""The recovery extensions of the controller, each in isolation against hand-computed values and
finite differences, and the guarantee that their "off" values are the paper's controller.

No physics: synthetic IMU readings drive `controller_step` (the closed loop is covered by
tests/test_closed_loop.py and the GPU studies).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.capture_point import capture_point, capture_point_rate, push_gate
from tkujax.control.controller import (Sensors, StepsState, detect_push, later_step_feet, cp_angle,
                                       controller_init, controller_step, stance_offsets)
from tkujax.control.controller_params import ControllerParams
from tkujax.model import LEG_ACTUATORS

G = 9.81
OPTIONS_OFF = dict(cp_rate_blend=0.0, cp_lookahead_s=0.0, cp_trigger=0.0, stance_ankle_kp=0.0,
                   stance_ankle_kd=0.0, stance_hip_kp=0.0, stance_hip_kd=0.0,
                   stance_roll_kp=0.0, stance_roll_kd=0.0, max_steps=1.0)


@pytest.fixture(scope="module")
def params() -> ControllerParams:
    return ControllerParams.paper()


def _fd(f, x, h=1e-4):
    return (f(x + h) - f(x - h)) / (2 * h)


def test_paper_has_every_option_off(params):
    for name, off in OPTIONS_OFF.items():
        assert getattr(params, name) == off, name
        assert getattr(ControllerParams(), name) == off, name


def test_rate_aware_capture_point_hand_values(params):
    jax.config.update("jax_enable_x64", True)
    try:
        leg_len, h = params.leg_length, params.com_height
        theta, rate = 0.1, 0.8
        # b = 0, tau = 0: exactly the paper's Eq. 6-10.
        assert float(capture_point_rate(theta, rate, params)) == float(
            capture_point(theta, leg_len, h, G))
        # b = 1: the measured rate in Eq. 8.
        p1 = dataclasses.replace(params, cp_rate_blend=1.0)
        want = leg_len * math.sin(theta) + leg_len * math.cos(theta) * rate * math.sqrt(h / G)
        assert float(capture_point_rate(theta, rate, p1)) == pytest.approx(want, rel=1e-12)
        # b = 0.25: a blend of the two rates; lookahead tau multiplies by exp(tau sqrt(g/h)).
        p2 = dataclasses.replace(params, cp_rate_blend=0.25, cp_lookahead_s=0.1)
        rate_e = math.copysign(math.sqrt(2 * G / leg_len * (1 - math.cos(theta))), theta)
        rate_b = 0.75 * rate_e + 0.25 * rate
        want = ((leg_len * math.sin(theta) + leg_len * math.cos(theta) * rate_b * math.sqrt(h / G))
                * math.exp(0.1 * math.sqrt(G / h)))
        assert float(capture_point_rate(theta, rate, p2)) == pytest.approx(want, rel=1e-12)
    finally:
        jax.config.update("jax_enable_x64", False)


@pytest.mark.parametrize("field", ["cp_rate_blend", "cp_lookahead_s"])
def test_rate_aware_capture_point_gradient_matches_finite_differences(params, field):
    jax.config.update("jax_enable_x64", True)
    try:
        base = dataclasses.replace(params, cp_rate_blend=0.4, cp_lookahead_s=0.05)
        f = lambda v: capture_point_rate(0.08, -0.5, dataclasses.replace(base, **{field: v}))  # noqa: E731
        x0 = jnp.float64(getattr(base, field))
        assert float(jax.grad(f)(x0)) == pytest.approx(float(_fd(f, x0)), rel=1e-6)
    finally:
        jax.config.update("jax_enable_x64", False)


def test_stance_offsets_hand_values_and_zero_gains(params):
    zero = np.asarray(stance_offsets(0.05, 0.3, -0.02, 0.1, params))
    assert np.array_equal(zero, np.zeros(12))
    p = dataclasses.replace(params, stance_ankle_kp=0.5, stance_ankle_kd=0.1, stance_hip_kp=-0.4,
                            stance_hip_kd=0.02, stance_roll_kp=0.3, stance_roll_kd=-0.05,
                            stance_limit=0.2)
    off = np.asarray(stance_offsets(0.05, 0.3, -0.02, 0.1, p))
    sat = lambda u: 0.2 * math.tanh(u / 0.2)  # noqa: E731
    ankle, hip = sat(0.5 * 0.05 + 0.1 * 0.3), sat(-0.4 * 0.05 + 0.02 * 0.3)
    roll = sat(0.3 * -0.02 - 0.05 * 0.1)
    for side in ("r", "l"):
        assert off[LEG_ACTUATORS.index(f"{side}_ankle_pitch")] == pytest.approx(ankle, rel=1e-5)
        assert off[LEG_ACTUATORS.index(f"{side}_hip_pitch")] == pytest.approx(hip, rel=1e-5)
        assert off[LEG_ACTUATORS.index(f"{side}_ankle_roll")] == pytest.approx(roll, rel=1e-5)
        for j in ("hip_yaw", "hip_roll", "knee"):
            assert off[LEG_ACTUATORS.index(f"{side}_{j}")] == 0.0
    # Saturation: never beyond the limit.
    big = dataclasses.replace(p, stance_ankle_kp=5.0)
    assert abs(float(stance_offsets(1.0, 0.0, 0.0, 0.0, big)[4])) <= np.float32(0.2)


def test_stance_gain_gradient_matches_finite_differences(params):
    jax.config.update("jax_enable_x64", True)
    try:
        def f(kp):
            p = dataclasses.replace(params, stance_ankle_kp=kp, stance_ankle_kd=0.05)
            return stance_offsets(0.07, 0.4, 0.0, 0.0, p)[4]
        x0 = jnp.float64(0.8)
        assert float(jax.grad(f)(x0)) == pytest.approx(float(_fd(f, x0)), rel=1e-6)
    finally:
        jax.config.update("jax_enable_x64", False)


def test_paper_gates_when_capture_point_trigger_is_off(params):
    phis = np.radians(np.linspace(-10, 25, 71))
    for phi in phis:
        det = detect_push(jnp.float32(phi), jnp.float32(0.0), jnp.float32(0.7), jnp.float32(0.0),
                      params)
        assert float(det.pitch_gate) == float(push_gate(jnp.float32(phi), params))
        want = params.cp_gain * capture_point(cp_angle(jnp.float32(phi), params),
                                              params.leg_length, params.com_height, params.gravity)
        assert float(det.x_new) == float(want)


def test_capture_point_trigger_reads_the_rate_not_the_angle(params):
    p = dataclasses.replace(params, cp_trigger=1.0, cp_rate_blend=1.0)
    lean, leg_len, h = p.standing_lean, p.leg_length, p.com_height
    # Beyond the paper's 12 deg threshold but swinging back fast: the capture point is inside
    # the foot, so no step (the paper would step).
    phi = math.radians(13.0)
    back = -1.2
    x_cp = leg_len * math.sin(phi - lean) + leg_len * math.cos(phi - lean) * back * math.sqrt(h / G)
    assert -p.cp_trigger_backward_m < x_cp < p.cp_trigger_forward_m
    det = detect_push(jnp.float32(phi), jnp.float32(0.0), jnp.float32(back), jnp.float32(0.0), p)
    assert float(det.x_cp) == pytest.approx(x_cp, abs=1e-6)
    assert float(det.pitch_gate) == 0.0
    assert float(push_gate(jnp.float32(phi), params)) == 1.0
    # Near the standing lean but falling forward fast: the capture point is past the toe.
    fwd = 2.0
    x_cp = leg_len * math.cos(0.0) * fwd * math.sqrt(h / G)
    assert x_cp > p.cp_trigger_forward_m
    det = detect_push(jnp.float32(lean), jnp.float32(0.0), jnp.float32(fwd), jnp.float32(0.0), p)
    assert float(det.pitch_gate) == 1.0
    assert float(push_gate(jnp.float32(lean), params)) == 0.0


def _falling_forward(params, n_periods, rate=1.5):
    """Drive controller_step with a gyro reading a steady forward fall (no physics)."""
    step = jax.jit(controller_step)
    state = controller_init(params)
    lean = params.standing_lean
    states = []
    for k in range(n_periods):
        ang = lean + 0.02 * k
        accel = jnp.array([-G * math.sin(ang), 0.0, G * math.cos(ang)], jnp.float32)
        state, out = step(state, Sensors(jnp.array([0.0, rate, 0.0], jnp.float32), accel),
                          params)
        states.append(state)
    return states, out


def test_second_step_alternates_feet_and_starts_where_the_first_ended(params):
    p = dataclasses.replace(params, cp_trigger=1.0, cp_rate_blend=1.0, max_steps=2.0)
    n = int(round(2 * p.step_period / p.control_period)) + 4
    states, _ = _falling_forward(p, n)
    counts = [float(s.steps.count) for s in states]
    assert counts[0] == 1.0 and max(counts) == 2.0
    k2 = counts.index(2.0)
    first, second = states[k2 - 1].steps, states[k2].steps
    assert float(first.swing_left) == 1.0 and float(second.swing_left) == 0.0
    np.testing.assert_array_equal(np.asarray(second.feet_from), np.asarray(first.feet_to))
    # The first step ends with the feet x_Sup apart around the waist, the left one ahead.
    x1 = float(states[0].x_sup_m)
    np.testing.assert_allclose(np.asarray(first.feet_to), [-x1 / 2, 0, x1 / 2, 0], atol=1e-7)
    # The second: the right foot swings ahead, the left slides back, both by x_new / 2.
    to = np.asarray(second.feet_to)
    assert to[0] > 0 and to[2] == pytest.approx(-to[0]) and to[1] == to[3] == 0.0
    # It starts only after the first step has finished.
    assert (k2 - 0) * p.control_period >= p.step_period
    # One step allowed: the count stays at 1 whatever the capture point does.
    states1, _ = _falling_forward(params.__class__(**{**dataclasses.asdict(p), "max_steps": 1.0}),
                                  n)
    assert max(float(s.steps.count) for s in states1) == 1.0


def test_later_step_feet_profile(params):
    steps = StepsState(count=jnp.float32(2.0),
                       feet_from=jnp.array([-0.02, 0.0, 0.02, 0.0], jnp.float32),
                       feet_to=jnp.array([0.03, -0.01, -0.03, 0.01], jnp.float32),
                       swing_left=jnp.float32(0.0))
    T, gamma = params.step_period, params.double_support_ratio
    d_y, d_z = params.hip_offset_y, params.hip_to_ankle_z
    r0, l0 = (np.asarray(v) for v in later_step_feet(0.0, steps, params))
    np.testing.assert_allclose(r0, [-0.02, -d_y, -d_z], atol=1e-7)
    np.testing.assert_allclose(l0, [0.02, d_y, -d_z], atol=1e-7)
    r1, l1 = (np.asarray(v) for v in later_step_feet(T, steps, params))
    np.testing.assert_allclose(r1, [0.03, -d_y - 0.01, -d_z], atol=1e-7)
    np.testing.assert_allclose(l1, [-0.03, d_y + 0.01, -d_z], atol=1e-7)
    mid = 0.5 * T                 # mid-swing: the right (swing) foot at the lift height
    rm, lm = (np.asarray(v) for v in later_step_feet(mid, steps, params))
    assert rm[2] == pytest.approx(-d_z + params.lift_height, abs=1e-6)
    assert lm[2] == pytest.approx(-d_z, abs=1e-7)
    assert 0.0 < gamma < 0.9


@pytest.mark.parametrize("field,value", [("max_steps", 4.0), ("cp_trigger", 0.5),
                                         ("cp_rate_blend", 1.5), ("stance_limit", 0.0),
                                         ("stance_ankle_kp", 9.0), ("cp_lookahead_s", -0.1)])
def test_validate_names_the_option_and_its_range(params, field, value):
    with pytest.raises(ValueError, match=rf"ControllerParams\.{field} must be in "):
        dataclasses.replace(params, **{field: value}).validate()


def test_recommended_is_the_committed_tuning_result(params):
    import json
    from pathlib import Path

    rec = ControllerParams.recommended()
    tuned = json.loads((Path(__file__).parents[1] / "results" / "tune_recovery_ensemble"
                        / "params_after.json").read_text())
    for f in dataclasses.fields(ControllerParams):
        # A field added after the tuning holds its default, which the tuning ran with.
        assert getattr(rec, f.name) == tuned.get(f.name, f.default), f.name
    # Everything the tuning did not touch is the paper's (geometry, Kalman noises, thresholds).
    for name in ("leg_length", "com_height", "kalman_q", "kalman_r", "standing_lean"):
        assert getattr(rec, name) == getattr(params, name)
    assert rec.cp_trigger == 1.0 and rec.max_steps == 2.0 and rec.lateral_steps == 1.0
