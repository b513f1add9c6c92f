"""Benchmark hook for `tkujax bench`: the time of one gradient step of the tuning loss."""

from __future__ import annotations

import time

import jax
import numpy as np

from tkujax.sweeps.compile_cache import persistent_cache_hits
from tkujax.studies.tune.problem import TuneProblem
from tkujax.studies.tune.reparam import DEG, PAPER_TUNABLE
from tkujax.studies.tune.tune_spec import parse_tune_spec, sample_pushes


def bench_spec(batch: int, duration_s: float, remat, float64: bool = False,
               jitter: bool = False):
    """The TuneSpec both benchmarks use: PAPER_TUNABLE, sagittal pushes of 0.3-2.0 N s at
    0.3 s (azimuth jitter 10 deg for the gradient step, as the figures so far)."""
    push = {"impulse_ns": {"uniform": [0.3, 2.0]}, "azimuth_deg": [0.0, 180.0], "onset_s": 0.3}
    if jitter:
        push["azimuth_jitter_deg"] = 10.0
    return parse_tune_spec({"tune": {"batch": batch, "duration_s": duration_s, "iterations": 1,
                                     "params": list(PAPER_TUNABLE), "remat": bool(remat),
                                     "float64": float64},
                            "push": push})


def benchmark_gradient_step(batch: int, duration_s: float, repeats: int = 3,
                            remat: bool | str = True, float64: bool = False,
                            rollout_options: dict | None = None) -> dict:
    """Time of one jitted value_and_grad of the tuning loss (the paper's 8 tunable parameters,
    PAPER_TUNABLE: the recovery extensions' "off" start values lie on their range bounds, which
    a tune spec refuses; sagittal pushes of 0.3-2.0 N s) at `batch` pushes x `duration_s`,
    median of `repeats` after a compile; peak device memory from memory_stats() where the
    backend reports it, else None.
    rollout_options: further RolloutConfig fields (remat overrides `remat`; unroll_*)."""
    opts = dict(rollout_options or {})
    remat = opts.pop("remat", remat)
    spec = bench_spec(batch, duration_s, remat, float64, jitter=True)
    reparam, base = spec.reparam(), spec.base_params()
    problem = TuneProblem(reparam, base, spec.loss, duration_s, remat, float64,
                          rollout_options=opts)
    recs = sample_pushes(spec, batch, 0)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    z = reparam.latent_of(base)
    tau = 1.0 * DEG
    with persistent_cache_hits() as hits:
        t0 = time.perf_counter()
        _, _, g = problem.value_and_grad(z, tau, recs, keys)
        compile_s = time.perf_counter() - t0
    sec = _median_call_s(lambda: problem.value_and_grad(z, tau, recs, keys), repeats)
    try:
        stats = jax.devices()[0].memory_stats()
    except Exception:  # noqa: BLE001 - backends without memory stats
        stats = None
    peak = int(stats["peak_bytes_in_use"]) if stats and "peak_bytes_in_use" in stats else None
    return dict(batch=batch, duration_s=duration_s, seconds=sec, first_call_s=round(compile_s, 2),
                first_call_cache_hits=hits["hits"],
                pushes_per_s=batch / sec, physics_steps_per_s=batch * problem.steps_per_push / sec,
                peak_device_bytes=peak, remat=remat, float64=float64, rollout_options=opts,
                grad_finite=bool(np.all(np.isfinite(g))), n_params=reparam.size)


def gradient_compile_times(batch: int, duration_s: float, remat: bool | str = True,
                           compiler_options: dict | None = None,
                           rollout_options: dict | None = None, cached: bool = True,
                           step_repeats: int = 0) -> dict:
    """Compile time of the tuning gradient (value_and_grad of the loss at `batch` pushes x
    `duration_s`): cold, into an empty persistent cache, then (`cached`) from that cache in a
    cleared process state (what a second `tkujax tune` run pays). rollout_options: further
    RolloutConfig fields (remat overrides `remat`; unroll_ticks, unroll_substeps). Also the
    time to trace and lower (lower_s, part of the cold figure) and the size of the lowered
    program (hlo_chars), which compile time grows with. step_repeats > 0: also the median time
    of that many calls of the compiled gradient after a warm-up (step_s), for compiler options
    that trade run time for compile time."""
    from tkujax.sweeps.compile_cache import fresh_compilation_cache

    opts = dict(rollout_options or {})
    remat = opts.pop("remat", remat)
    spec = bench_spec(batch, duration_s, remat)
    reparam, base = spec.reparam(), spec.base_params()
    recs = sample_pushes(spec, batch, 0)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    z = reparam.latent_of(base)
    out = dict(batch=batch, duration_s=duration_s, remat=remat, rollout_options=opts,
               compiler_options=compiler_options or {})
    with fresh_compilation_cache():
        for label in ("cold_s", "cached_s") if cached else ("cold_s",):
            jax.clear_caches()
            problem = TuneProblem(reparam, base, spec.loss, duration_s, remat, False,
                                  compiler_options=compiler_options, rollout_options=opts)
            t0 = time.perf_counter()
            lowered, args = problem.lower_value_and_grad(z, DEG, recs, keys)
            lower_s = time.perf_counter() - t0
            if label == "cold_s":
                out["lower_s"] = round(lower_s, 2)
                out["hlo_chars"] = len(lowered.as_text())     # not timed
            t0 = time.perf_counter()
            exe = lowered.compile()
            out[label] = round(lower_s + time.perf_counter() - t0, 2)
    if step_repeats > 0:
        jax.block_until_ready(exe(*args))                                  # warm-up
        out["step_s"] = round(_median_call_s(
            lambda: jax.block_until_ready(exe(*args)), step_repeats), 3)
    return out


def _median_call_s(call, repeats: int) -> float:
    """Median wall time of max(repeats, 1) calls of `call` (which must block until done)."""
    times = []
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        call()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
