"""What every bench stage shares: the timing rule, the push batch, the traced parameters."""

from __future__ import annotations

import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.sim import physics
from tkujax.sim.push import CONTROL_PERIOD_S


def timed(fn, repeats: int) -> float:
    """Median wall time of max(repeats, 1) calls of `fn` after one warm-up call (which also
    compiles); `fn` returns device arrays, waited for."""
    jax.block_until_ready(fn())
    times = []
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def push_batch(n: int, seed: int = 0) -> dict:
    """A reproducible batch of push records (the sweep's columns)."""
    rng = np.random.default_rng(seed)
    cols = dict(impulse_ns=rng.uniform(0.2, 3.0, n), azimuth_deg=rng.uniform(0, 360, n),
                height_m=np.full(n, 0.36), duration_s=np.full(n, 0.02), onset_s=np.full(n, 0.3),
                control=(np.arange(n) % 2).astype(float), link_mass_scale=np.ones(n),
                torso_com_offset_x_m=np.zeros(n), floor_friction=np.full(n, -1.0),
                servo_kp_scale=np.ones(n), gyro_noise_std=np.zeros(n), accel_noise_std=np.zeros(n))
    return {k: jnp.asarray(v, jnp.float32) for k, v in cols.items()}


def traced_paper_params() -> ControllerParams:
    """The paper's controller parameters as the sweeps trace them (array leaves)."""
    from tkujax.sweeps.sweep import traced_params

    return traced_params(ControllerParams.paper())


def substeps() -> int:
    """Physics steps per control tick of the default model."""
    return int(round(CONTROL_PERIOD_S / physics.host_model().opt.timestep))


def n_ticks(duration_s: float) -> int:
    """Control ticks in `duration_s`."""
    return int(round(duration_s / CONTROL_PERIOD_S))


def physics_steps(duration_s: float) -> int:
    """Physics steps in `duration_s` of the default model."""
    return int(round(duration_s / physics.host_model().opt.timestep))
