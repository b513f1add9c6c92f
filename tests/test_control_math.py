"""Tests of the controller math: params, Kalman filter, capture point, CPG, leg IK.

The references here (rotation matrices, forward kinematics, piecewise oscillators, Eq. 6-10)
are independent numpy transcriptions, not calls into the code under test. Finite differences
run in float64 inside `jax.enable_x64(True)` blocks so no global setting leaks to other files.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.capture_point import capture_point, push_detected, push_gate, push_recovery
from tkujax.control.cpg import cpg_feet
from tkujax.control.ik import LegAngles, leg_ik, paper_leg_ik, paper_to_model_angles
from tkujax.control.kalman import (KalmanState, accel_to_angle, accel_variance, gyro_to_rates,
                                   kalman_init, kalman_step)
from tkujax.control.controller_params import ControllerParams

# Default-model geometry, given explicitly (tests do not call ControllerParams.paper()).
P = ControllerParams(hip_offset_y=0.045, hip_to_ankle_z=0.20, thigh_length=0.11,
                     calf_length=0.11, leg_length=0.27, com_height=0.29)
DEG = math.pi / 180.0
G = 9.81


# ----------------------------------------------------------------------------- helpers
def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def fk_leg(hip_yaw, hip_roll, hip_pitch, knee, ankle_pitch, ankle_roll, thigh, calf):
    """Forward kinematics of the chain z-x-y | y | y-x, zero = straight down; float64 numpy.

    Returns (ankle position relative to the hip centre, sole rotation in the level frame).
    """
    down = np.array([0.0, 0.0, -1.0])
    r_thigh = rot_z(hip_yaw) @ rot_x(hip_roll) @ rot_y(hip_pitch)
    knee_pos = r_thigh @ (thigh * down)
    r_calf = r_thigh @ rot_y(knee)
    ankle_pos = knee_pos + r_calf @ (calf * down)
    r_sole = r_calf @ rot_y(ankle_pitch) @ rot_x(ankle_roll)
    return ankle_pos, r_sole


def fk_angles(a: LegAngles, thigh, calf, i=None):
    get = (lambda v: float(np.asarray(v, np.float64))) if i is None else (
        lambda v: float(np.asarray(v, np.float64)[i]))
    return fk_leg(0.0, get(a.hip_roll), get(a.hip_pitch), get(a.knee), get(a.ankle_pitch),
                  get(a.ankle_roll), thigh, calf)


def check_grad_fd(f, x0, h=1e-6, rtol=1e-5, atol=1e-8):
    """jax.grad of a scalar function of a scalar vs a central difference, in float64."""
    with jax.enable_x64(True):
        x0 = jnp.float64(x0)
        f_jit = jax.jit(f)  # one compile beats many op-by-op dispatches
        g = float(jax.jit(jax.grad(f))(x0))
        fd = (float(f_jit(x0 + h)) - float(f_jit(x0 - h))) / (2 * h)
        assert np.isfinite(g), g
        assert abs(g - fd) <= atol + rtol * abs(fd), (g, fd)
        return g


def grad_wrt_field(fn, params, name):
    """Function of one scalar: fn(params with field `name` set to it)."""
    return lambda x: fn(dataclasses.replace(params, **{name: x}))


# ----------------------------------------------------------------------------- params
def test_params_defaults_and_pytree():
    p = ControllerParams()
    assert p.control_period == 0.030 and p.step_period == 0.3
    assert p.double_support_ratio == 0.2 and p.lift_height == 0.03
    assert np.isclose(p.eps_forward, 12 * DEG) and np.isclose(p.eps_backward, 2 * DEG)
    assert np.isclose(p.standing_lean, 7 * DEG) and p.cp_angle_offset == p.standing_lean
    assert p.cp_gain == 1.0 and p.gate_temperature == 0.0
    assert ((p.hip_offset_y, p.hip_to_ankle_z, p.thigh_length, p.calf_length)
            == (0.045, 0.20, 0.11, 0.11))
    assert (p.leg_length, p.com_height) == (0.27, 0.29)
    leaves, treedef = jax.tree_util.tree_flatten(p)
    assert len(leaves) == len(dataclasses.fields(ControllerParams))
    assert jax.tree_util.tree_unflatten(treedef, leaves) == p
    assert p.validate() is p
    with pytest.raises(dataclasses.FrozenInstanceError):
        p.step_period = 1.0  # type: ignore[misc]


@pytest.mark.parametrize("field,value,msg", [
    ("step_period", 3.0, "(0, 2]"),
    ("step_period", 0.0, "(0, 2]"),
    ("double_support_ratio", 0.95, "[0, 0.9)"),
    ("lift_height", -0.01, "[0, 0.1]"),
    ("lift_height", float("nan"), "[0, 0.1]"),
    ("thigh_length", 0.0, "(0, 2]"),
    ("eps_forward", -0.1, "[0, pi/2)"),
    ("eps_backward", -0.1, "[0, pi/2)"),
    ("kalman_r", 0.0, "(0, inf)"),
    ("gate_temperature", -1e-3, "[0, 1]"),
    ("hip_to_ankle_z", 0.3, "thigh_length + calf_length"),
    ("accel_gate", -0.5, "[0, 100] m/s^2"),
    ("accel_gate", float("nan"), "[0, 100] m/s^2"),
])
def test_params_validate_rejects(field, value, msg):
    bad = dataclasses.replace(P, **{field: value})
    with pytest.raises(ValueError) as e:
        bad.validate()
    assert field in str(e.value) and msg in str(e.value)


def test_params_validate_in_jit_is_type_error():
    with pytest.raises(TypeError):
        jax.jit(lambda p: p.validate().step_period)(P)


# ----------------------------------------------------------------------------- Kalman
def test_accel_to_angle_matches_rotations():
    # Leaning forward = rotation about +y by +theta takes the top (+z) toward +x.
    assert (rot_y(0.2) @ np.array([0, 0, 1.0]))[0] > 0
    # Roll > 0 = rotation about +x: the top goes toward -y.
    assert (rot_x(0.2) @ np.array([0, 0, 1.0]))[1] < 0
    angs = np.linspace(-1.2, 1.2, 9)
    pitch, roll = np.meshgrid(angs, angs, indexing="ij")
    pitch, roll = pitch.ravel(), roll.ravel()
    f_w = np.array([0, 0, G])
    f_b = np.stack([(rot_y(p) @ rot_x(r)).T @ f_w for p, r in zip(pitch, roll)])
    out = np.asarray(jax.jit(accel_to_angle)(jnp.asarray(f_b, jnp.float32)))
    assert out.shape == (81, 2)
    np.testing.assert_allclose(out[:, 0], pitch, atol=2e-6)
    np.testing.assert_allclose(out[:, 1], roll, atol=2e-6)
    # Single-axis cases give the per-axis formulas pitch = atan2(-a_x, a_z), roll = atan2(a_y, a_z).
    th = 0.3
    fb = rot_y(th).T @ f_w
    np.testing.assert_allclose(fb, [-G * np.sin(th), 0, G * np.cos(th)], atol=1e-12)
    np.testing.assert_allclose(accel_to_angle(jnp.asarray(fb, jnp.float32)), [th, 0], atol=1e-6)
    fb = rot_x(th).T @ f_w
    np.testing.assert_allclose(fb, [0, G * np.sin(th), G * np.cos(th)], atol=1e-12)
    np.testing.assert_allclose(accel_to_angle(jnp.asarray(fb, jnp.float32)), [0, th], atol=1e-6)


def test_accel_gyro_degenerate_and_grad():
    # Free fall (zero specific force) and 90 deg pitch: finite values and gradients.
    for a in ([0.0, 0.0, 0.0], [-G, 0.0, 0.0]):
        a = jnp.asarray(a)
        assert np.all(np.isfinite(accel_to_angle(a)))
        jac = jax.jacobian(accel_to_angle)(a)
        assert np.all(np.isfinite(jac))
    np.testing.assert_allclose(accel_to_angle(jnp.array([-G, 0.0, 0.0]))[0], np.pi / 2, atol=1e-6)
    # Gyro: rotation about body +y is the pitch rate, about +x the roll rate.
    np.testing.assert_allclose(gyro_to_rates(jnp.array([0.1, 0.2, 0.3])), [0.2, 0.1], rtol=1e-7)


def test_kalman_step_formula():
    s = kalman_init(jnp.array([0.1, -0.05]), P)
    assert isinstance(s, KalmanState) and s.phi.shape == s.p.shape == (2,)
    np.testing.assert_allclose(s.p, [P.kalman_r] * 2)
    rate, z = jnp.array([0.5, -0.2]), jnp.array([0.13, -0.04])
    s1 = jax.jit(kalman_step)(s, rate, z, P)
    phi_pred = np.array([0.1, -0.05]) + P.control_period * np.array([0.5, -0.2])
    p_pred = P.kalman_r + P.kalman_q
    k = p_pred / (p_pred + P.kalman_r)
    np.testing.assert_allclose(s1.phi, phi_pred + k * (np.array([0.13, -0.04]) - phi_pred),
                               rtol=1e-6)
    np.testing.assert_allclose(s1.p, [(1 - k) * p_pred] * 2, rtol=1e-6)


def test_robust_kalman_closed_form():
    """accel_gate > 0: R_eff = r (1 + ((|a| - g) / gate)^2), K = p / (p + R_eff); 0: the paper."""
    gate = 0.5
    robust = dataclasses.replace(P, accel_gate=gate).validate()
    # Specific forces of magnitude g + e along a tilted direction (pitch 0.1 rad): the angle is
    # the same, only the magnitude differs.
    u = rot_y(0.1).T @ np.array([0.0, 0.0, 1.0])
    devs = np.array([-9.0, -2.0, -0.3, 0.0, 0.1, 0.5, 1.0, 5.0, 30.0])
    acc = jnp.asarray((G + devs)[:, None] * u, jnp.float32)
    np.testing.assert_allclose(accel_variance(acc, robust),
                               P.kalman_r * (1 + (devs / gate) ** 2), rtol=1e-4)
    np.testing.assert_allclose(accel_variance(acc, P), np.full(len(devs), P.kalman_r), rtol=1e-7)
    s0 = kalman_init(jnp.full((len(devs), 2), 0.05), P)
    rate, z = jnp.zeros((len(devs), 2)), accel_to_angle(acc)
    p_pred = P.kalman_r + P.kalman_q
    k = p_pred / (p_pred + P.kalman_r * (1 + (devs / gate) ** 2))
    s1 = jax.jit(kalman_step)(s0, rate, z, P, accel_variance(acc, robust))
    np.testing.assert_allclose(s1.phi[:, 0], 0.05 + k * (0.1 - 0.05), rtol=1e-4)
    np.testing.assert_allclose(s1.p[:, 1], (1 - k) * p_pred, rtol=1e-4)
    # A 30 m/s^2 impact sample barely moves the estimate; at |a| = g it is the paper's update.
    assert abs(float(s1.phi[-1, 0]) - 0.05) < 1e-3 * (0.1 - 0.05)   # < 0.1 % of the innovation
    paper = jax.jit(kalman_step)(s0, rate, z, P)
    np.testing.assert_allclose(s1.phi[3], paper.phi[3], rtol=1e-6)
    # Off (gate 0): bit-identical to the paper's filter, whatever the magnitude.
    off = jax.jit(kalman_step)(s0, rate, z, P, accel_variance(acc, P))
    np.testing.assert_array_equal(off.phi, paper.phi)


@pytest.mark.parametrize("gate", [0.0, 0.5])
def test_robust_kalman_grads(gate):
    """Finite gradients at gate 0 (the safe where) and correct ones where it is on."""
    acc = jnp.asarray([[-3.0, 0.5, 9.5], [0.0, 0.0, G], [-20.0, 0.0, 9.0]])

    def loss(p):
        st = kalman_init(jnp.zeros((3, 2)), p)
        st = kalman_step(st, jnp.zeros((3, 2)), accel_to_angle(acc), p, accel_variance(acc, p))
        return jnp.sum(st.phi ** 2)

    params = dataclasses.replace(P, accel_gate=gate)
    with jax.enable_x64(True):
        g = jax.grad(loss)(jax.tree_util.tree_map(jnp.float64, params))
    assert all(np.isfinite(float(v)) for v in jax.tree_util.tree_leaves(g))
    if gate > 0:
        check_grad_fd(grad_wrt_field(loss, P, "accel_gate"), gate, h=1e-6, rtol=1e-5)


def _run_filter(params, rates, zs, phi0):
    def body(st, inp):
        st = kalman_step(st, inp[0], inp[1], params)
        return st, st.phi
    _, phis = jax.lax.scan(body, kalman_init(phi0, params), (rates, zs))
    return phis


def test_kalman_beats_accel_and_gyro():
    rng = np.random.default_rng(0)
    dt, n = P.control_period, 200                      # 6 s
    t = dt * np.arange(1, n + 1)
    base = np.array([7 * DEG, 1 * DEG])
    amp, tau, w = np.array([0.15, 0.06]), 1.5, 2 * np.pi * np.array([1.2, 0.8])
    true = base + amp * np.exp(-t[:, None] / tau) * np.sin(w * t[:, None])
    true_rate = amp * np.exp(-t[:, None] / tau) * (w * np.cos(w * t[:, None])
                                                   - np.sin(w * t[:, None]) / tau)
    gyro = true_rate + np.array([0.05, -0.04]) + 0.01 * rng.standard_normal((n, 2))
    acc = true + 0.05 * rng.standard_normal((n, 2))
    phi0 = base
    est = np.asarray(jax.jit(_run_filter)(P, jnp.asarray(gyro, jnp.float32),
                                          jnp.asarray(acc, jnp.float32),
                                          jnp.asarray(phi0, jnp.float32)))
    gyro_int = phi0 + dt * np.cumsum(gyro, axis=0)
    rms = lambda e: float(np.sqrt(np.mean(e**2)))  # noqa: E731
    e_kf, e_acc, e_gyro = rms(est - true), rms(acc - true), rms(gyro_int - true)
    print(f'RMS error: Kalman {e_kf:.4f}, accelerometer {e_acc:.4f}, '
          f'integrated gyro {e_gyro:.4f} rad')
    assert e_kf < 0.6 * e_acc and e_kf < 0.6 * e_gyro, (e_kf, e_acc, e_gyro)


def test_kalman_grads_fd():
    rng = np.random.default_rng(1)
    rates = rng.normal(size=(20, 2)) * 0.3
    zs = rng.normal(size=(20, 2)) * 0.05

    def loss(p):
        return jnp.sum(_run_filter(p, jnp.asarray(rates), jnp.asarray(zs), jnp.zeros(2)) ** 2)

    for name, x0 in (("kalman_q", 1e-4), ("kalman_r", 3e-3), ("control_period", 0.03)):
        check_grad_fd(grad_wrt_field(loss, P, name), x0, h=x0 * 1e-4, rtol=1e-5)


# ----------------------------------------------------------------------------- capture point
def literal_capture_point(phi, leg_len, h, g=G):
    """Eq. 6-10 transcribed in numpy float64, with the sign of phi kept on phidot."""
    phidot = np.sign(phi) * np.sqrt(2.0 * (g / leg_len) * (1.0 - np.cos(phi)))  # Eq. 10 (+ sign)
    x_com = leg_len * np.sin(phi)                                                # Eq. 7
    xdot_com = leg_len * np.cos(phi) * phidot                                    # Eq. 8
    return x_com + xdot_com * np.sqrt(h / g)                                     # Eq. 6


def test_capture_point_vs_literal():
    phi = np.concatenate([np.linspace(-0.6, 0.6, 241), [-1e-3, 1e-3, 0.0]])
    ref = literal_capture_point(phi, 0.27, 0.29)
    out = jax.jit(capture_point)(jnp.asarray(phi, jnp.float32), 0.27, 0.29)
    np.testing.assert_allclose(out, ref, rtol=2e-6, atol=1e-8)
    with jax.enable_x64(True):
        out64 = capture_point(jnp.asarray(phi), 0.27, 0.29)
        assert out64.dtype == jnp.float64
        np.testing.assert_allclose(out64, ref, rtol=1e-12, atol=1e-14)
    # Odd in phi: the same step forward and backward for opposite tilts.
    np.testing.assert_allclose(capture_point(-jnp.float32(0.3), 0.27, 0.29),
                               -capture_point(jnp.float32(0.3), 0.27, 0.29), rtol=1e-7)


def test_push_directions_and_band():
    for p in (P, dataclasses.replace(P, cp_angle_offset=0.0)):
        back = push_recovery(jnp.float32(15 * DEG), p)    # pushed from the back: leans forward
        front = push_recovery(jnp.float32(-5 * DEG), p)   # pushed from the front: leans back
        assert back > 0 and front < 0
        band = push_recovery(jnp.linspace(-1.99 * DEG, 11.99 * DEG, 50), p)
        np.testing.assert_array_equal(band, 0.0)
    # The value: the capture point of the deviation from the standing lean, times the gain.
    p2 = dataclasses.replace(P, cp_gain=1.5)
    np.testing.assert_allclose(push_recovery(jnp.float32(15 * DEG), p2),
                               1.5 * literal_capture_point(8 * DEG, 0.27, 0.29), rtol=1e-5)
    # Hard thresholds are strict, as in Algorithm 1.
    det = push_detected(jnp.array([P.eps_forward, -P.eps_backward, 0.3, -0.1]), P)
    np.testing.assert_array_equal(det, [False, False, True, True])


def test_soft_gate_converges_to_hard():
    phi = jnp.linspace(-0.5, 0.6, 1101)
    far = (jnp.abs(phi - P.eps_forward) > 0.01) & (jnp.abs(phi + P.eps_backward) > 0.01)
    hard = push_recovery(phi, P)
    gate_fn = jax.jit(push_gate)
    errs = []
    for tau in (1e-2, 3e-3, 1e-3, 1e-4):
        p = dataclasses.replace(P, gate_temperature=tau)
        g = gate_fn(phi, p)
        assert float(g.min()) >= 0.0 and float(g.max()) <= 1.0
        errs.append(float(jnp.max(jnp.where(far, jnp.abs(push_recovery(phi, p) - hard), 0.0))))
    assert all(a > b for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < 1e-7, errs
    # tau == 0 is exactly the hard gate, through the same compiled function.
    np.testing.assert_array_equal(gate_fn(phi, P), push_detected(phi, P).astype(jnp.float32))


def test_capture_point_grads():
    # Finite at phi = 0 (the literal sqrt form has an infinite derivative there).
    g0 = jax.grad(capture_point)(jnp.float32(0.0), 0.27, 0.29)
    assert np.isfinite(g0) and g0 > 0
    # Slope at 0: l + l sqrt(g/l) sqrt(h/g) = l + sqrt(l h).
    np.testing.assert_allclose(g0, 0.27 + math.sqrt(0.27 * 0.29), rtol=1e-6)
    for tau in (0.0, 0.01):
        p = dataclasses.replace(P, gate_temperature=tau)
        for phi in (0.0, p.eps_forward, -p.eps_backward, 0.3, -0.2):
            grads = jax.grad(push_recovery, argnums=(0, 1))(jnp.float32(phi), p)
            assert all(np.isfinite(x) for x in jax.tree_util.tree_leaves(grads)), (tau, phi, grads)
    # Gradient wrt the temperature at exactly 0 (hard branch selected) is finite (zero).
    gt = jax.grad(lambda t: push_recovery(0.3, dataclasses.replace(P, gate_temperature=t)))(0.0)
    assert np.isfinite(gt)


@pytest.mark.parametrize("tau,phi", [(0.0, 0.35), (0.0, -0.15), (0.02, 0.2), (0.02, -0.03)])
def test_capture_point_grads_fd(tau, phi):
    p = dataclasses.replace(P, gate_temperature=tau)
    f = lambda q: push_recovery(jnp.float64(phi), q)  # noqa: E731
    names = ["leg_length", "com_height", "gravity", "cp_gain", "cp_angle_offset"]
    if tau > 0:
        names += ["gate_temperature", "eps_forward", "eps_backward"]
    for name in names:
        check_grad_fd(grad_wrt_field(f, p, name), getattr(p, name))
    check_grad_fd(lambda x: push_recovery(x, p), phi)


# ----------------------------------------------------------------------------- CPG
def literal_cpg(t, x_sup, T, gamma, H, d_y, d_z):
    """Eq. 11-18 with Table 2, piecewise in plain Python floats, plus the t < 0 / t >= T rules."""
    def osc(rho, omega, hold):
        if t < gamma * T / 2:
            return 0.0
        if t < T - gamma * T / 2:
            return rho * math.sin(omega * (t - T / 2 * gamma) + 0.0)
        return hold
    tp = T * (1 - gamma)
    wx, wy, wz = math.pi / (2 * tp), 2 * math.pi / tp, math.pi / tp
    right = (osc(-x_sup / 2, wx, -x_sup / 2) + 0.0, osc(0.0, wy, 0.0) - d_y,
             osc(0.0, wz, 0.0) - d_z)
    left = (osc(x_sup / 2, wx, x_sup / 2) + 0.0, osc(0.0, wy, 0.0) + d_y, osc(H, wz, 0.0) - d_z)
    return np.array(right), np.array(left)


def _cpg_times(T, gamma):
    bounds = [0.0, gamma * T / 2, T - gamma * T / 2, T]
    ts = [b + d for b in bounds for d in (-1e-4, -1e-9, 0.0, 1e-9, 1e-4)]
    return np.array(sorted(ts + list(np.linspace(-0.1, T + 0.1, 157))))


@pytest.mark.parametrize("x_sup", [0.05, -0.03])
def test_cpg_vs_literal(x_sup):
    T, gamma = P.step_period, P.double_support_ratio
    ts = _cpg_times(T, gamma)
    ref = np.array([np.stack(literal_cpg(t, x_sup, T, gamma, P.lift_height, P.hip_offset_y,
                                         P.hip_to_ankle_z)) for t in ts])
    f = jax.jit(cpg_feet)
    pr, pl = f(jnp.asarray(ts, jnp.float32), jnp.float32(x_sup), P)
    assert pr.shape == pl.shape == (len(ts), 3)
    np.testing.assert_allclose(pr, ref[:, 0], atol=2e-6)
    np.testing.assert_allclose(pl, ref[:, 1], atol=2e-6)
    with jax.enable_x64(True):
        pr, pl = cpg_feet(jnp.asarray(ts), jnp.float64(x_sup), P)
        np.testing.assert_allclose(pr, ref[:, 0], atol=1e-12)
        np.testing.assert_allclose(pl, ref[:, 1], atol=1e-12)


def test_cpg_shape_continuity_direction():
    T, gamma, H = P.step_period, P.double_support_ratio, P.lift_height
    x_sup = 0.04
    cpg = jax.jit(cpg_feet)
    with jax.enable_x64(True):
        ts = np.linspace(-0.05, T + 0.05, 4001)
        pr, pl = (np.asarray(a) for a in cpg(jnp.asarray(ts), 0.04, P))
        dt = ts[1] - ts[0]
        # Continuity of every coordinate: no jump bigger than the steepest sine slope allows.
        max_slope = H * math.pi / (T * (1 - gamma)) + x_sup / 2 * 2 * math.pi / (T * (1 - gamma))
        assert np.max(np.abs(np.diff(pl, axis=0))) < 1.01 * max_slope * dt
        assert np.max(np.abs(np.diff(pr, axis=0))) < 1.01 * max_slope * dt
        # x is continuous at landing: just before the end of the swing it already reaches rho.
        t_land = T - gamma * T / 2
        a, b = cpg(jnp.array([t_land - 1e-9, t_land]), 0.04, P)[1][:, 0]
        assert abs(float(a) - float(b)) < 1e-9 and abs(float(b) - x_sup / 2) < 1e-15
        # z peaks at H_Sup at mid-step (t = T/2), and never exceeds it.
        _, pl_mid = cpg(jnp.float64(T / 2), 0.04, P)
        np.testing.assert_allclose(pl_mid[2], -P.hip_to_ankle_z + H, atol=1e-15)
        assert pl[:, 2].max() <= -P.hip_to_ankle_z + H + 1e-15
        np.testing.assert_allclose(pr[:, 2], -P.hip_to_ankle_z)            # support foot stays down
        np.testing.assert_allclose(pr[:, 1], -P.hip_offset_y)
        np.testing.assert_allclose(pl[:, 1], P.hip_offset_y)
    # Forward step: left foot ahead of, right foot behind the waist; backward the opposite.
    for xs, sign in ((0.04, 1.0), (-0.04, -1.0)):
        pr, pl = cpg(jnp.array([-0.01, 0.2, T, T + 1.0]), xs, P)
        np.testing.assert_allclose(pr[0], [0, -P.hip_offset_y, -P.hip_to_ankle_z], atol=1e-7)
        np.testing.assert_allclose(pl[0], [0, P.hip_offset_y, -P.hip_to_ankle_z], atol=1e-7)
        assert np.all(sign * pl[1:, 0] > 0) and np.all(sign * pr[1:, 0] < 0)
        np.testing.assert_allclose(pl[2:, 0], xs / 2, rtol=1e-6)
        np.testing.assert_allclose(pl[2:, 2], -P.hip_to_ankle_z, rtol=1e-6)
    # Broadcasting over batch dims of t and x_sup.
    pr, pl = cpg(jnp.linspace(0, T, 5)[:, None], jnp.array([0.01, 0.02, -0.03]), P)
    assert pr.shape == pl.shape == (5, 3, 3)


@pytest.mark.parametrize("t", [0.07, 0.15, 0.26, 0.29])
def test_cpg_grads_fd(t):
    def f(p, xs=0.04):
        pr, pl = cpg_feet(jnp.float64(t), xs, p)
        return jnp.sum(pl * jnp.array([1.0, 2.0, 3.0])) + jnp.sum(pr * jnp.array([0.5, -1.0, 0.7]))
    for name in ("step_period", "double_support_ratio", "lift_height", "hip_offset_y",
                 "hip_to_ankle_z"):
        check_grad_fd(grad_wrt_field(f, P, name), getattr(P, name))
    check_grad_fd(lambda xs: f(P, xs), 0.04)
    check_grad_fd(lambda tt: jnp.sum(cpg_feet(tt, 0.04, P)[1]), t)


# ----------------------------------------------------------------------------- IK
def _reachable_grid():
    g = np.stack(np.meshgrid(np.linspace(-0.06, 0.06, 9), np.linspace(-0.04, 0.04, 7),
                             -np.linspace(0.15, 0.215, 8), indexing="ij"), -1).reshape(-1, 3)
    return g[np.linalg.norm(g, axis=1) < 0.22 - 1e-4]


@pytest.mark.parametrize("x64", [False, True])
def test_leg_ik_round_trip(x64):
    grid = _reachable_grid()
    assert len(grid) > 300
    tol_p, tol_r = (1e-5, 1e-4) if not x64 else (1e-12, 1e-12)
    with jax.enable_x64(x64):
        a = jax.jit(leg_ik)(jnp.asarray(grid), 0.11, 0.11)
        assert a.knee.dtype == (jnp.float64 if x64 else jnp.float32)
        assert np.all(np.asarray(a.reachable))
        for i in range(len(grid)):
            pos, r_sole = fk_angles(a, 0.11, 0.11, i)
            assert np.max(np.abs(pos - grid[i])) < tol_p, (grid[i], pos)
            # ||R - I||_F / sqrt(2) is the rotation angle for small angles.
            assert np.linalg.norm(r_sole - np.eye(3)) / math.sqrt(2) < tol_r


def test_leg_ik_signs():
    a = leg_ik(jnp.array([0.0, 0.0, -0.2]), 0.11, 0.11)
    assert a.hip_pitch < 0 and a.knee > 0 and a.ankle_pitch < 0 and a.hip_roll == 0
    np.testing.assert_allclose(a.ankle_pitch, a.hip_pitch, atol=1e-6)  # equal links: symmetric
    a = leg_ik(jnp.array([0.0, 0.02, -0.2]), 0.11, 0.11)
    assert a.hip_roll > 0 and np.isclose(a.ankle_roll, -a.hip_roll)
    # Straight leg: all zero up to the distance clip (1e-6 relative), which bends the knee by
    # ~sqrt(8e-6) = 2.8 mrad while the ankle position moves by only 2.2e-7 m.
    a = leg_ik(jnp.array([0.0, 0.0, -0.22]), 0.11, 0.11)
    np.testing.assert_allclose([a.hip_roll, a.hip_pitch, a.knee, a.ankle_pitch, a.ankle_roll], 0.0,
                               atol=3e-3)
    np.testing.assert_allclose(fk_angles(a, 0.11, 0.11)[0], [0, 0, -0.22], atol=1e-6)


def test_leg_ik_matches_paper_without_lateral_offset():
    g = np.stack(np.meshgrid(np.linspace(-0.04, 0.04, 9), [0.0], -np.linspace(0.15, 0.2, 6),
                             indexing="ij"), -1).reshape(-1, 3)
    with jax.enable_x64(True):
        ours = jax.jit(leg_ik)(jnp.asarray(g), 0.11, 0.11)
        paper = paper_to_model_angles(jax.jit(paper_leg_ik)(g[:, 0], g[:, 1], -g[:, 2], 0.11, 0.11))
        for name in ("hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll"):
            np.testing.assert_allclose(getattr(ours, name), getattr(paper, name), atol=1e-10,
                                       err_msg=name)


def test_leg_ik_better_than_paper_with_lateral_offset():
    g = np.stack(np.meshgrid(np.linspace(-0.04, 0.04, 5), [-0.04, -0.02, 0.02, 0.04],
                             -np.linspace(0.16, 0.2, 5), indexing="ij"), -1).reshape(-1, 3)
    with jax.enable_x64(True):
        ours = jax.jit(leg_ik)(jnp.asarray(g), 0.11, 0.11)
        paper = paper_to_model_angles(jax.jit(paper_leg_ik)(g[:, 0], g[:, 1], -g[:, 2], 0.11, 0.11))
        err_ours = max(np.linalg.norm(fk_angles(ours, 0.11, 0.11, i)[0] - g[i])
                       for i in range(len(g)))
        err_paper = max(np.linalg.norm(fk_angles(paper, 0.11, 0.11, i)[0] - g[i])
                        for i in range(len(g)))
    print(f"max FK error with |p_y| <= 4 cm: ours {err_ours:.2e} m, "
          f"paper Eq. 19-28 {err_paper:.2e} m")
    assert err_ours < 1e-12 and err_paper > 1e-3


def test_leg_ik_unreachable_and_boundaries():
    lt, lc = 0.11, 0.11
    pts = jnp.array([[0.0, 0.0, -0.3], [0.1, 0.05, -0.25], [0.0, 0.0, -0.22], [0.0, 0.0, 0.0],
                     [0.05, 0.0, 0.0]])
    a = leg_ik(pts, lt, lc)
    assert all(np.all(np.isfinite(np.asarray(v))) for v in a[:5])
    np.testing.assert_array_equal(a.reachable, [False, False, True, True, True])
    # Nearest reachable pose: on the ray through the target, at full extension.
    for i in (0, 1):
        pos, r_sole = fk_angles(a, lt, lc, i)
        target = np.asarray(pts[i], np.float64)
        np.testing.assert_allclose(pos, target / np.linalg.norm(target) * (lt + lc), atol=2e-6)
        np.testing.assert_allclose(r_sole, np.eye(3), atol=1e-5)
    # Unequal links: too close to the hip.
    a2 = leg_ik(jnp.array([0.0, 0.0, -0.005]), 0.12, 0.10)
    assert not bool(a2.reachable)
    pos, _ = fk_angles(a2, 0.12, 0.10)
    np.testing.assert_allclose(pos, [0, 0, -0.02], atol=2e-6)

    def loss(p, lt, lc):
        a = leg_ik(p, lt, lc)
        return sum(jnp.sum(v * w) for v, w in zip(a[:5], (1.0, 2.0, 3.0, 4.0, 5.0)))

    for x64 in (False, True):
        with jax.enable_x64(x64):
            grad_fn = jax.jit(jax.grad(loss, argnums=(0, 1, 2)))
            for p in list(np.asarray(pts)) + [np.array([0.0, 0.0, -0.005])]:
                grads = grad_fn(jnp.asarray(p), 0.11, 0.11)
                assert all(np.all(np.isfinite(np.asarray(x))) for x in grads), (p, grads)


def test_leg_ik_grads_fd():
    p0 = np.array([0.03, -0.02, -0.18])

    def loss(p, lt, lc):
        a = leg_ik(p, lt, lc)
        return sum(jnp.sum(v * w) for v, w in zip(a[:5], (1.0, 2.0, 3.0, 4.0, 5.0)))

    for k in range(3):
        e = np.eye(3)[k]
        check_grad_fd(lambda x, e=e: loss(jnp.asarray(p0) + x * e, 0.11, 0.11), 0.0, h=1e-7)
    check_grad_fd(lambda x: loss(jnp.asarray(p0), x, 0.11), 0.11, h=1e-7)
    check_grad_fd(lambda x: loss(jnp.asarray(p0), 0.11, x), 0.11, h=1e-7)


# ----------------------------------------------------------------------------- jit / vmap / retrace
def test_vmap_1000_matches_batched():
    rng = np.random.default_rng(2)
    n = 1000
    phi = jnp.asarray(rng.uniform(-0.4, 0.5, n), jnp.float32)
    xs = jax.jit(jax.vmap(push_recovery, in_axes=(0, None)))(phi, P)
    np.testing.assert_allclose(xs, push_recovery(phi, P), rtol=1e-6, atol=1e-9)
    # vmap over a batch of parameter values (every leaf batched).
    pb = jax.tree_util.tree_map(lambda v: jnp.full((n,), v, jnp.float32), P)
    pb = dataclasses.replace(pb, cp_gain=jnp.linspace(0.5, 1.5, n, dtype=jnp.float32))
    xs_b = jax.jit(jax.vmap(push_recovery))(phi, pb)
    np.testing.assert_allclose(xs_b, xs * pb.cp_gain, rtol=1e-5, atol=1e-8)

    ts = jnp.asarray(rng.uniform(-0.05, 0.35, n), jnp.float32)
    pr, pl = jax.jit(jax.vmap(cpg_feet, in_axes=(0, 0, None)))(ts, xs, P)
    pr2, pl2 = jax.jit(cpg_feet)(ts, xs, P)
    np.testing.assert_allclose(pr, pr2, atol=1e-7)
    np.testing.assert_allclose(pl, pl2, atol=1e-7)

    targets = pl - jnp.array([0.0, P.hip_offset_y, 0.0])
    a = jax.jit(jax.vmap(leg_ik, in_axes=(0, None, None)))(targets, 0.11, 0.11)
    a2 = jax.jit(leg_ik)(targets, 0.11, 0.11)
    for u, v in zip(a, a2):
        np.testing.assert_allclose(u, v, atol=1e-6)

    acc = jnp.asarray(rng.normal(size=(n, 3)) + np.array([0, 0, G]), jnp.float32)
    z = jax.jit(jax.vmap(accel_to_angle))(acc)
    np.testing.assert_allclose(z, jax.jit(accel_to_angle)(acc), atol=1e-6)
    st = kalman_init(jnp.zeros((n, 2)), P)
    s1 = jax.jit(jax.vmap(kalman_step, in_axes=(0, 0, 0, None)))(st, gyro_to_rates(acc), z, P)
    s2 = jax.jit(kalman_step)(st, gyro_to_rates(acc), z, P)
    np.testing.assert_allclose(s1.phi, s2.phi, atol=1e-6)


def test_no_recompilation_across_param_values():
    traces = [0]

    def tick(state, gyro, accel, t, params):
        traces[0] += 1  # runs only when jax traces
        st = kalman_step(state, gyro_to_rates(gyro), accel_to_angle(accel), params)
        x_sup = push_recovery(st.phi[0], params)
        _, p_left = cpg_feet(t, x_sup, params)
        hip = jnp.array([0.0, 1.0, 0.0]) * params.hip_offset_y
        return st, leg_ik(p_left - hip, params.thigh_length, params.calf_length)

    tick_jit = jax.jit(tick)
    st = kalman_init(jnp.array([0.3, 0.0]), P)
    variants = [P,
                dataclasses.replace(P, eps_forward=0.1, step_period=0.4),
                dataclasses.replace(P, gate_temperature=0.01, cp_gain=2.0),
                dataclasses.replace(P, thigh_length=0.12, kalman_q=1e-3),
                P.validate()]
    outs = [tick_jit(st, jnp.array([0.0, 0.1, 0.0]), jnp.array([-2.0, 0.0, 9.6]),
                     jnp.float32(0.15), v)
            for v in variants]
    assert traces[0] == 1
    assert not np.allclose(outs[0][1].hip_pitch, outs[1][1].hip_pitch)
    for _, a in outs:
        assert all(np.all(np.isfinite(np.asarray(v))) for v in a[:5])
