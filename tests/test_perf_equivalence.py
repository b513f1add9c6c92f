"""The performance work keeps the closed loop's results: the sweeps' chunk (make_chunk_fn) gives
the outcomes stored below, computed with the code before it (commit 694af53, CPU, float32), and
the bench's profile loop, the remat modes and the scan unrolling give the same outcomes.

Batch 4 x 1.5 s, the shape of tests/test_sweep.py's tiny sweep: the chunk's program is shared
through the persistent cache. The four pushes: a small forward push that recovers, a large one
without control (falls), a backward push with a heavier robot, a sideways push with softer
servos and sensor noise."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.sweeps.sweep import make_chunk_fn, traced_params

N = 4
RECORDS = dict(impulse_ns=[0.4, 2.5, 1.6, 2.5], azimuth_deg=[0.0, 0.0, 180.0, 90.0],
               height_m=[0.36] * N, duration_s=[0.02] * N, onset_s=[0.3] * N,
               control=[1.0, 0.0, 1.0, 1.0], link_mass_scale=[1.0, 1.0, 1.1, 1.0],
               torso_com_offset_x_m=[0.0] * N, floor_friction=[-1.0] * N,
               servo_kp_scale=[1.0, 1.0, 1.0, 0.9], gyro_noise_std=[0.0, 0.02, 0.0, 0.02],
               accel_noise_std=[0.0, 0.1, 0.0, 0.0])
nan = math.nan
# make_chunk_fn((), 1.5) with MJX's tree passes (the sweeps' before "compact") at commit 694af53
# on the CPU (keys: PRNGKey(3) split 4 ways);
# re-stored when the default robot gained its IMU low-pass (7.5 Hz accelerometer,
# ModelParams.accel_lowpass_hz):
# only the third push (backward, control on) changed, as the filtered IMU moves its step.
STORED = {
    "capture_point_m": [0.0, 0.0, -0.0692421942949295, 0.0],
    "capture_point_y_m": [0.0, 0.0, 0.0, 0.0],
    "diverged": [0.0, 0.0, 0.0, 0.0],
    "fell": [0.0, 1.0, 0.0, 1.0],
    "peak_incl_deg": [2.694120168685913, 202.85546875, 12.816699981689453, 142.61505126953125],
    "recovery_time_s": [0.5699958801269531, nan, nan, nan],
    "step_length_m": [0.00012799352407455444, 0.09710676968097687, -0.021587524563074112,
                      0.00032892078161239624],
    "step_width_m": [0.0, 1.1175870895385742e-08, -0.013595756143331528, 0.10227169096469879],
    "zmp_excursion_m": [0.025744300335645676, 0.04164246469736099, 0.12573905289173126,
                        0.15175911784172058],
}


def _inputs():
    recs = {k: jnp.asarray(v, jnp.float32) for k, v in RECORDS.items()}
    return recs, jax.random.split(jax.random.PRNGKey(3), N), traced_params(ControllerParams.paper())


def _assert_outcomes(out, expected, exact: bool):
    """exact: bit for bit (NaN where NaN). Else the booleans exactly, and the floats of the
    pushes that stand to rtol 1e-3 (float32 over hundreds of physics steps, summed in another
    order by another program); after a fall the motion is chaotic and its floats are not
    compared."""
    assert set(out) == set(expected)
    stood = ~np.asarray(expected["fell"], bool)
    for k, v in expected.items():
        got = np.asarray(out[k], np.float64)
        want = np.asarray(np.asarray(v, np.float32), np.float64)
        if exact or k in ("fell", "diverged"):
            np.testing.assert_array_equal(got, want, err_msg=k)
        else:
            np.testing.assert_allclose(got[stood], want[stood], rtol=1e-3, atol=1e-4,
                                       err_msg=k)


@pytest.mark.slow
def test_sweep_chunk_outcomes_unchanged():
    """Float tolerance rather than bits, so that another CPU or jax release passes; on this
    project's CPU the outcomes were bit-identical when the work landed."""
    _assert_outcomes(make_chunk_fn((), 1.5, tree_passes="mjx")(*_inputs()), STORED, exact=False)


@pytest.mark.slow
def test_compact_sweep_chunk_keeps_the_outcomes():
    """The sweeps' compact tree passes (a fixed summation order) give the stored outcomes too:
    the same falls, the readings to float tolerance."""
    _assert_outcomes(make_chunk_fn((), 1.5)(*_inputs()), STORED, exact=False)


@pytest.mark.slow
def test_profile_loop_is_the_sweep_chunk():
    """The bench profile's `full` variant is the sweeps' program: the same outcomes, exactly."""
    from tkujax.bench.profile import loop_fn

    args = _inputs()
    ref = {k: np.asarray(v) for k, v in make_chunk_fn((), 1.5)(*args).items()}
    _assert_outcomes(loop_fn(1.5)(*args), ref, exact=True)


@pytest.mark.slow
def test_loop_options_keep_the_outcomes():
    """Checkpointing (a no-op without a gradient) and scan unrolling change the program, not
    the arithmetic: the outcomes agree to float tolerance."""
    from tkujax.bench.profile import loop_fn

    args = _inputs()
    ref = {k: np.asarray(v) for k, v in make_chunk_fn((), 1.5)(*args).items()}
    out = loop_fn(1.5, dict(remat="nested", unroll_substeps=2))(*args)
    _assert_outcomes(out, ref, exact=False)
    # The sweeps run the flat loop; the nested one gives the same outcomes.
    _assert_outcomes(loop_fn(1.5, dict(loop="nested"))(*args), ref, exact=False)


def test_rollout_config_checks_its_options():
    from tkujax.bench.ablation import ablated_rollout
    from tkujax.sim.options import Episode, ProgramOptions, checkpoints
    from tkujax.sim.rollout_mjx import RolloutConfig, rollout

    for bad in (0, -3):
        with pytest.raises(ValueError, match="unroll_substeps"):
            make_chunk_fn((), 1.5, unroll_substeps=bad)

    with pytest.raises(ValueError, match="remat"):
        checkpoints("sometimes")
    with pytest.raises(ValueError, match="unknown profile variant 'loop=spiral'"):
        from tkujax.bench.profile import variant_config
        variant_config("loop=spiral")
    for mode in (False, True, "none", "tick", "tick_nocse", "tick_dots", "substep", "nested"):
        checkpoints(mode)
    from tkujax.sim.push import Push
    from tkujax.sim.setup import init

    _, model, index, state = init()
    push = Push(*(jnp.float32(v) for v in (1.0, 0.0, 0.36, 0.02, 0.3)))
    with pytest.raises(ValueError, match="ProgramOptions.loop must be one of"):
        RolloutConfig(duration_s=0.06, program=ProgramOptions(loop="spiral"))
    for field in ("unroll_ticks", "unroll_substeps", "gradient_window_ticks"):
        with pytest.raises(ValueError, match=f"ProgramOptions.{field} must be an integer >= 1, "
                                             f"got 0"):
            ProgramOptions(**{field: 0})
    episode = Episode(push, 1.0, jax.random.PRNGKey(0))
    jax.eval_shape(lambda: rollout(model, state, episode, ControllerParams.paper(),
                                   RolloutConfig(duration_s=0.06), index))
    with pytest.raises(ValueError, match="ablate"):
        jax.eval_shape(lambda: ablated_rollout(model, state, episode, ControllerParams.paper(),
                                               RolloutConfig(duration_s=0.06), index, ("x",)))


@pytest.mark.slow
@pytest.mark.parametrize("fixed", [None, "latency"])
def test_flat_loop_gives_the_nested_series(fixed):
    """The flat loop (one scan over physics steps, the tick and the records in conds) is the
    nested loop's arithmetic: every Series field agrees to float rounding, for the float
    controller (sensor noise on) and for the fixed-point twin whose fractional servo latency
    switches commands in mid-tick (servo substep 6 of 15)."""
    from tkujax.control.fixed import FixedPointConfig, servo_switch_substep
    from tkujax.sim.push import Push
    from tkujax.sim.rollout_mjx import Episode, ProgramOptions, RolloutConfig, rollout
    from tkujax.sim.setup import init

    cfg = (FixedPointConfig(straight_through=False, latency_ticks=1, latency_frac=0.4)
           if fixed else None)
    _, model, index, state = init()
    if cfg is not None:
        assert servo_switch_substep(cfg, 15) == 6
    push = Push(*(jnp.float32(v) for v in (1.6, 0.0, 0.36, 0.02, 0.03)))

    def run(loop):
        config = RolloutConfig(duration_s=0.45, fixed=cfg, program=ProgramOptions(loop=loop))
        f = jax.jit(lambda key: rollout(model, state, Episode(push, 1.0, key, 0.02, 0.1),
                                        ControllerParams.paper(), config, index))
        return jax.tree.map(np.asarray, f(jax.random.PRNGKey(5)))

    nested, flat = run("nested"), run("flat")
    assert nested.t.shape == flat.t.shape == (15,)
    np.testing.assert_array_equal(flat.t, nested.t)
    for name in nested.keys():
        a, b = nested[name], flat[name]
        if a is None:
            assert b is None, name
            continue
        np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-5, err_msg=name)
    # Not a trivial match: the push moved the robot and the controller began its step.
    assert np.ptp(nested.pitch) > 1e-3 and nested.gate.max() > 0.5
