"""The bench's measured stages, each a function of its sizes returning its JSON record.

  raw_stepping    raw MJX stepping of TKU-X holding fixed targets (no controller): physics
                  steps/s (its program reads no sensor, so XLA drops MuJoCo's sensor stage);
  closed_loop     the closed-loop sweep chunk (sensors, controller, metrics): steps/s, pushes/s;
  compile_times   its compile, cold (empty persistent cache) and from the persistent cache;
  multi_device    the sharded chunk on 1..n local devices;
  cpu_peer        MuJoCo C physics across all cores with the JAX controller between ticks;
  gradient_step   one tuning gradient step: time and the process's peak device memory;
  gradient_compile  the tuning gradient's compile, per variant of its program.

Speeds are reported, never asserted.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.bench.common import physics_steps, push_batch, timed, traced_paper_params
from tkujax.control.controller_params import ControllerParams
from tkujax.sim import physics
from tkujax.sim.setup import init
from tkujax.sweeps.compile_cache import fresh_compilation_cache
from tkujax.sweeps.sweep import SWEEP_COMPILER_OPTIONS, SWEEP_UNROLL_SUBSTEPS, make_chunk_fn


def raw_program(batch: int, n_steps: int):
    """(jit(vmap) of `n_steps` raw MJX steps holding the stand targets, its batched state)."""
    host, model, _, stand = init(settle_s=0.0)         # the keyframe itself, unsettled
    ctrl = jnp.asarray(host.key("stand").ctrl, jnp.float32)
    # The sweeps' XLA options, so that the two rows differ by the closed loop alone (raw MJX
    # ran 11.9 ms per 15 steps at batch 1,024 on an H100 with or without them).
    run = jax.jit(jax.vmap(lambda d: physics.step_holding(model, d, ctrl, n_steps)[0].qpos),
                  compiler_options=SWEEP_COMPILER_OPTIONS)
    return run, physics.batch_state(stand, batch)


def raw_stepping(batch: int, n_steps: int, repeats: int) -> dict:
    run, state = raw_program(batch, n_steps)
    sec = timed(lambda: run(state), repeats)
    return dict(batch=batch, steps=n_steps, seconds=sec, physics_steps_per_s=batch * n_steps / sec)


def closed_loop(batch: int, duration_s: float, repeats: int, compiled=None,
                unroll_substeps: int | None = None) -> dict:
    """`compiled`: the chunk's executable for this batch (the compile stage's), else compiled
    here on the warm-up call. unroll_substeps: the loop structure (make_chunk_fn's; None: the
    sweeps' default)."""
    unroll = SWEEP_UNROLL_SUBSTEPS if unroll_substeps is None else unroll_substeps
    params = traced_paper_params()
    fn = compiled or make_chunk_fn((), duration_s, unroll_substeps=unroll)
    recs = push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    sec = timed(lambda: fn(recs, keys, params), repeats)
    steps = physics_steps(duration_s)
    return dict(batch=batch, duration_s=duration_s, unroll_substeps=unroll, seconds=sec,
                pushes_per_s=batch / sec, physics_steps_per_s=batch * steps / sec)


def compile_times(batch: int, duration_s: float, keep: dict | None = None,
                  unroll_substeps: int | None = None) -> dict:
    """Cold compile into an empty persistent cache, then again from that cache. `keep`: a dict
    that receives {(batch, unroll_substeps): the executable} (the closed-loop stage at that
    batch and loop structure runs it instead of compiling again)."""
    unroll = SWEEP_UNROLL_SUBSTEPS if unroll_substeps is None else unroll_substeps
    params = traced_paper_params()
    recs = push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    out = dict(batch=batch, unroll_substeps=unroll)
    with fresh_compilation_cache():
        for label in ("cold_s", "cached_s"):
            jax.clear_caches()
            fn = make_chunk_fn((), duration_s, unroll_substeps=unroll)
            t0 = time.perf_counter()
            exe = fn.lower(recs, keys, params).compile()
            out[label] = time.perf_counter() - t0
    if keep is not None:
        keep[(batch, unroll)] = exe
    return out


def multi_device(batch: int, duration_s: float, repeats: int) -> list[dict]:
    """The sharded closed-loop chunk at a fixed global batch on 1..n local devices."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    params = traced_paper_params()
    fn = make_chunk_fn((), duration_s)
    steps = physics_steps(duration_s)
    out = []
    devices = jax.local_devices()
    for n in sorted({1, len(devices)}):
        sharding = NamedSharding(Mesh(np.array(devices[:n]), ("push",)), PartitionSpec("push"))
        recs = {k: jax.device_put(v, sharding) for k, v in push_batch(batch).items()}
        keys = jax.device_put(jax.random.split(jax.random.PRNGKey(0), batch), sharding)
        sec = timed(lambda recs=recs, keys=keys: fn(recs, keys, params), repeats)
        out.append(dict(n_devices=n, batch=batch, seconds=sec, pushes_per_s=batch / sec,
                        physics_steps_per_s=batch * steps / sec))
    return out


def cpu_peer(batch: int, duration_s: float, repeats: int) -> dict | None:
    try:
        from tkujax.sim.rollout_mujoco import simulate_mujoco
    except ImportError:
        return None
    from tkujax.sim.push import Push
    from tkujax.sim.options import RolloutConfig

    r = {k: np.asarray(v) for k, v in push_batch(batch).items()}
    pushes = Push(r["impulse_ns"], np.radians(r["azimuth_deg"]), r["height_m"], r["duration_s"],
                  r["onset_s"])
    pushes = jax.tree_util.tree_map(jnp.asarray, pushes)
    config = RolloutConfig(duration_s=duration_s)
    params = ControllerParams.paper()
    sec = timed(lambda: simulate_mujoco(pushes, r["control"], params, config=config), repeats)
    steps = physics_steps(duration_s)
    return dict(batch=batch, duration_s=duration_s, seconds=sec, pushes_per_s=batch / sec,
                physics_steps_per_s=batch * steps / sec)


def gradient_step(batch: int, duration_s: float, repeats: int,
                  rollout_options: dict | None = None) -> dict | None:
    try:
        from tkujax.studies.tune import benchmark_gradient_step
    except ImportError:
        return None
    return benchmark_gradient_step(batch, duration_s, repeats, rollout_options=rollout_options)


# XLA options that trade the compiled code's quality for compile time, per gradient variant
# item (GPU only; `gradient_compile` records the step time beside the compile so that the trade
# is measured, not assumed): llvm=0 runs LLVM without its optimisation passes on the kernels,
# ptxas=0 compiles the PTX without ptxas's optimisations.
COMPILE_SPEED_OPTIONS = {
    "llvm": {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True},
    "ptxas": {"xla_gpu_disable_gpuasm_optimizations": True},
}


def parse_grad_variants(text: str) -> list[dict]:
    """"remat=tick;remat=nested,unroll_substeps=3;autotune=0;llvm=0,ptxas=0" -> one dict per
    variant (keys: remat, unroll_ticks, unroll_substeps, tree_passes, autotune, llvm, ptxas; see
    gradient_compile). llvm and ptxas take 0 (their optimisations off) only."""
    from tkujax.sim.options import REMAT_MODES, TREE_PASSES

    out = []
    keys = ("remat", "unroll_ticks", "unroll_substeps", "tree_passes", "autotune",
            *COMPILE_SPEED_OPTIONS)
    # Keys that name one of a ProgramOptions field's string modes (remat's booleans left out).
    choices = {"remat": REMAT_MODES[2:], "tree_passes": TREE_PASSES}
    for part in filter(None, (p.strip() for p in text.split(";"))):
        v = {}
        for item in filter(None, (i.strip() for i in part.split(","))):
            key, eq, val = item.partition("=")
            if not eq or key not in keys:
                raise ValueError(f"gradient variant item {item!r}: expected remat=MODE, "
                                 f"unroll_ticks=K, unroll_substeps=K, tree_passes=mjx|compact, "
                                 f"autotune=LEVEL, llvm=0 "
                                 f"or ptxas=0")
            if key in choices:
                if val not in choices[key]:
                    raise ValueError(f"{key}={val!r}: one of {choices[key]}")
                v[key] = val
            elif key in COMPILE_SPEED_OPTIONS:
                if val != "0":
                    raise ValueError(f"{key}={val!r}: only {key}=0 (its optimisations off)")
                v[key] = 0
            else:
                if not val.isdigit():
                    raise ValueError(f"{key}={val!r}: a non-negative integer")
                v[key] = int(val)
        out.append(v)
    return out


def gradient_compile(batch: int, duration_s: float, variants: list[dict] | None = None,
                     cached: bool = True) -> list[dict]:
    """Cold (and, with `cached`, from the persistent cache) compile of the tuning gradient, per
    variant: {"remat": ProgramOptions.remat mode (default: the tuner's, TUNE_REMAT),
    "unroll_ticks", "unroll_substeps": scan unrolling, "autotune": xla_gpu_autotune_level,
    "llvm": 0, "ptxas": 0: COMPILE_SPEED_OPTIONS} (the last three GPU only: skipped on another
    backend). A variant with XLA options also times the compiled gradient step (step_s), since
    they trade the code's speed for compile time. Default: the tuner's program with XLA's
    defaults and, on a GPU, with autotuning off (MJX's matrices are tiny: autotuning their
    kernels buys little run time and costs compile time)."""
    from tkujax.studies.tune.benchmark import gradient_compile_times

    gpu = jax.default_backend() == "gpu"
    if variants is None:
        variants = [{}] + ([{"autotune": 0}] if gpu else [])
    out = []
    for v in variants:
        v = dict(v)
        xla = {k: v.pop(k) for k in ("autotune", *COMPILE_SPEED_OPTIONS) if k in v}
        if xla and not gpu:
            out.append(dict(variant=dict(v, **xla), skipped=f"{', '.join(xla)}: GPU only"))
            continue
        opts = {}
        if "autotune" in xla:
            opts["xla_gpu_autotune_level"] = xla["autotune"]
        for k in COMPILE_SPEED_OPTIONS:
            if k in xla:
                opts.update(COMPILE_SPEED_OPTIONS[k])
        row = gradient_compile_times(batch, duration_s, compiler_options=opts or None,
                                     rollout_options=v, cached=cached,
                                     step_repeats=3 if opts else 0)
        out.append(dict(row, variant=dict(v, **xla)))
    return out
