"""The closed loop (MJX physics + the paper's controller) under pushes, and the push models.

One batch of 8 pushes is simulated once for the whole module through
`tkujax.sim.rollout_mjx.simulate` with `ControllerParams.paper()` and the default
`RolloutConfig()` (2.4 s, hit at 0.75 s). It is deliberately the same batch shape and config as
`tkujax paper` (tests/test_paper.py), so the compiled function (~40-80 s on a CPU) is shared
through `sim.batched_rollout`'s cache. The "stands 3 s" check runs on the MuJoCo C backend
(`tkujax.sim.rollout_mujoco.simulate_mujoco`, which only compiles the controller), so it needs
no second MJX compile for a longer scan.

What is asserted here is qualitative closed-loop behaviour at impulses chosen for the default
(calibrated) model, not the paper's exact outcome table. The paper's Tables 4-5 are a separate
fidelity comparison, written by `tkujax paper` to results/paper/table.md and discussed in the
README; they are not tuned into these tests. On this model the no-control fall threshold from
the back lies between 0.60 and 0.68 N s, and the controller's step thresholds (Kalman phi > 12
deg or phi < -2 deg, phi including the ~7 deg standing lean) are crossed at 0.6 N s from the
back and 0.9 N s from the front, which the uncontrolled robot survives. With the paper's
parameters the stepping robot is still swaying at the end of the 2.4 s horizon ("not
settled"): a finding of the calibration (README), so recovery is asserted only for control off.

Run with -s to see the measured numbers.
"""

import math

import jax
import numpy as np
import pytest

from tkujax.sim import rollout_mujoco as backend_mujoco
from tkujax.sim import ball_rig
from tkujax.sim import physics
from tkujax.sim import rollout_mjx as sim
from tkujax.sim import push as push_lib
from tkujax.control.controller_params import ControllerParams
from tkujax.sim.push import G, ball_momentum_ns, ball_push, ball_speed_m_s, force_at, make_push

ROBOT_MASS_KG = 4.5
ONSET_S = push_lib.PAPER_ONSET_S
STEP_BACK_NS = 0.6         # crosses the 12 deg detection threshold; survived without control
STEP_FRONT_NS = 0.9        # crosses the -2 deg threshold; survived without control
TOPPLE_IMPULSE_NS = 2.2    # well above this model's no-control threshold from the back (0.6-0.7)

# name -> (Push, balance control 0/1). Order is the batch order; 8 = the paper command's batch.
CASES = {
    "no_push_on": (make_push(0.0), 1.0),
    "baseball_back_off": (ball_push("baseball", "back"), 0.0),
    "strong_back_off": (make_push(TOPPLE_IMPULSE_NS, 0.0), 0.0),
    "step_back_on": (make_push(STEP_BACK_NS, 0.0), 1.0),
    "step_front_on": (make_push(STEP_FRONT_NS, 180.0), 1.0),
    "no_push_off": (make_push(0.0), 0.0),
    "step_back_off": (make_push(STEP_BACK_NS, 0.0), 0.0),
    "step_front_off": (make_push(STEP_FRONT_NS, 180.0), 0.0),
}
NAMES = list(CASES)
IDX = {name: i for i, name in enumerate(NAMES)}
CONFIG = sim.RolloutConfig()                     # the paper command's config: shares the compile
N_TICKS = int(round(CONFIG.duration_s / CONFIG.control_period_s))


def _batch(names):
    pushes = push_lib.stack_pushes([CASES[n][0] for n in names])
    enabled = np.array([CASES[n][1] for n in names], np.float32)
    return pushes, enabled


@pytest.fixture(scope="module")
def run():
    pushes, enabled = _batch(NAMES)
    series, outcomes = sim.simulate(pushes, enabled, ControllerParams.paper(), config=CONFIG)
    print("\ncase                 fell  recovery_s  step_cm  capture_pt_cm  peak_dev_deg  "
          "phi_est range deg")
    for n, i in IDX.items():
        phi = np.degrees(series["pitch_est"][i])
        print(f"{n:20s} {int(outcomes['fell'][i])}     {outcomes['recovery_time_s'][i]:6.2f}"
              f"    {100 * outcomes['step_length_m'][i]:6.2f}   "
              f"{100 * outcomes['capture_point_m'][i]:6.2f}         "
              f"{outcomes['peak_incl_deg'][i]:7.2f}      {phi.min():6.2f} .. {phi.max():6.2f}")
    return series, outcomes


@pytest.fixture(scope="module")
def standing_pitch_deg():
    """Pelvis pitch of the settled stand pose (the state every rollout starts from)."""
    data = physics.settled_stand_data(physics.host_model(), 1.0)
    pitch, _ = physics.pitch_roll_from_quat(np.asarray(data.qpos[3:7]))
    return math.degrees(float(pitch))


# --- the batch: jit / vmap, shapes, finiteness ------------------------------------------------

@pytest.mark.slow
def test_batch_shapes_and_time_axis(run):
    series, outcomes = run
    n = len(NAMES)
    for key, arr in series.items():
        assert arr.shape[:2] == (n, N_TICKS), key
    for key in ("zmp",):
        assert series[key].shape == (n, N_TICKS, 2)
    for key in ("com", "r_ankle", "l_ankle"):
        assert series[key].shape == (n, N_TICKS, 3)
    for key, arr in outcomes.items():
        assert arr.shape == (n,), key
    # Sampled at the end of each 30 ms control period, for every push alike.
    expected_t = CONFIG.control_period_s * np.arange(1, N_TICKS + 1)
    np.testing.assert_allclose(series["t"], np.broadcast_to(expected_t, (n, N_TICKS)), atol=1e-4)


@pytest.mark.slow
def test_outputs_finite(run):
    series, outcomes = run
    for key, arr in series.items():
        assert np.all(np.isfinite(arr)), key
    for key, arr in outcomes.items():
        if key in ("recovery_time_s", "recovery_time_pitch_s"):  # NaN: fell or "not settled"
            assert np.all(np.isnan(arr[outcomes["fell"].astype(bool)])), key
            ok = arr[np.isfinite(arr)]
            assert not np.any(np.isinf(arr)) and np.all((ok >= 0) & (ok <= CONFIG.duration_s)), key
        else:
            assert np.all(np.isfinite(arr)), key


@pytest.mark.slow
def test_vmap_rows_independent_and_jit_reused(run, compiles):
    """Reversing the batch reverses the results (rows do not mix), with no recompilation."""
    _, outcomes = run
    rev = NAMES[::-1]
    pushes, enabled = _batch(rev)
    compiles.reset()
    _, out_rev = sim.simulate(pushes, enabled, ControllerParams.paper(), config=CONFIG)
    assert compiles.count == 0, f"the same batch shape compiled again: {compiles.names}"
    for key in ("fell", "step_length_m", "capture_point_m", "peak_incl_deg"):
        np.testing.assert_allclose(out_rev[key], outcomes[key][::-1], atol=1e-5, err_msg=key)


# --- behaviour --------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["no_push_on", "no_push_off"])
@pytest.mark.slow
def test_no_push_stands_whole_horizon(run, standing_pitch_deg, name):
    series, outcomes = run
    i = IDX[name]
    assert not outcomes["fell"][i]
    pitch = np.degrees(series["pitch"][i])
    assert np.max(np.abs(pitch - standing_pitch_deg)) < 1.0
    assert np.all(series["x_sup"][i] == 0.0)          # the controller never detects a push
    assert abs(outcomes["step_length_m"][i]) < 1e-3


def test_no_push_stands_3s_mujoco_backend(standing_pitch_deg):
    """"No push -> stands 3 s", control on and off (MuJoCo C physics, same loop)."""
    config = sim.RolloutConfig(duration_s=3.0)
    pushes = push_lib.stack_pushes([make_push(0.0), make_push(0.0)])
    series, outcomes = backend_mujoco.simulate_mujoco(
        pushes, np.array([1.0, 0.0], np.float32), ControllerParams.paper(), config=config)
    assert series["t"].shape == (2, 100)
    assert series["t"][0, -1] == pytest.approx(3.0, abs=1e-6)
    assert not np.any(outcomes["fell"])
    pitch = np.degrees(series["pitch"])
    print(f"\n3 s stand (MuJoCo C): pitch {pitch.min():.3f} .. {pitch.max():.3f} deg, "
          f"settled stand {standing_pitch_deg:.3f} deg")
    assert np.max(np.abs(pitch - standing_pitch_deg)) < 1.0
    assert np.all(series["x_sup"] == 0.0)


@pytest.mark.slow
def test_baseball_from_back_control_off_recovers(run):
    series, outcomes = run
    i = IDX["baseball_back_off"]
    assert not outcomes["fell"][i]
    assert np.isfinite(outcomes["recovery_time_s"][i])
    assert outcomes["peak_incl_deg"][i] > 0.2                   # it was actually pushed


@pytest.mark.slow
def test_strong_push_from_back_control_off_falls(run):
    """2.2 N s (not the paper's volleyball, see the module doc) topples the uncontrolled robot."""
    series, outcomes = run
    i = IDX["strong_back_off"]
    assert outcomes["fell"][i]
    assert np.isnan(outcomes["recovery_time_s"][i])
    # It falls forward, the way it was pushed.
    assert np.degrees(series["pitch"][i]).max() > 45.0


@pytest.mark.slow
def test_push_from_back_control_on_recovers_with_forward_step(run):
    series, outcomes = run
    i = IDX["step_back_on"]
    assert np.degrees(series["pitch_est"][i]).max() > 12.0      # crossed epsilon_1
    assert not outcomes["fell"][i]
    assert outcomes["step_length_m"][i] > 0.01
    assert outcomes["capture_point_m"][i] > 0.0
    # The same push without control: no step (the step is the controller's), and it recovers.
    assert abs(outcomes["step_length_m"][IDX["step_back_off"]]) < 0.005
    assert np.isfinite(outcomes["recovery_time_s"][IDX["step_back_off"]])


@pytest.mark.slow
def test_push_from_front_control_on_steps_backward(run):
    series, outcomes = run
    i = IDX["step_front_on"]
    assert np.degrees(series["pitch_est"][i]).min() < -2.0      # crossed -epsilon_2
    assert not outcomes["fell"][i]
    assert outcomes["step_length_m"][i] < -0.01
    assert outcomes["capture_point_m"][i] < 0.0
    assert abs(outcomes["step_length_m"][IDX["step_front_off"]]) < 0.005


@pytest.mark.slow
def test_control_off_never_latches_a_step(run):
    series, outcomes = run
    off = [IDX[n] for n in NAMES if CASES[n][1] == 0.0]
    for key in ("x_sup", "y_sup", "step_weight", "gate"):
        assert np.all(series[key][off] == 0.0), key
    assert np.all(outcomes["capture_point_m"][off] == 0.0)
    # ... while the same pushes with control on do latch one.
    assert np.all(series["step_weight"][[IDX["step_back_on"], IDX["step_front_on"]], -1] == 1.0)


# --- series sanity while standing ----------------------------------------------------------------

def _standing_ticks(series, i):
    return series["t"][i] <= ONSET_S


@pytest.mark.slow
def test_sole_forces_carry_the_weight_while_standing(run):
    series, _ = run
    mg = ROBOT_MASS_KG * G
    assert physics.host_model().body_subtreemass[0] == pytest.approx(ROBOT_MASS_KG, rel=1e-6)
    for name in ("no_push_on", "baseball_back_off", "step_back_on"):
        i = IDX[name]
        total = series["fsr_total"][i][_standing_ticks(series, i)]
        np.testing.assert_allclose(total, mg, rtol=0.03, err_msg=name)
    total = series["fsr_total"][IDX["no_push_on"]]
    print(f"\nsum of the 8 sole forces standing: {total.min():.3f} .. {total.max():.3f} N "
          f"(m g = {mg:.3f} N)")


def _convex_hull(points):
    """Counter-clockwise convex hull of 2-D points (Andrew's monotone chain)."""
    pts = sorted(map(tuple, np.asarray(points, float)))

    def half(seq):
        out = []
        for p in seq:
            while len(out) >= 2 and np.cross(np.subtract(out[-1], out[-2]),
                                             np.subtract(p, out[-2])) <= 0:
                out.pop()
            out.append(p)
        return out[:-1]

    return np.array(half(pts) + half(pts[::-1]))


def _inside_margin(hull, p):
    """Signed distance of p inside the CCW polygon (positive inside)."""
    d = []
    for a, b in zip(hull, np.roll(hull, -1, axis=0)):
        edge = b - a
        d.append(np.cross(edge, p - a) / np.linalg.norm(edge))
    return min(d)


@pytest.mark.slow
def test_zmp_inside_support_polygon_while_standing(run):
    """ZMP (sole sensors' centre of pressure) well inside the two feet, under the CoM."""
    series, _ = run
    model = physics.host_model()
    data = physics.settled_stand_data(model, 1.0)
    hull = _convex_hull(data.site_xpos[sim.model_index().fsr_sites, :2])
    for name in ("no_push_on", "no_push_off", "step_back_on"):
        i = IDX[name]
        standing = _standing_ticks(series, i) if name == "step_back_on" else slice(None)
        zmp, com = series["zmp"][i][standing], series["com"][i][standing]
        margins = np.array([_inside_margin(hull, z) for z in zmp])
        assert margins.min() > 0.02, name     # > 2 cm from every edge of the support polygon
        # Static standing: the centre of pressure is under the centre of mass.
        assert np.max(np.linalg.norm(zmp - com[:, :2], axis=-1)) < 0.005, name


# --- the push models --------------------------------------------------------------------------

@pytest.mark.parametrize("impulse,azimuth_deg,direction", [
    (0.5, 0.0, (1.0, 0.0, 0.0)), (1.3, 90.0, (0.0, 1.0, 0.0)), (0.25, 180.0, (-1.0, 0.0, 0.0))])
def test_force_at_integrates_to_impulse_along_azimuth(impulse, azimuth_deg, direction):
    push = make_push(impulse, azimuth_deg, duration_s=0.02, onset_s=0.75)
    dt = 1e-6
    t = np.arange(0.74, 0.78, dt)
    f = np.asarray(jax.vmap(lambda s: force_at(push, s))(t), np.float64)
    total = np.trapezoid(f, dx=dt, axis=0) if hasattr(np, "trapezoid") else np.trapz(f, dx=dt,
                                                                                      axis=0)
    assert np.linalg.norm(total) == pytest.approx(impulse, rel=0.005)
    np.testing.assert_allclose(total / np.linalg.norm(total), direction, atol=1e-5)
    # Zero outside [onset, onset + duration), peak J pi / (2 tau) in the middle.
    outside = (t < 0.75 - 1e-5) | (t >= 0.77 + 1e-5)
    assert np.all(f[outside] == 0.0)
    peak = np.asarray(force_at(push, 0.76))
    assert np.linalg.norm(peak) == pytest.approx(impulse * math.pi / (2 * 0.02), rel=1e-4)


def test_pendulum_length_gives_quarter_swing_of_034s():
    """RK4 of theta'' = -(g/L) sin(theta) from 45 deg at rest reaches the bottom at 0.34 s."""
    length = push_lib.pendulum_length_m()
    w2 = G / length

    def rhs(y):
        return np.array([y[1], -w2 * math.sin(y[0])])

    dt = 1e-4
    y, t = np.array([math.radians(45.0), 0.0]), 0.0
    while True:
        k1 = rhs(y)
        k2 = rhs(y + 0.5 * dt * k1)
        k3 = rhs(y + 0.5 * dt * k2)
        k4 = rhs(y + dt * k3)
        y_next = y + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        if y_next[0] <= 0.0:
            frac = y[0] / (y[0] - y_next[0])          # linear interpolation of the crossing
            t_bottom, v_bottom = t + frac * dt, length * abs(y[1] + frac * (y_next[1] - y[1]))
            break
        y, t = y_next, t + dt
    print(f"\npendulum L = {length:.4f} m: bottom at {t_bottom:.5f} s, {v_bottom:.4f} m/s")
    assert t_bottom == pytest.approx(push_lib.FALLING_TIME_S, rel=1e-3)
    assert v_bottom == pytest.approx(ball_speed_m_s(), rel=1e-3)
    # Not the small-angle formula: a 45 deg swing is slower, so the length that gives 0.34 s is
    # ~7.5 % shorter than g (2 T / pi)^2.
    small_angle = G * (2 * push_lib.FALLING_TIME_S / math.pi) ** 2
    assert length < 0.95 * small_angle


# Tolerance of the impulse model against the physical ball rig, as stated in
# tkujax/ball_rig.py's docstring: the ball delivers 1.02-1.12 J, "J agrees with the physical rig
# within ~12 %" (tests/test_ball_rig.py pins each case to its measured ratio).
RIG_AGREEMENT_TOL = 0.12


@pytest.mark.parametrize("ball,direction", [("volleyball", "back"), ("baseball", "front")])
def test_ball_rig_and_impulse_model_agree_on_momentum(ball, direction):
    rig = ball_rig.ball_rig_impulse(ball, direction)
    j = ball_momentum_ns(ball)
    ratio = rig["delivered_ns"] / j
    print(f"\n{ball} {direction}: rig delivers {rig['delivered_ns']:.4f} N s, impulse model "
          f"J = {j:.4f} N s, ratio {ratio:.3f}")
    assert rig["impulse_model_ns"] == pytest.approx(j)
    assert abs(ratio - 1.0) <= RIG_AGREEMENT_TOL
    # The paper's case applies J times the calibrated contact's impulse factor (its default),
    # and the front hit's ratio to it from the front.
    contact = push_lib.BallContact()
    factor = contact.impulse_factor * (contact.front_impulse_ratio if direction == "front"
                                       else 1.0)
    assert float(ball_push(ball, direction).impulse_ns) == pytest.approx(factor * j, rel=1e-6)
    assert float(ball_push(ball, direction).height_m) == pytest.approx(
        contact.contact_height_m(direction), abs=1e-6)
    assert float(ball_push(ball, direction, contact=push_lib.BallContact.estimated()).impulse_ns) \
        == pytest.approx(j, rel=1e-6)
