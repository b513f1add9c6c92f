"""`tkujax bench`: throughput of the same TKU-X push sweep, measured side by side.

  a. raw MJX stepping of TKU-X holding fixed targets (no controller): physics steps/s;
  b. the closed-loop sweep (sensors, controller, metrics): physics steps/s and pushes/s;
  c. the CPU peer: MuJoCo C physics across all cores with the JAX controller between ticks
     (when tkujax.sim.rollout_mujoco is available);
  d. one tuning gradient step (when tkujax.studies.tune is available): time and peak device memory;
  e. compile time of (b), cold (empty persistent cache) and from the persistent cache.
Each figure is the median of `repeats` timed runs after a warm-up; the ratios b/a and b/c are
printed. Speeds are reported, never asserted.
"""

from __future__ import annotations

import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.sim import physics
from tkujax.sim.setup import init
from tkujax.control.params import ControllerParams
from tkujax.studies.provenance import package_versions
from tkujax.studies.sweep import make_chunk_fn, traced_params


def _timed(fn, repeats: int) -> float:
    jax.block_until_ready(fn())            # warm-up (and compile)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _push_batch(n: int, seed: int = 0) -> dict:
    """A reproducible batch of push records (the sweep's columns)."""
    rng = np.random.default_rng(seed)
    cols = dict(impulse_ns=rng.uniform(0.2, 3.0, n), azimuth_deg=rng.uniform(0, 360, n),
                height_m=np.full(n, 0.36), duration_s=np.full(n, 0.02), onset_s=np.full(n, 0.3),
                control=(np.arange(n) % 2).astype(float), link_mass_scale=np.ones(n),
                torso_com_offset_x_m=np.zeros(n), floor_friction=np.full(n, -1.0),
                servo_kp_scale=np.ones(n), gyro_noise_std=np.zeros(n), accel_noise_std=np.zeros(n))
    return {k: jnp.asarray(v, jnp.float32) for k, v in cols.items()}


def raw_stepping(batch: int, n_steps: int, repeats: int) -> dict:
    host, model, _, stand = init(settle_s=0.0)         # the keyframe itself, unsettled
    state = physics.batch_state(stand, batch)
    ctrl = jnp.asarray(host.key("stand").ctrl, jnp.float32)
    run = jax.jit(jax.vmap(lambda d: physics.step_holding(model, d, ctrl, n_steps)[0].qpos))
    sec = _timed(lambda: run(state), repeats)
    return dict(batch=batch, steps=n_steps, seconds=sec, physics_steps_per_s=batch * n_steps / sec)


def closed_loop(batch: int, duration_s: float, repeats: int) -> dict:
    params = traced_params(ControllerParams.paper())
    fn = make_chunk_fn((), duration_s)
    recs = _push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    sec = _timed(lambda: fn(recs, keys, params), repeats)
    steps = int(round(duration_s / physics.host_model().opt.timestep))
    return dict(batch=batch, duration_s=duration_s, seconds=sec, pushes_per_s=batch / sec,
                physics_steps_per_s=batch * steps / sec)


def compile_times(batch: int, duration_s: float) -> dict:
    """Cold compile into an empty persistent cache, then again from that cache."""
    params = traced_params(ControllerParams.paper())
    recs = _push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    old_dir = jax.config.jax_compilation_cache_dir
    with tempfile.TemporaryDirectory() as cache:
        jax.config.update("jax_compilation_cache_dir", cache)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
        out = {}
        for label in ("cold_s", "cached_s"):
            jax.clear_caches()
            fn = make_chunk_fn((), duration_s)
            t0 = time.perf_counter()
            fn.lower(recs, keys, params).compile()
            out[label] = time.perf_counter() - t0
    jax.config.update("jax_compilation_cache_dir", old_dir)
    return out


def multi_device(batch: int, duration_s: float, repeats: int) -> list[dict]:
    """The sharded closed-loop chunk at a fixed global batch on 1..n local devices."""
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    params = traced_params(ControllerParams.paper())
    fn = make_chunk_fn((), duration_s)
    steps = int(round(duration_s / physics.host_model().opt.timestep))
    out = []
    devices = jax.local_devices()
    for n in sorted({1, len(devices)}):
        sharding = NamedSharding(Mesh(np.array(devices[:n]), ("push",)), PartitionSpec("push"))
        recs = {k: jax.device_put(v, sharding) for k, v in _push_batch(batch).items()}
        keys = jax.device_put(jax.random.split(jax.random.PRNGKey(0), batch), sharding)
        sec = _timed(lambda recs=recs, keys=keys: fn(recs, keys, params), repeats)
        out.append(dict(n_devices=n, batch=batch, seconds=sec, pushes_per_s=batch / sec,
                        physics_steps_per_s=batch * steps / sec))
    return out


def cpu_peer(batch: int, duration_s: float, repeats: int) -> dict | None:
    try:
        from tkujax.sim.rollout_mujoco import simulate_mujoco
    except ImportError:
        return None
    from tkujax.sim.push import Push
    from tkujax.sim.rollout_mjx import RolloutConfig

    r = {k: np.asarray(v) for k, v in _push_batch(batch).items()}
    pushes = Push(r["impulse_ns"], np.radians(r["azimuth_deg"]), r["height_m"], r["duration_s"],
                  r["onset_s"])
    pushes = jax.tree_util.tree_map(jnp.asarray, pushes)
    config = RolloutConfig(duration_s=duration_s)
    params = ControllerParams.paper()
    sec = _timed(lambda: simulate_mujoco(pushes, r["control"], params, config=config), repeats)
    steps = int(round(duration_s / physics.host_model().opt.timestep))
    return dict(batch=batch, duration_s=duration_s, seconds=sec, pushes_per_s=batch / sec,
                physics_steps_per_s=batch * steps / sec)


def gradient_step(batch: int, duration_s: float, repeats: int) -> dict | None:
    try:
        from tkujax.studies.tune import benchmark_gradient_step
    except ImportError:
        return None
    return benchmark_gradient_step(batch, duration_s, repeats)


def gradient_compile(batch: int, duration_s: float) -> list[dict]:
    """Cold and cached compile of the tuning gradient, with XLA's defaults and, on a GPU, with
    autotuning off (MJX's matrices are tiny: autotuning their kernels buys little run time and
    costs compile time)."""
    from tkujax.studies.tune.benchmark import gradient_compile_times

    variants = [None]
    if jax.default_backend() == "gpu":
        variants.append({"xla_gpu_autotune_level": 0})
    return [gradient_compile_times(batch, duration_s, compiler_options=v) for v in variants]


def run_bench(out: str | Path, batches=(1024, 4096, 16384, 65536), duration_s: float = 1.5,
              raw_steps: int = 300, repeats: int = 3, cpu_batch: int | None = 256,
              grad_batch: int | None = 1024, compile_batch: int = 1024,
              scaling_batch: int | None = None, grad_compile_batch: int = 0) -> dict:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    dev = jax.devices()[0]
    result = dict(device=str(dev), device_kind=getattr(dev, "device_kind", dev.platform),
                  n_devices=jax.device_count(), platform=platform.platform(),
                  versions=package_versions(("jax", "jaxlib", "mujoco", "mujoco-mjx")),
                  repeats=repeats, duration_s=duration_s, raw=[], closed_loop=[])
    if compile_batch:
        result["compile"] = compile_times(compile_batch, duration_s)
    for b in batches:
        result["raw"].append(raw_stepping(b, raw_steps, repeats))
        result["closed_loop"].append(closed_loop(b, duration_s, repeats))
        _write(out, result)
    if scaling_batch and jax.local_device_count() > 1:
        result["multi_device"] = multi_device(scaling_batch, duration_s, repeats)
        _write(out, result)
    if cpu_batch:
        result["cpu_peer"] = cpu_peer(cpu_batch, duration_s, repeats)
        _write(out, result)   # each stage is written as it finishes: a killed run keeps them
    if grad_batch:
        result["gradient_step"] = gradient_step(grad_batch, duration_s, repeats)
        _write(out, result)
    if grad_compile_batch:
        result["gradient_compile"] = gradient_compile(grad_compile_batch, duration_s)
    _write(out, result)
    return result


def _write(out: Path, result: dict) -> None:
    out.write_text(json.dumps(result, indent=1))
    out.with_suffix(".md").write_text(summary_markdown(result))


def summary_markdown(r: dict) -> str:
    lines = [f"# tkujax bench on {r['device_kind']} ({r['n_devices']} device(s))", "",
             f"Versions: {r['versions']}. Median of {r['repeats']} runs; closed loop = "
             f"{r['duration_s']} s pushes with controller, sensors and metrics.", "",
             "| batch | raw MJX steps/s (a) | closed-loop steps/s (b) | pushes/s | b/a |",
             "|---|---|---|---|---|"]
    for a, b in zip(r["raw"], r["closed_loop"]):
        lines.append(f"| {a['batch']} | {a['physics_steps_per_s']:.3g} | "
                     f"{b['physics_steps_per_s']:.3g} | {b['pushes_per_s']:.3g} | "
                     f"{b['physics_steps_per_s'] / a['physics_steps_per_s']:.2f} |")
    c = r.get("cpu_peer")
    if c:
        best = max(r["closed_loop"], key=lambda x: x["physics_steps_per_s"])
        lines += ["", f"CPU peer (MuJoCo C, batch {c['batch']}): {c['physics_steps_per_s']:.3g} "
                  f"steps/s, {c['pushes_per_s']:.3g} pushes/s; b/c = "
                  f"{best['physics_steps_per_s'] / c['physics_steps_per_s']:.1f}x"]
    g = r.get("gradient_step")
    if g:
        lines += ["", f"Gradient step (reverse mode through the closed loop, batch {g['batch']} x "
                  f"{g['duration_s']} s, {g['n_params']} parameters, remat {g['remat']}, float64 "
                  f"{g['float64']}): {g['seconds']:.2f} s per step = {g['pushes_per_s']:.3g} "
                  f"pushes/s, first call (compile) {g['first_call_s']:.0f} s, peak device memory "
                  f"{g['peak_device_bytes'] / 2**30:.2f} GiB, gradient finite: {g['grad_finite']}."]
    md = r.get("multi_device")
    if md:
        base = md[0]["pushes_per_s"]
        lines += ["", "| devices | batch | pushes/s | speed-up |", "|---|---|---|---|"]
        lines += [f"| {m['n_devices']} | {m['batch']} | {m['pushes_per_s']:.3g} | "
                  f"{m['pushes_per_s'] / base:.2f}x |" for m in md]
    for gc in r.get("gradient_compile", []):
        lines += ["", f"Compile of the tuning gradient (batch {gc['batch']}, options "
                  f"{gc['compiler_options'] or 'XLA defaults'}): cold {gc['cold_s']:.1f} s, from "
                  f"the persistent cache {gc['cached_s']:.1f} s."]
    comp = r.get("compile")
    if comp:
        lines += ["", f"Compile of the closed loop: cold {comp['cold_s']:.1f} s, "
                  f"from the persistent cache {comp['cached_s']:.1f} s."]
    return "\n".join(lines) + "\n"
