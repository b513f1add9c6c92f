"""The composed controller: IK through MuJoCo's kinematics of TKU-X, stand targets, and the
semantics of `controller_step` on synthetic IMU signals (no physics), under jit, grad and vmap.

MuJoCo C (`mj_kinematics`) is the reference for the forward kinematics: the leg targets of
`solve_legs` are written into qpos with the base at the `stand` keyframe pose. That pose has
base yaw 0 and the waist at the origin of the level frame the CPG uses, so "relative to the
`waist` site, in world axes" is exactly the CPG's frame.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from tkujax.control.capture_point import capture_point
from tkujax.control.controller import Sensors, controller_init, controller_step, stand_leg_targets
from tkujax.control.cpg import cpg_feet
from tkujax.control.controller_params import ControllerParams
from tkujax.control.solve import solve_legs
from tkujax.model import LEG_ACTUATORS, load_model

G = 9.81
N_PERIODS = 200                   # 6 s of control periods for the semantic runs
POS_TOL_M = 1e-3
TILT_TOL_DEG = 1.0
L_ANKLE_PITCH = LEG_ACTUATORS.index("l_ankle_pitch")
R_HIP_ROLL = LEG_ACTUATORS.index("r_hip_roll")
L_HIP_ROLL = LEG_ACTUATORS.index("l_hip_roll")


@pytest.fixture(scope="module")
def params() -> ControllerParams:
    return ControllerParams.paper()


class _Kinematics:
    """MuJoCo forward kinematics of TKU-X with the base at the stand keyframe pose."""

    def __init__(self):
        self.model = load_model()
        self.data = mujoco.MjData(self.model)
        self.key = self.model.key("stand")
        self.adr = np.array([self.model.joint(n).qposadr[0] for n in LEG_ACTUATORS])

    def feet(self, targets: np.ndarray):
        """(12,) leg joint angles -> (ankle positions (2, 3) [right, left] relative to the
        waist site in world axes, m; sole tilts (2,) [right, left] from world z, deg)."""
        d = self.data
        d.qpos[:] = self.key.qpos
        d.qpos[self.adr] = targets
        mujoco.mj_kinematics(self.model, d)
        waist = d.site("waist").xpos
        pos, tilt = [], []
        for site in ("r_ankle", "l_ankle"):
            s = d.site(site)
            pos.append(s.xpos - waist)
            z_axis = s.xmat.reshape(3, 3)[:, 2]          # the foot body's z axis (sole normal)
            tilt.append(math.degrees(math.acos(min(1.0, float(z_axis[2])))))
        return np.array(pos), np.array(tilt)


@pytest.fixture(scope="module")
def kin() -> _Kinematics:
    return _Kinematics()


def _imu(pitch_deg, gyro_pitch_rate=0.0, n=N_PERIODS) -> tuple[np.ndarray, np.ndarray]:
    """(gyro (n, 3), accel (n, 3)) float32 of a body pitched by pitch_deg (scalar or (n,)) at
    rest: accel = g (-sin, 0, cos), gyro y = the pitch rate (rad/s)."""
    pitch = np.radians(np.broadcast_to(np.asarray(pitch_deg, float), (n,)))
    accel = G * np.stack([-np.sin(pitch), np.zeros(n), np.cos(pitch)], -1)
    gyro = np.zeros((n, 3))
    gyro[:, 1] = gyro_pitch_rate
    return gyro.astype(np.float32), accel.astype(np.float32)


def _scan(params, gyro, accel, enabled):
    """Run controller_step over a sensor sequence; returns the stacked (states, outputs)."""

    def body(state, x):
        state, out = controller_step(state, Sensors(*x), params, enabled)
        return state, (state, out)

    return jax.lax.scan(body, controller_init(params), (gyro, accel))[1]


_run = jax.jit(_scan)


def _np(tree):
    return jax.tree_util.tree_map(np.asarray, tree)


# --------------------------------------------------------------------------------------------
# IK round trip through MuJoCo's forward kinematics


def _cpg_grid(params):
    """Every phase of the recovery step (before, lift-off, swing, landing, after) x x_Sup."""
    T, gamma = params.step_period, params.double_support_ratio
    t_lift, t_land = 0.5 * gamma * T, T - 0.5 * gamma * T
    ts = np.unique(np.concatenate([np.linspace(-0.03, T + 0.03, 33),
                                   [t_lift, 0.5 * (t_lift + t_land), t_land, T]]))
    xs = np.linspace(-0.08, 0.08, 9)
    return np.meshgrid(ts, xs, indexing="ij")


def test_ik_round_trip_through_mujoco_kinematics(params, kin):
    t, x_sup = _cpg_grid(params)
    p_r, p_l = cpg_feet(jnp.asarray(t), jnp.asarray(x_sup), params)
    q, reachable = solve_legs(p_r, p_l, params)
    assert bool(np.all(reachable))
    want = np.stack([np.asarray(p_r), np.asarray(p_l)], -2).reshape(-1, 2, 3)
    q = np.asarray(q).reshape(-1, 12)
    # The grid covers the CPG's workspace: the full lift, both step directions, landed feet.
    lift = want[:, 1, 2] + params.hip_to_ankle_z
    assert lift.max() == pytest.approx(params.lift_height, abs=1e-4) and lift.min() >= -1e-7
    assert (want[:, 1, 0].max() == pytest.approx(0.04)
            and want[:, 1, 0].min() == pytest.approx(-0.04))

    pos_err, tilt = np.zeros(len(q)), np.zeros(len(q))
    for i in range(len(q)):
        pos, tilts = kin.feet(q[i])
        pos_err[i] = np.abs(pos - want[i]).max()
        tilt[i] = tilts.max()
    assert pos_err.max() < POS_TOL_M, f"worst ankle error {pos_err.max():.3g} m"
    assert tilt.max() < TILT_TOL_DEG, f"worst sole tilt {tilt.max():.3g} deg"


def test_ik_lateral_offsets(params, kin):
    """|y offset| up to 2 cm from +-d_y on either foot: exact position; the sole tilt stays
    within the bound documented in tkujax/control/solve.py, ~|sin(hip roll) sin(lean)|."""
    T = params.step_period
    rows = [(t, x, dy_r, dy_l) for t in (-0.03, 0.5 * T, T) for x in (-0.08, 0.0, 0.08)
            for dy_r in (-0.02, -0.01, 0.01, 0.02) for dy_l in (-0.02, -0.01, 0.01, 0.02)]
    t, x_sup, dy_r, dy_l = (np.array(c) for c in zip(*rows))
    p_r, p_l = (np.array(p) for p in cpg_feet(jnp.asarray(t), jnp.asarray(x_sup), params))
    p_r[:, 1] += dy_r
    p_l[:, 1] += dy_l
    q, reachable = solve_legs(jnp.asarray(p_r), jnp.asarray(p_l), params)
    q = np.asarray(q)
    assert bool(np.all(reachable))
    sin_lean = abs(math.sin(params.standing_lean))
    worst_pos, worst_tilt, worst_excess = 0.0, 0.0, -np.inf
    for i in range(len(q)):
        pos, tilts = kin.feet(q[i])
        worst_pos = max(worst_pos, np.abs(pos - np.stack([p_r[i], p_l[i]])).max())
        for tilt_deg, roll in zip(tilts, q[i, [R_HIP_ROLL, L_HIP_ROLL]]):
            bound_deg = math.degrees(abs(math.sin(roll)) * sin_lean)
            worst_tilt = max(worst_tilt, tilt_deg)
            worst_excess = max(worst_excess, tilt_deg - (TILT_TOL_DEG + bound_deg))
    # The hip roll really is exercised (several degrees).
    assert np.degrees(np.abs(q[:, [R_HIP_ROLL, L_HIP_ROLL]])).max() > 5.0
    assert worst_pos < POS_TOL_M, f"worst ankle error {worst_pos:.3g} m"
    print(f"lateral offsets: worst sole tilt {worst_tilt:.3f} deg")
    assert worst_excess <= 0.0, (f"sole tilt exceeds 1 deg + |sin r sin lean| by "
                                 f"{worst_excess:.3g} deg")


def test_stand_leg_targets_match_keyframe(params):
    model = load_model()
    key = model.key("stand")
    ctrl = np.array([key.ctrl[model.actuator(n).id] for n in LEG_ACTUATORS])
    np.testing.assert_allclose(np.asarray(stand_leg_targets(params)), ctrl, rtol=0, atol=1e-6)


# --------------------------------------------------------------------------------------------
# controller_step on synthetic sensor signals


def _trigger_index(states) -> int | None:
    """The single period at which the (hard-gated) step starts; asserts it is unique."""
    w = states.step_weight
    assert np.all(np.diff(w) >= 0)
    started = w >= 0.5
    starts = np.flatnonzero(np.diff(np.concatenate([[False], started]).astype(int)) == 1)
    assert len(starts) <= 1
    return int(starts[0]) if len(starts) else None


def test_standing_signal_holds_stand_targets(params):
    states, out = _np(_run(params, *_imu(7.0), 1.0))
    np.testing.assert_allclose(out.phi, params.standing_lean, atol=1e-6)
    assert np.all(out.gate == 0) and np.all(states.step_weight == 0)
    assert np.all(states.x_sup_m == 0) and _trigger_index(states) is None
    np.testing.assert_array_equal(out.leg_targets,
                                  np.broadcast_to(np.asarray(stand_leg_targets(params)),
                                                  (N_PERIODS, 12)))


@pytest.mark.parametrize("direction,pitch_deg,rate,cp_gain",
                         [("forward", 15.0, 0.5, 1.0), ("forward", 15.0, 0.5, 1.5),
                          ("backward", -5.0, -0.5, 1.0)])
def test_push_triggers_one_recovery_step(params, kin, direction, pitch_deg, rate, cp_gain):
    p = dataclasses.replace(params, cp_gain=cp_gain)
    dt, T = p.control_period, p.step_period
    states, out = _np(_run(p, *_imu(pitch_deg, rate), 1.0))
    k = _trigger_index(states)
    assert k is not None
    phi_k = float(out.phi[k])
    # Triggered by the threshold of its direction, and not before.
    if direction == "forward":
        assert phi_k > p.eps_forward and np.all(out.phi[:k] <= p.eps_forward)
    else:
        assert phi_k < -p.eps_backward and np.all(out.phi[:k] >= -p.eps_backward)
    assert states.phi_at_detect[k] == phi_k
    # Latched once: x_Sup, start time, detection angle never change afterwards.
    x_sup = float(states.x_sup_m[k])
    for leaf in (states.x_sup_m, states.step_start_s, states.phi_at_detect):
        assert np.all(leaf[k:] == leaf[k])
    assert np.all(states.x_sup_m[:k] == 0)
    assert states.step_start_s[k] == pytest.approx(k * dt, abs=1e-5)
    want_x = cp_gain * float(capture_point(phi_k - p.cp_angle_offset, p.leg_length, p.com_height,
                                           p.gravity))
    assert x_sup == pytest.approx(want_x, rel=1e-5)
    assert (x_sup > 0) if direction == "forward" else (x_sup < 0)
    assert 0.01 < abs(x_sup) < 0.15

    # Before the trigger: stand targets. From the trigger on: the CPG step from t = 0.
    stand = np.asarray(stand_leg_targets(p))
    np.testing.assert_array_equal(out.leg_targets[:k], np.broadcast_to(stand, (k, 12)))
    t = np.arange(N_PERIODS - k) * dt
    p_r, p_l = cpg_feet(jnp.asarray(t, jnp.float32), jnp.full(t.shape, x_sup, jnp.float32), p)
    want_q, reachable = solve_legs(p_r, p_l, p)
    assert np.all(out.reachable) and bool(np.all(reachable))
    np.testing.assert_allclose(out.leg_targets[k:], np.asarray(want_q), rtol=0, atol=1e-5)

    # Through MuJoCo: the left ankle moves by x_Sup/2 (monotonically) over T, the right by
    # -x_Sup/2, then both hold; the targets after T are constant.
    feet = np.array([kin.feet(q)[0] for q in out.leg_targets[k:]])
    left_x = feet[:, 1, 0] * np.sign(x_sup)
    assert feet[0, 1, 0] == pytest.approx(0.0, abs=POS_TOL_M)
    assert np.all(np.diff(left_x) >= -1e-6)
    done = t >= T - 1e-6
    assert done.sum() > 10
    np.testing.assert_allclose(feet[done, 1, 0], x_sup / 2, atol=POS_TOL_M)
    np.testing.assert_allclose(feet[done, 0, 0], -x_sup / 2, atol=POS_TOL_M)
    lift = feet[:, 1, 2] - feet[0, 1, 2]
    assert lift.max() == pytest.approx(p.lift_height, abs=2e-3)
    np.testing.assert_allclose(out.leg_targets[k:][done],
                               out.leg_targets[k:][done][:1].repeat(done.sum(), 0),
                               rtol=0, atol=1e-6)


@pytest.mark.parametrize("pitch_deg,rate", [(15.0, 0.5), (-5.0, -0.5), (7.0, 0.0)])
def test_disabled_never_steps(params, pitch_deg, rate):
    states, out = _np(_run(params, *_imu(pitch_deg, rate), 0.0))
    assert np.all(out.gate == 0) and np.all(states.step_weight == 0) and np.all(states.x_sup_m == 0)
    np.testing.assert_array_equal(out.leg_targets,
                                  np.broadcast_to(np.asarray(stand_leg_targets(params)),
                                                  (N_PERIODS, 12)))


def test_soft_gate_gradients(params):
    """gate_temperature > 0: gate strictly inside (0, 1), and the final left-ankle-pitch target
    is differentiable (finite, non-zero) in the thresholds, the step timing and size."""
    p = dataclasses.replace(params, gate_temperature=math.radians(1.0))
    n = 15
    # A ramp 7 -> ~18 deg with the matching gyro rate: the step starts mid-run, so the last
    # period is inside the swing and every parameter below shapes the final target.
    slope_deg = 0.8
    gyro, accel = _imu(7.0 + slope_deg * np.arange(n),
                       math.radians(slope_deg) / p.control_period, n)

    def final_l_ankle_pitch(q):
        return _scan(q, gyro, accel, 1.0)[1].leg_targets[-1, L_ANKLE_PITCH]

    states, out = _np(jax.jit(_scan)(p, gyro, accel, 1.0))
    assert np.all((out.gate > 0) & (out.gate < 1))
    k = int(np.argmax(states.step_weight >= 0.5))
    assert 0 < k < n - 1 and states.step_weight[k - 1] < 0.5
    t_final = (n - 1 - k) * p.control_period
    assert 0.5 * p.double_support_ratio * p.step_period < t_final < p.step_period

    grads = jax.jit(jax.grad(final_l_ankle_pitch))(p)
    for name in ("eps_forward", "step_period", "lift_height", "cp_gain"):
        g = float(getattr(grads, name))
        assert math.isfinite(g), f"d target / d {name} = {g}"
        assert g != 0.0, f"d target / d {name} is 0"
    assert all(np.isfinite(np.asarray(leaf)).all() for leaf in jax.tree_util.tree_leaves(grads))


def test_params_are_traced_not_static(params):
    traces = []

    @jax.jit
    def run(q, gyro, accel):
        traces.append(1)
        return _scan(q, gyro, accel, 1.0)

    gyro, accel = _imu(15.0, 0.5, 40)
    other = dataclasses.replace(params, eps_forward=math.radians(10.0), step_period=0.25,
                                lift_height=0.02, cp_gain=1.3, gate_temperature=0.01,
                                cp_angle_offset=0.0)
    a = _np(run(params, gyro, accel))
    b = _np(run(other, gyro, accel))
    assert len(traces) == 1
    assert not np.allclose(a[1].leg_targets, b[1].leg_targets)  # the values are really used


def test_vmap_matches_unbatched(params):
    """64 different sensor sequences (standing, forward and backward pushes of several sizes)."""
    n_batch = 64
    tilts = np.concatenate([np.linspace(-8.0, -3.0, 16), np.linspace(0.0, 10.0, 16),
                            np.linspace(13.0, 22.0, 32)])
    rates = (np.where(tilts > 12, 0.4, np.where(tilts < -2, -0.4, 0.0))
             * np.linspace(0.5, 1.5, n_batch))
    seqs = [_imu(a, r) for a, r in zip(tilts, rates)]
    gyro = np.stack([s[0] for s in seqs])
    accel = np.stack([s[1] for s in seqs])
    batched = _np(jax.jit(jax.vmap(_scan, in_axes=(None, 0, 0, None)))(params, gyro, accel, 1.0))
    assert batched[1].leg_targets.shape == (n_batch, N_PERIODS, 12)
    stepped = batched[0].step_weight[:, -1] == 1
    assert 0 < stepped.sum() < n_batch
    for i in range(n_batch):
        single = _np(_run(params, gyro[i], accel[i], 1.0))
        for b_leaf, s_leaf in zip(jax.tree_util.tree_leaves(batched),
                                  jax.tree_util.tree_leaves(single)):
            if b_leaf.dtype == bool:
                np.testing.assert_array_equal(b_leaf[i], s_leaf)
            else:
                np.testing.assert_allclose(b_leaf[i], s_leaf, rtol=1e-5, atol=1e-6)
