"""`tkujax bench`: throughput of the same TKU-X push sweep, measured side by side.

  a. raw MJX stepping of TKU-X holding fixed targets (no controller): physics steps/s (its
     program reads no sensor, so XLA drops MuJoCo's sensor stage: the closed loop computes
     its IMU alone each step, `tkujax.sim.physics.imu_reading`);
  b. the closed-loop sweep (sensors, controller, metrics): physics steps/s and pushes/s;
  c. the CPU peer: MuJoCo C physics across all cores with the JAX controller between ticks
     (when tkujax.sim.rollout_mujoco is available);
  d. one tuning gradient step (when tkujax.studies.tune is available): time and the process's
     peak device memory (earlier stages of the run included);
  e. compile time of (b), cold (empty persistent cache) and from the persistent cache;
  f. compile time of the tuning gradient, per variant of its program (remat, unrolling);
  g. the profile of (b): what each part costs per control tick (`tkujax.bench_profile`).
Each figure is the median of `repeats` timed runs after a warm-up; the ratios b/a and b/c are
printed. Speeds are reported, never asserted.

Two sizes (MODES): "default" (a, b at 1,024 and 65,536, c, e: a few minutes on one GPU) and
"full" (a, b at four batches, c, d, e, f and the multi-device scaling). Every stage is timed;
progress goes to stderr, and the JSON and its .md are rewritten after each stage with
`stages` (name, status, wall_s), `total_wall_s` and `complete`, so a run cut short keeps what
finished, and `run_bench(resume=True)` (`--resume`) goes on with it.
"""

from __future__ import annotations

import json
import platform
import statistics
import sys
import time
import traceback
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.sim import physics
from tkujax.sim.setup import init
from tkujax.control.params import ControllerParams
from tkujax.studies.compile_cache import fresh_compilation_cache
from tkujax.studies.provenance import package_versions
from tkujax.studies.sweep import (SWEEP_COMPILER_OPTIONS, SWEEP_UNROLL_SUBSTEPS,
                                  make_chunk_fn, traced_params)


def _timed(fn, repeats: int) -> float:
    """Median wall time of max(repeats, 1) calls of `fn` after one warm-up call (which also
    compiles); `fn` returns device arrays, waited for."""
    jax.block_until_ready(fn())
    times = []
    for _ in range(max(repeats, 1)):
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
    sec = _timed(lambda: run(state), repeats)
    return dict(batch=batch, steps=n_steps, seconds=sec, physics_steps_per_s=batch * n_steps / sec)


def closed_loop(batch: int, duration_s: float, repeats: int, compiled=None,
                unroll_substeps: int | None = None) -> dict:
    """`compiled`: the chunk's executable for this batch (the compile stage's), else compiled
    here on the warm-up call. unroll_substeps: the loop structure (make_chunk_fn's; None: the
    sweeps' default)."""
    unroll = SWEEP_UNROLL_SUBSTEPS if unroll_substeps is None else unroll_substeps
    params = traced_params(ControllerParams.paper())
    fn = compiled or make_chunk_fn((), duration_s, unroll_substeps=unroll)
    recs = _push_batch(batch)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    sec = _timed(lambda: fn(recs, keys, params), repeats)
    steps = int(round(duration_s / physics.host_model().opt.timestep))
    return dict(batch=batch, duration_s=duration_s, unroll_substeps=unroll, seconds=sec,
                pushes_per_s=batch / sec, physics_steps_per_s=batch * steps / sec)


def compile_times(batch: int, duration_s: float, keep: dict | None = None,
                  unroll_substeps: int | None = None) -> dict:
    """Cold compile into an empty persistent cache, then again from that cache. `keep`: a dict
    that receives {(batch, unroll_substeps): the executable} (the closed-loop stage at that
    batch and loop structure runs it instead of compiling again)."""
    unroll = SWEEP_UNROLL_SUBSTEPS if unroll_substeps is None else unroll_substeps
    params = traced_params(ControllerParams.paper())
    recs = _push_batch(batch)
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
    from tkujax.sim.rollout_mjx import REMAT_MODES, TREE_PASSES

    out = []
    keys = ("remat", "unroll_ticks", "unroll_substeps", "tree_passes", "autotune",
            *COMPILE_SPEED_OPTIONS)
    # Keys that name one of a RolloutConfig field's string modes (remat's booleans left out).
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
    variant: {"remat": RolloutConfig.remat mode (default: the tuner's, TUNE_REMAT),
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


def traced_paper_params() -> ControllerParams:
    return traced_params(ControllerParams.paper())


# Sizes of the two modes. "default" finishes in a few minutes on one GPU (the closed-loop /
# raw-MJX ratio at 1,024 and 65,536, the closed loop's compile, the CPU peer); "full" adds
# the middle batches, the gradient step and its compile, and the multi-device scaling.
MODES = {
    "default": dict(batches=(1024, 65536), repeats=2, cpu_batch=256, grad_batch=None,
                    compile_batch=1024, scaling_batch=None, grad_compile_batch=0),
    "full": dict(batches=(1024, 4096, 16384, 65536), repeats=3, cpu_batch=256, grad_batch=1024,
                 compile_batch=1024, scaling_batch=65536, grad_compile_batch=256),
}
STAGE_GROUPS = ("compile", "throughput", "multi_device", "cpu_peer", "profile", "gradient_step",
                "gradient_compile")


class _Stages:
    """Runs the bench's stages one by one: progress on stderr, each stage's wall time and
    status in result["stages"], the JSON (and .md) rewritten after each stage, so that a run
    cut short keeps what finished. A failing stage is recorded and the next one runs; with
    `budget_s`, a stage that would start after the budget is recorded as skipped. A resumed
    `result` (`_resumed`) already records its finished stages: they are kept and not run
    again, and its `total_wall_s` (the earlier runs' wall time) is added to this run's."""

    def __init__(self, out: Path, result: dict, budget_s: float | None, quiet: bool):
        self.out, self.result, self.budget_s, self.quiet = out, result, budget_s, quiet
        self.done = frozenset(s["name"] for s in result.setdefault("stages", []))
        self.wall_before_s = result.get("total_wall_s", 0.0)
        self.t0 = time.perf_counter()

    def log(self, msg: str) -> None:
        if not self.quiet:
            print(f"[bench {time.perf_counter() - self.t0:7.1f} s] {msg}", file=sys.stderr,
                  flush=True)

    def run(self, name: str, fn) -> None:
        if name in self.done:
            self.log(f"{name}: done in an earlier run, kept")
            return
        rec = dict(name=name)
        elapsed = time.perf_counter() - self.t0
        if self.budget_s is not None and elapsed > self.budget_s:
            rec.update(status="skipped", why=f"budget {self.budget_s:g} s spent")
            self.log(f"{name}: skipped (budget {self.budget_s:g} s spent)")
        else:
            self.log(f"{name}: start")
            t = time.perf_counter()
            try:
                fn()
                rec["status"] = "done"
            except Exception as err:  # noqa: BLE001 - recorded; the next stage runs
                rec.update(status="failed", error=f"{type(err).__name__}: {err}"[:2000])
                self.log(f"{name}: FAILED {type(err).__name__}: {err}")
                traceback.print_exc(file=sys.stderr)
            rec["wall_s"] = round(time.perf_counter() - t, 2)
            self.log(f"{name}: {rec['status']} in {rec['wall_s']:.1f} s")
        if self.result.get("runs", 1) > 1:
            rec["run"] = self.result["runs"]
        self.result["stages"].append(rec)
        self.write()

    def write(self, complete: bool = False) -> None:
        self.result["total_wall_s"] = round(
            self.wall_before_s + time.perf_counter() - self.t0, 2)
        self.result["complete"] = complete
        _write(self.out, self.result)


def _resumed(out: Path, settings: dict, device_kind: str, versions: dict) -> dict | None:
    """The earlier run in `out` to go on with (None when there is none), its unfinished
    stages' records dropped: they run again. Refused, naming the key, when the earlier run
    was made with other settings, on another kind of device or with other versions: its
    figures would not compare with this run's."""
    if not out.exists():
        return None
    prior = json.loads(out.read_text())
    if "settings" not in prior:
        raise ValueError(f"{out}: cannot resume: the file has no 'settings' record (written "
                         f"by an older tkujax); rerun without --resume")
    now = dict(settings, device_kind=device_kind, versions=versions)
    then = dict(prior["settings"], device_kind=prior.get("device_kind"),
                versions=prior.get("versions"))
    for key in sorted(set(now) | set(then)):
        if now.get(key) != then.get(key):
            raise ValueError(f"{out}: cannot resume: {key} was {then.get(key)!r}, now "
                             f"{now.get(key)!r}; rerun with the same options, or without "
                             f"--resume")
    prior["stages"] = [s for s in prior.get("stages", []) if s.get("status") == "done"]
    prior["runs"] = prior.get("runs", 1) + 1
    return prior


MAX_BATCH = 10_000_000


def _check_sizes(**sizes) -> None:
    """The bench's sizes at the edge, before any stage runs: a ValueError names the argument,
    its allowed range and the value (a batch of -5 or a duration of -1 s would otherwise fail
    inside a stage, or run nothing)."""
    def whole(name, v, lo, hi=MAX_BATCH):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
            raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {v!r}")

    def seconds(name, v, hi):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= hi:
            raise ValueError(f"{name} must be in (0, {hi}] seconds, got {v!r}")

    for name in ("batches", "profile_batches"):
        for b in sizes[name]:
            whole(f"{name} (each)", b, 1)
    for name in ("raw_steps", "repeats", "profile_repeats"):
        whole(name, sizes[name], 1, 100_000)
    for name in ("compile_batch", "grad_compile_batch"):
        whole(name, sizes[name], 0)
    for name in ("cpu_batch", "grad_batch", "scaling_batch"):     # None or 0: skipped
        if sizes[name] is not None:
            whole(name, sizes[name], 0)
    if sizes["compile_workers"] is not None:
        whole("compile_workers", sizes["compile_workers"], 1, 256)
    seconds("duration_s", sizes["duration_s"], 60)
    seconds("profile_duration_s", sizes["profile_duration_s"], 60)
    b = sizes["budget_s"]           # 0: every stage skipped (the run's record alone)
    if b is not None and (isinstance(b, bool) or not isinstance(b, (int, float))
                          or not 0 <= b <= 1e6):
        raise ValueError(f"budget_s must be in [0, 1e6] seconds, got {b!r}")


def run_bench(out: str | Path, batches=MODES["default"]["batches"], duration_s: float = 1.5,
              raw_steps: int = 300, repeats: int = MODES["default"]["repeats"],
              cpu_batch: int | None = 256, grad_batch: int | None = None,
              compile_batch: int = 1024, scaling_batch: int | None = None,
              grad_compile_batch: int = 0, *, mode: str = "default",
              stages: tuple[str, ...] | None = None, profile_batches=(),
              profile_duration_s: float = 0.3, profile_repeats: int = 1,
              profile_variants=None, compile_workers: int | None = None,
              trace_dir: str | Path | None = None, grad_variants: list[dict] | None = None,
              grad_cached: bool = True, budget_s: float | None = None,
              unroll_substeps: tuple[int, ...] | None = None, quiet: bool = False,
              resume: bool = False) -> dict:
    """The bench (module docstring). The size arguments default to the "default" mode (MODES);
    `stages`: the STAGE_GROUPS to run (None: those the sizes enable, plus "profile" when
    `profile_batches` is given). `unroll_substeps`: the closed loop's loop structures to
    compile and time (None: the sweeps' SWEEP_UNROLL_SUBSTEPS alone). Returns the result, also
    written to `out` (JSON) and its .md."""
    from tkujax import bench_profile

    _check_sizes(batches=batches, duration_s=duration_s, raw_steps=raw_steps, repeats=repeats,
                 cpu_batch=cpu_batch, grad_batch=grad_batch, compile_batch=compile_batch,
                 scaling_batch=scaling_batch, grad_compile_batch=grad_compile_batch,
                 profile_batches=profile_batches, profile_duration_s=profile_duration_s,
                 profile_repeats=profile_repeats, compile_workers=compile_workers,
                 budget_s=budget_s)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if stages is None:
        stages = tuple(g for g, on in (
            ("compile", compile_batch), ("throughput", batches),
            ("multi_device", scaling_batch and jax.local_device_count() > 1),
            ("cpu_peer", cpu_batch), ("profile", profile_batches),
            ("gradient_step", grad_batch), ("gradient_compile", grad_compile_batch)) if on)
    unknown = set(stages) - set(STAGE_GROUPS)
    if unknown:
        raise ValueError(f"unknown bench stage(s) {sorted(unknown)}; known: {STAGE_GROUPS}")
    if "profile" in stages:
        for v in profile_variants or ():
            if v != "no_push":
                bench_profile._variant_config(v)        # fail before any stage runs
    unrolls = tuple(unroll_substeps or (SWEEP_UNROLL_SUBSTEPS,))
    if any(int(u) < 1 for u in unrolls):
        raise ValueError(f"unroll_substeps must be >= 1, got {list(unrolls)}")
    dev = jax.devices()[0]
    device_kind = getattr(dev, "device_kind", dev.platform)
    versions = package_versions(("jax", "jaxlib", "mujoco", "mujoco-mjx"))
    # What the figures depend on: a resumed run must have been made with the same.
    settings = dict(
        mode=mode, stages=list(stages), batches=[int(b) for b in batches],
        duration_s=duration_s, raw_steps=raw_steps, repeats=repeats, cpu_batch=cpu_batch,
        grad_batch=grad_batch, compile_batch=compile_batch, scaling_batch=scaling_batch,
        grad_compile_batch=grad_compile_batch, grad_variants=grad_variants,
        grad_cached=grad_cached, unroll_substeps=[int(u) for u in unrolls],
        profile_batches=[int(b) for b in profile_batches],
        profile_duration_s=profile_duration_s, profile_repeats=profile_repeats,
        profile_variants=list(profile_variants) if profile_variants else None,
        n_devices=jax.device_count())
    result = _resumed(out, settings, device_kind, versions) if resume else None
    if result is None:
        result = dict(mode=mode, stages_requested=list(stages), device=str(dev),
                      device_kind=device_kind, n_devices=jax.device_count(),
                      platform=platform.platform(), versions=versions, repeats=repeats,
                      duration_s=duration_s, raw=[], closed_loop=[], settings=settings)
    run = _Stages(out, result, budget_s, quiet)
    if result.get("runs", 1) > 1:
        run.log(f"resuming {out}: {len(run.done)} stage(s) kept from earlier run(s)")
    compiled = {}

    result["unroll_substeps"] = list(unrolls)
    if "compile" in stages and compile_batch:
        for u in unrolls:
            def stage_compile(u=u):
                c = compile_times(compile_batch, duration_s, keep=compiled, unroll_substeps=u)
                result.setdefault("compile_variants", []).append(c)
                result.setdefault("compile", c)         # the first structure's, as before
            run.run("compile" if len(unrolls) == 1 else f"compile_unroll{u}", stage_compile)
    if "throughput" in stages:
        for b in batches:
            run.run(f"raw_{b}", lambda b=b: result["raw"].append(
                raw_stepping(b, raw_steps, repeats)))
            for u in unrolls:
                run.run(f"closed_loop_{b}" + ("" if len(unrolls) == 1 else f"_unroll{u}"),
                        lambda b=b, u=u: result["closed_loop"].append(
                            closed_loop(b, duration_s, repeats, compiled.pop((b, u), None), u)))
    if "multi_device" in stages and scaling_batch:
        def stage_multi():
            result["multi_device"] = multi_device(scaling_batch, duration_s, repeats)
        run.run("multi_device", stage_multi)
    if "cpu_peer" in stages and cpu_batch:
        def stage_cpu():
            result["cpu_peer"] = cpu_peer(cpu_batch, duration_s, repeats)
        run.run("cpu_peer", stage_cpu)
    if "profile" in stages:
        result.setdefault("profile", [])
        variants = tuple(profile_variants or bench_profile.DEFAULT_VARIANTS)
        for b in profile_batches:
            def stage_profile(b=b):
                # An unfinished earlier attempt's partial rows go; this attempt's replace them.
                result["profile"] = [q for q in result["profile"] if q.get("batch") != b]
                p = {}
                result["profile"].append(p)     # filled, and written, row by row
                bench_profile.profile_closed_loop(
                    b, profile_duration_s, profile_repeats, variants,
                    compile_workers or bench_profile.DEFAULT_COMPILE_WORKERS, trace_dir,
                    log=run.log, into=p, on_update=run.write)
                run.write()
                p["controller_parts"] = bench_profile.profile_controller_parts(
                    b, profile_duration_s, profile_repeats)
            run.run(f"profile_{b}", stage_profile)
    if "gradient_step" in stages and grad_batch:
        def stage_grad():
            result["gradient_step"] = gradient_step(grad_batch, duration_s, repeats)
        run.run("gradient_step", stage_grad)
    if "gradient_compile" in stages and grad_compile_batch:
        result.setdefault("gradient_compile", [])
        gpu = jax.default_backend() == "gpu"
        variants = grad_variants if grad_variants is not None else (
            [{}] + ([{"autotune": 0}] if gpu else []))
        for i, v in enumerate(variants):
            run.run(f"gradient_compile_{i}", lambda v=v: result["gradient_compile"].extend(
                gradient_compile(grad_compile_batch, duration_s, [v], grad_cached)))
    run.write(complete=True)
    run.log(f"total {result['total_wall_s']:.1f} s; wrote {out} and {out.with_suffix('.md')}")
    return result


def _write(out: Path, result: dict) -> None:
    out.write_text(json.dumps(result, indent=1))
    out.with_suffix(".md").write_text(summary_markdown(result))


def summary_markdown(r: dict) -> str:
    lines = [f"# tkujax bench on {r['device_kind']} ({r['n_devices']} device(s))", "",
             f"Mode: {r.get('mode', 'default')}. Versions: {r['versions']}. Median of "
             f"{r['repeats']} runs; closed loop = {r['duration_s']} s pushes with controller, "
             f"sensors and metrics.", ""]
    if r["raw"] or r["closed_loop"]:
        lines += ["| batch | substep unroll | raw MJX steps/s (a) | closed-loop steps/s (b) | "
                  "pushes/s | b/a |", "|---|---|---|---|---|---|"]
        raw = {a["batch"]: a for a in r["raw"]}
        for b in r["closed_loop"]:
            a = raw.get(b["batch"])
            u = b.get("unroll_substeps", 1)
            lines.append(f"| {b['batch']} | {u} | {a['physics_steps_per_s']:.3g} | " if a else
                         f"| {b['batch']} | {u} | - | ")
            lines[-1] += (f"{b['physics_steps_per_s']:.3g} | {b['pushes_per_s']:.3g} | " +
                          (f"{b['physics_steps_per_s'] / a['physics_steps_per_s']:.2f} |" if a
                           else "- |"))
        for a in r["raw"]:
            if all(b["batch"] != a["batch"] for b in r["closed_loop"]):
                lines.append(f"| {a['batch']} | - | {a['physics_steps_per_s']:.3g} | - | - | - |")
    c = r.get("cpu_peer")
    if c and r["closed_loop"]:
        best = max(r["closed_loop"], key=lambda x: x["physics_steps_per_s"])
        lines += ["", f"CPU peer (MuJoCo C, batch {c['batch']}): {c['physics_steps_per_s']:.3g} "
                  f"steps/s, {c['pushes_per_s']:.3g} pushes/s; b/c = "
                  f"{best['physics_steps_per_s'] / c['physics_steps_per_s']:.1f}x"]
    elif c:
        lines += ["", f"CPU peer (MuJoCo C, batch {c['batch']}): {c['physics_steps_per_s']:.3g} "
                  f"steps/s, {c['pushes_per_s']:.3g} pushes/s"]
    g = r.get("gradient_step")
    if g:
        lines += ["", f"Gradient step (reverse mode through the closed loop, batch {g['batch']} x "
                  f"{g['duration_s']} s, {g['n_params']} parameters, remat {g['remat']}, float64 "
                  f"{g['float64']}): {g['seconds']:.2f} s per step = {g['pushes_per_s']:.3g} "
                  f"pushes/s, first call (compile) {g['first_call_s']:.0f} s"
                  + (" (read from the persistent cache: not a cold compile)"
                     if g.get("first_call_cache_hits") else "") + ", peak device "
                  "memory of the process (earlier stages included; run --stages "
                  "gradient_step alone for the step's own) "
                  + (f"{g['peak_device_bytes'] / 2**30:.2f} GiB" if g['peak_device_bytes']
                     else "n/a") + f", gradient finite: {g['grad_finite']}."]
    md = r.get("multi_device")
    if md:
        base = md[0]["pushes_per_s"]
        lines += ["", "| devices | batch | pushes/s | speed-up |", "|---|---|---|---|"]
        lines += [f"| {m['n_devices']} | {m['batch']} | {m['pushes_per_s']:.3g} | "
                  f"{m['pushes_per_s'] / base:.2f}x |" for m in md]
    gcs = r.get("gradient_compile") or []
    if gcs:
        lines += ["", "Compile of the tuning gradient (cold: empty persistent cache; includes "
                  "tracing and lowering):", "",
                  "| batch | variant | lower s | cold s | cached s | HLO chars | step s |",
                  "|---|---|---|---|---|---|---|"]
        for gc in gcs:
            v = gc.get("variant", gc.get("compiler_options")) or "tuner defaults"
            if "skipped" in gc:
                lines.append(f"| - | {v} | skipped: {gc['skipped']} | | | | |")
                continue
            lines.append(f"| {gc['batch']} | {v} | {gc.get('lower_s', '-')} | "
                         f"{gc['cold_s']:.1f} | {gc.get('cached_s', '-')} | "
                         f"{gc.get('hlo_chars', '-')} | {gc.get('step_s', '-')} |")
    for comp in r.get("compile_variants") or ([r["compile"]] if r.get("compile") else []):
        lines += ["", f"Compile of the closed loop (batch {comp.get('batch', '-')}, substep "
                  f"unroll {comp.get('unroll_substeps', 1)}): cold {comp['cold_s']:.1f} s, "
                  f"from the persistent cache {comp['cached_s']:.1f} s."]
    for p in r.get("profile") or []:
        from tkujax.bench_profile import profile_markdown

        lines += [""] + profile_markdown(p)
    if r.get("stages"):
        lines += ["", "| stage | status | wall s |", "|---|---|---|"]
        lines += [f"| {s['name']} | {s['status']}"
                  + (f" ({s['error'][:120]})" if s.get("error") else "")
                  + f" | {s.get('wall_s', '-')} |" for s in r["stages"]]
        lines += ["", f"Total wall time: {r.get('total_wall_s', 0):.1f} s"
                  + (f" over {r['runs']} runs (resumed)" if r.get("runs", 1) > 1 else "")
                  + ("" if r.get("complete") else " (incomplete: the run was cut short or is "
                     "still going)") + "."]
    return "\n".join(lines) + "\n"
