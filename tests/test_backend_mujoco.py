"""The MuJoCo C backend against the MJX one, plus its own plumbing.

The MJX batch compiles once for this module (~40-60 s on CPU); its batch shape stays fixed.
Timings and the per-case table are printed (run with -s to see them), never asserted.
"""

import dataclasses
import math
import time
import types

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from tkujax.sim import rollout_mujoco as bm
from tkujax.sim.closed_loop import push_wrench
from tkujax.sim.robot import builtin_robot
from tkujax.sim import push as push_lib
from tkujax.sim import rollout_mjx as sim
from tkujax.control.controller_params import ControllerParams

# (impulse N s, azimuth deg, balance control 0/1): small/large pushes from behind and in front.
CASES = [(0.3, 0.0, 0.0), (0.9, 0.0, 1.0), (1.5, 0.0, 1.0), (2.2, 0.0, 0.0),
         (0.3, 180.0, 1.0), (0.9, 180.0, 0.0), (1.5, 180.0, 1.0), (2.2, 180.0, 1.0)]
ONSET_S = push_lib.PAPER_ONSET_S


def _batch():
    pushes = push_lib.stack_pushes([push_lib.make_push(i, a) for i, a, _ in CASES])
    enabled = np.array([c for *_, c in CASES], np.float32)
    return pushes, enabled


def _timed(f, *args, **kw):
    t0 = time.perf_counter()
    out = f(*args, **kw)
    return out, time.perf_counter() - t0


@pytest.fixture(scope="module")
def runs():
    pushes, enabled = _batch()
    params = ControllerParams.paper()
    (mjx_out, mjx_first_s) = _timed(sim.simulate, pushes, enabled, params)
    (mjx_out, mjx_s) = _timed(sim.simulate, pushes, enabled, params)        # after compile
    (_, c_first_s) = _timed(bm.simulate_mujoco, pushes, enabled, params)
    (c_out, c_s) = _timed(bm.simulate_mujoco, pushes, enabled, params)      # after compile
    (ps_out, ps_s) = _timed(bm.simulate_mujoco, pushes, enabled, params,
                            push_wrench="period_start")
    print(f"\nwall time, {len(CASES)} pushes x {sim.RolloutConfig().duration_s} s: "
          f"MJX {mjx_s:.2f} s (first call with compile {mjx_first_s:.1f} s); "
          f"MuJoCo C exact {c_s:.2f} s (first call {c_first_s:.1f} s); "
          f"MuJoCo C period_start {ps_s:.2f} s")
    return dict(mjx=mjx_out, c=c_out, ps=ps_out)


@pytest.mark.slow
def test_same_keys_shapes_dtypes(runs):
    (sm, om), (sc, oc) = runs["mjx"], runs["c"]
    assert sm.keys() == sc.keys() and om.keys() == oc.keys()
    for k in sm:
        assert isinstance(sc[k], np.ndarray)
        assert (sc[k].shape, sc[k].dtype) == (sm[k].shape, sm[k].dtype), k
    for k in om:
        assert isinstance(oc[k], np.ndarray)
        assert (oc[k].shape, oc[k].dtype) == (om[k].shape, om[k].dtype), k
    np.testing.assert_allclose(sc["t"], sm["t"], atol=1e-4)


@pytest.mark.slow
def test_fall_outcomes_agree_with_mjx(runs):
    (_, om), (_, oc) = runs["mjx"], runs["c"]
    print("\nimpulse az ctrl |  MJX: fell  rec_s  step_cm | MuJoCo: fell  rec_s  step_cm")
    for j, (imp, az, ctrl) in enumerate(CASES):
        print(f"  {imp:.1f} {az:5.0f}  {'on ' if ctrl else 'off'} |"
              f"       {int(om['fell'][j])}  {om['recovery_time_s'][j]:5.2f}  "
              f"{100 * om['step_length_m'][j]:6.2f}  |"
              f"         {int(oc['fell'][j])}  {oc['recovery_time_s'][j]:5.2f}  "
              f"{100 * oc['step_length_m'][j]:6.2f}")
    agree = int(np.sum(om["fell"] == oc["fell"]))
    print(f"fall outcomes agree on {agree}/{len(CASES)}")
    assert agree >= len(CASES) - 1
    assert om["fell"].any() and not om["fell"].all()   # the batch spans both outcomes


@pytest.mark.slow
def test_pre_push_standing_agrees(runs):
    (sm, om), (sc, oc) = runs["mjx"], runs["c"]
    pre = sm["t"][0] <= ONSET_S
    assert pre.sum() > 10
    d_pitch = np.degrees(np.abs(sm["pitch"][:, pre] - sc["pitch"][:, pre])).max()
    d_est = np.degrees(np.abs(sm["pitch_est"][:, pre] - sc["pitch_est"][:, pre])).max()
    d_com = np.abs(sm["com"][:, pre] - sc["com"][:, pre]).max()
    print(f"\npre-push max |MJX - MuJoCo|: pitch {d_pitch:.4f} deg, pitch_est {d_est:.4f} deg, "
          f"CoM {1000 * d_com:.3f} mm")
    assert d_pitch < 0.3
    assert d_est < 0.3
    assert d_com < 2e-3
    np.testing.assert_allclose(oc["standing_pitch_deg"], om["standing_pitch_deg"], atol=0.3)
    assert not np.any(sc["gate"][:, pre])               # no detection while standing


@pytest.mark.slow
def test_period_start_wrench_approximation(runs):
    """Freezing the lever arm at the period's first step: measure what it changes."""
    (sc, oc), (sp, op) = runs["c"], runs["ps"]
    ok = ~oc["fell"] & ~op["fell"]
    d_pitch = np.degrees(np.abs(sc["pitch"] - sp["pitch"]).max(1))
    d_step = 100 * np.abs(oc["step_length_m"] - op["step_length_m"])
    both_nan = np.isnan(oc["recovery_time_s"]) & np.isnan(op["recovery_time_s"])
    d_rec = np.where(both_nan, 0.0, np.abs(oc["recovery_time_s"] - op["recovery_time_s"]))
    print(f"\nperiod_start vs exact wrench: max pitch diff per case (deg) {d_pitch.round(3)}; "
          f"step length diff (cm) {d_step.round(3)}; recovery time diff (s) {d_rec.round(3)}")
    np.testing.assert_array_equal(oc["fell"], op["fell"])
    assert d_pitch[ok].max() < 1.0


def test_push_wrench_twin_matches_sim():
    """_force/_wrench reproduce push.force_at and closed_loop.push_wrench on tilted chest poses."""
    setup = bm._setup(builtin_robot())
    m, idx = setup.model, setup.index
    data = mujoco.MjData(m)
    mujoco.mj_setState(m, data, np.asarray(setup.state0), bm._FULL)
    data.qpos[3:7] = [math.cos(0.2), 0.05, math.sin(0.2), 0.02]
    data.qpos[3:7] /= np.linalg.norm(data.qpos[3:7])
    data.qpos[7:] += 0.1
    mujoco.mj_kinematics(m, data)
    b = idx.chest_body
    samples = [(1.2, 30.0, 0.36, 0.755), (0.7, 180.0, 0.30, 0.761), (2.0, 0.0, 0.40, 0.7)]
    for imp, az, h, t in samples:
        push = push_lib.make_push(imp, az, height_m=h)
        d = types.SimpleNamespace(time=jnp.float32(t), xpos=jnp.asarray(data.xpos),
                                  xmat=jnp.asarray(data.xmat.reshape(-1, 3, 3)),
                                  xipos=jnp.asarray(data.xipos),
                                  xfrc_applied=jnp.zeros((m.nbody, 6)))
        ref = np.asarray(push_wrench(idx, d, push))
        p = {k: np.atleast_1d(np.asarray(getattr(push, k), np.float64))
             for k in ("impulse_ns", "azimuth_rad", "height_m", "duration_s", "onset_s")}
        force = bm._force(p, np.array([[t]]))
        pose = (data.xpos[b][None], data.xmat[b].reshape(1, 3, 3), data.xipos[b][None])
        got = bm._wrench(idx, pose, p["height_m"], force)[0, 0]
        np.testing.assert_allclose(got, ref[b], rtol=1e-4, atol=1e-4 * np.abs(ref[b]).max())
        assert np.abs(np.delete(ref, b, 0)).max() == 0.0


def test_chunked_rollout_is_one_trajectory():
    """Chaining rollout chunks with the recovered warm start = one uninterrupted mj_step loop."""
    setup = bm._setup(builtin_robot())
    m = setup.model
    ctrl = np.array(m.key("stand").ctrl) + 0.05 * np.random.default_rng(0).standard_normal(m.nu)
    data = mujoco.MjData(m)
    mujoco.mj_setState(m, data, np.asarray(setup.state0), bm._FULL)
    data.qacc_warmstart[:] = setup.warmstart0
    data.ctrl[:] = ctrl
    for _ in range(45):
        mujoco.mj_step(m, data)
    ref = np.empty(setup.state0.size)
    mujoco.mj_getState(m, data, ref, bm._FULL)

    pool, datas = bm._rollout_pool(0), [mujoco.MjData(m)]
    state, warm, qv = np.asarray(setup.state0)[None], setup.warmstart0[None], setup.qvel_slice
    for _ in range(3):
        states, _ = pool.rollout(m, datas, state, ctrl[None, None], initial_warmstart=warm,
                                 nstep=15)
        warm = (states[:, -1, qv] - states[:, -2, qv]) / m.opt.timestep
        state = states[:, -1]
    np.testing.assert_allclose(state[0], ref, atol=1e-9)
    np.testing.assert_allclose(warm[0], data.qacc_warmstart, atol=1e-6)


def test_noise_threads_and_validation():
    """Short runs: noise is seeded, thread count does not change results, bad mode raises."""
    config = dataclasses.replace(sim.RolloutConfig(), duration_s=0.3)
    pushes = push_lib.stack_pushes([push_lib.make_push(1.0, 0.0, onset_s=0.1),
                                    push_lib.make_push(1.0, 180.0, onset_s=0.1)])
    params = ControllerParams.paper()
    run = lambda **kw: bm.simulate_mujoco(pushes, 1.0, params, config=config, **kw)  # noqa: E731
    s1, o1 = run(n_threads=1)
    s2, _ = run(n_threads=2)
    for k in s1:
        np.testing.assert_array_equal(s1[k], s2[k], err_msg=k)
    assert s1["t"].shape == (2, 10)
    noisy_a, _ = run(gyro_noise_std=0.05, accel_noise_std=0.5, seed=3)
    noisy_b, _ = run(gyro_noise_std=0.05, accel_noise_std=0.5, seed=3)
    noisy_c, _ = run(gyro_noise_std=0.05, accel_noise_std=0.5, seed=4)
    np.testing.assert_array_equal(noisy_a["pitch_est"], noisy_b["pitch_est"])
    assert np.abs(noisy_a["pitch_est"] - noisy_c["pitch_est"]).max() > 1e-4
    assert np.abs(noisy_a["pitch_est"] - s1["pitch_est"]).max() > 1e-4
    rec, _ = bm.simulate_mujoco(pushes, 0.0, params, config=dataclasses.replace(
        config, record_qpos=True))
    assert rec["qpos"].shape == (2, 10, bm._setup(builtin_robot()).model.nq)
    with pytest.raises(ValueError, match="push_wrench"):
        run(push_wrench="sometimes")
