"""`run_bench`: the bench's stages run one by one under a frozen `BenchConfig`.

Two sizes (MODES): "default" (raw MJX and the closed loop at 1,024 and 65,536, the CPU peer,
the closed loop's compile: a few minutes on one GPU) and "full" (four batches, the gradient
step and its compile, the multi-device scaling). Every stage is timed; progress goes to
stderr, and the JSON and its .md are rewritten after each stage with `stages` (name, status,
wall_s), `total_wall_s` and `complete`, so a run cut short keeps what finished, and
`run_bench(..., resume=True)` (`--resume`) goes on with it. Each figure is the median of
`repeats` timed runs after a warm-up; speeds are reported, never asserted.
"""

from __future__ import annotations

import dataclasses
import errno
import json
import platform
import sys
import time
import traceback
from pathlib import Path

import jax
import numpy as np

from tkujax.bench import profile, stages
from tkujax.bench.controller_parts import profile_controller_parts
from tkujax.bench.bench_summary import summary_markdown
from tkujax.sweeps.progress import StatusLog
from tkujax.sweeps.provenance import package_versions
from tkujax.sweeps.sweep import SWEEP_UNROLL_SUBSTEPS

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
MAX_BATCH = 10_000_000


def _whole(name, v, lo, hi=MAX_BATCH):
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
        raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {v!r}")


def _seconds(name, v, hi):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= hi:
        raise ValueError(f"{name} must be in (0, {hi}] seconds, got {v!r}")


@dataclasses.dataclass(frozen=True)
class BenchConfig:
    """What the bench runs (the "default" mode's sizes unless given; `BenchConfig.for_mode`).

    stages: the STAGE_GROUPS to run (None: those the sizes enable, plus "profile" when
    `profile_batches` is given). A size of 0 or None skips its stage. unroll_substeps: the
    closed loop's loop structures to compile and time (None: the sweeps' own). grad_variants:
    `stages.parse_grad_variants`'s dicts. Checked when built: a ValueError names the field,
    its allowed range and the value, before any stage runs."""

    batches: tuple[int, ...] = MODES["default"]["batches"]
    duration_s: float = 1.5
    raw_steps: int = 300
    repeats: int = MODES["default"]["repeats"]
    cpu_batch: int | None = 256
    grad_batch: int | None = None
    compile_batch: int = 1024
    scaling_batch: int | None = None
    grad_compile_batch: int = 0
    mode: str = "default"
    stages: tuple[str, ...] | None = None
    profile_batches: tuple[int, ...] = ()
    profile_duration_s: float = 0.3
    profile_repeats: int = 1
    profile_variants: tuple[str, ...] | None = None
    compile_workers: int | None = None
    trace_dir: str | Path | None = None
    grad_variants: list[dict] | None = None
    grad_cached: bool = True
    budget_s: float | None = None
    unroll_substeps: tuple[int, ...] | None = None

    @classmethod
    def for_mode(cls, mode: str = "default", **fields) -> BenchConfig:
        """The sizes of MODES[mode], with `fields` on top."""
        if mode not in MODES:
            raise ValueError(f"mode must be one of {tuple(MODES)}, got {mode!r}")
        return cls(**{**MODES[mode], "mode": mode, **fields})

    def __post_init__(self):
        for name in ("batches", "profile_batches"):
            for b in getattr(self, name):
                _whole(f"{name} (each)", b, 1)
        for name in ("raw_steps", "repeats", "profile_repeats"):
            _whole(name, getattr(self, name), 1, 100_000)
        for name in ("compile_batch", "grad_compile_batch"):
            _whole(name, getattr(self, name), 0)
        for name in ("cpu_batch", "grad_batch", "scaling_batch"):     # None or 0: skipped
            if getattr(self, name) is not None:
                _whole(name, getattr(self, name), 0)
        if self.compile_workers is not None:
            _whole("compile_workers", self.compile_workers, 1, 256)
        _seconds("duration_s", self.duration_s, 60)
        _seconds("profile_duration_s", self.profile_duration_s, 60)
        b = self.budget_s           # 0: every stage skipped (the run's record alone)
        if b is not None and (isinstance(b, bool) or not isinstance(b, (int, float))
                              or not 0 <= b <= 1e6):
            raise ValueError(f"budget_s must be in [0, 1e6] seconds, got {b!r}")
        if self.unroll_substeps is not None and any(int(u) < 1 for u in self.unroll_substeps):
            raise ValueError(f"unroll_substeps must be >= 1, got {list(self.unroll_substeps)}")
        unknown = set(self.stages or ()) - set(STAGE_GROUPS)
        if unknown:
            raise ValueError(f"unknown bench stage(s) {sorted(unknown)}; known: {STAGE_GROUPS}")
        for v in self.profile_variants or ():
            if v != "no_push":
                profile.variant_config(v)        # unknown names fail before any stage runs

    def stage_groups(self) -> tuple[str, ...]:
        """The stages to run: `stages`, or those the sizes enable."""
        if self.stages is not None:
            return tuple(self.stages)
        return tuple(g for g, on in (
            ("compile", self.compile_batch), ("throughput", self.batches),
            ("multi_device", self.scaling_batch and jax.local_device_count() > 1),
            ("cpu_peer", self.cpu_batch), ("profile", self.profile_batches),
            ("gradient_step", self.grad_batch),
            ("gradient_compile", self.grad_compile_batch)) if on)

    def unrolls(self) -> tuple[int, ...]:
        return tuple(self.unroll_substeps or (SWEEP_UNROLL_SUBSTEPS,))


class Stages:
    """Runs the bench's stages one by one: progress on stderr, each stage's wall time and
    status in result["stages"], the JSON (and .md) rewritten after each stage, so that a run
    cut short keeps what finished. A failing stage is recorded and the next one runs; with
    `budget_s`, a stage that would start after the budget is recorded as skipped. A resumed
    `result` (`resumed`) already records its finished stages: they are kept and not run
    again, and its `total_wall_s` (the earlier runs' wall time) is added to this run's."""

    def __init__(self, out: Path, result: dict, budget_s: float | None, quiet: bool):
        self.out, self.result, self.budget_s, self.quiet = out, result, budget_s, quiet
        self.done = frozenset(s["name"] for s in result.setdefault("stages", []))
        self.wall_before_s = result.get("total_wall_s", 0.0)
        self.t0 = time.perf_counter()
        self.status = StatusLog(quiet, budget_s=budget_s, desc="bench ")

    def log(self, msg: str) -> None:
        if not self.quiet:
            self.status(f"[bench {time.perf_counter() - self.t0:7.1f} s] {msg}")

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


def resumed(out: Path, settings: dict, device_kind: str, versions: dict) -> dict | None:
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



def _write(out: Path, result: dict) -> None:
    out.write_text(json.dumps(result, indent=1))
    out.with_suffix(".md").write_text(summary_markdown(result))


def _settings(config: BenchConfig, groups: tuple[str, ...]) -> dict:
    """What the figures depend on: a resumed run must have been made with the same."""
    c = config
    return dict(
        mode=c.mode, stages=list(groups), batches=[int(b) for b in c.batches],
        duration_s=c.duration_s, raw_steps=c.raw_steps, repeats=c.repeats,
        cpu_batch=c.cpu_batch, grad_batch=c.grad_batch, compile_batch=c.compile_batch,
        scaling_batch=c.scaling_batch, grad_compile_batch=c.grad_compile_batch,
        grad_variants=c.grad_variants, grad_cached=c.grad_cached,
        unroll_substeps=[int(u) for u in c.unrolls()],
        profile_batches=[int(b) for b in c.profile_batches],
        profile_duration_s=c.profile_duration_s, profile_repeats=c.profile_repeats,
        profile_variants=list(c.profile_variants) if c.profile_variants else None,
        n_devices=jax.device_count())


def _throughput_stages(run: Stages, config: BenchConfig, groups, result: dict) -> None:
    """The compile stage (keeping its executables) and the raw / closed-loop throughput."""
    c, compiled, unrolls = config, {}, config.unrolls()
    result["unroll_substeps"] = list(unrolls)
    if "compile" in groups and c.compile_batch:
        for u in unrolls:
            def stage_compile(u=u):
                t = stages.compile_times(c.compile_batch, c.duration_s, keep=compiled,
                                         unroll_substeps=u)
                result.setdefault("compile_variants", []).append(t)
                result.setdefault("compile", t)         # the first structure's
            run.run("compile" if len(unrolls) == 1 else f"compile_unroll{u}", stage_compile)
    if "throughput" in groups:
        for b in c.batches:
            run.run(f"raw_{b}", lambda b=b: result["raw"].append(
                stages.raw_stepping(b, c.raw_steps, c.repeats)))
            for u in unrolls:
                run.run(f"closed_loop_{b}" + ("" if len(unrolls) == 1 else f"_unroll{u}"),
                        lambda b=b, u=u: result["closed_loop"].append(stages.closed_loop(
                            b, c.duration_s, c.repeats, compiled.pop((b, u), None), u)))


def _profile_stages(run: Stages, config: BenchConfig, result: dict) -> None:
    """The closed loop's profile at each of `profile_batches`, written row by row."""
    c = config
    result.setdefault("profile", [])
    variants = tuple(c.profile_variants or profile.DEFAULT_VARIANTS)
    for b in c.profile_batches:
        def stage_profile(b=b):
            # An unfinished earlier attempt's partial rows go; this attempt's replace them.
            result["profile"] = [q for q in result["profile"] if q.get("batch") != b]
            p = {}
            result["profile"].append(p)     # filled, and written, row by row
            profile.profile_closed_loop(
                b, c.profile_duration_s, c.profile_repeats, variants,
                c.compile_workers or profile.DEFAULT_COMPILE_WORKERS, c.trace_dir,
                log=run.log, into=p, on_update=run.write)
            run.write()
            p["controller_parts"] = profile_controller_parts(b, c.profile_duration_s,
                                                             c.profile_repeats)
        run.run(f"profile_{b}", stage_profile)


def _other_stages(run: Stages, config: BenchConfig, groups, result: dict) -> None:
    """Multi-device scaling, the CPU peer, the gradient step and the gradient's compile."""
    c = config

    def timed_stage(name: str, batch: int, measure) -> None:
        """A stage that times `measure(batch, duration, repeats)` into result[name]."""
        if name in groups and batch:
            run.run(name, lambda: result.__setitem__(name, measure(batch, c.duration_s,
                                                                   c.repeats)))

    timed_stage("multi_device", c.scaling_batch, stages.multi_device)
    timed_stage("cpu_peer", c.cpu_batch, stages.cpu_peer)
    if "profile" in groups:
        _profile_stages(run, c, result)
    timed_stage("gradient_step", c.grad_batch, stages.gradient_step)
    if "gradient_compile" in groups and c.grad_compile_batch:
        result.setdefault("gradient_compile", [])
        gpu = jax.default_backend() == "gpu"
        variants = c.grad_variants if c.grad_variants is not None else (
            [{}] + ([{"autotune": 0}] if gpu else []))
        for i, v in enumerate(variants):
            run.run(f"gradient_compile_{i}", lambda v=v: result["gradient_compile"].extend(
                stages.gradient_compile(c.grad_compile_batch, c.duration_s, [v],
                                        c.grad_cached)))


def run_bench(out: str | Path, config: BenchConfig | None = None, *, quiet: bool = False,
              resume: bool = False, **fields) -> dict:
    """The bench (module docstring) under `config` (or BenchConfig(**fields): the same
    fields as keywords). Returns the result, also written to `out` (JSON) and its .md;
    resume: go on with the run in `out` (same settings, device kind and versions)."""
    if config is None:
        config = BenchConfig(**fields)
    elif fields:
        config = dataclasses.replace(config, **fields)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    for path in (out, out.with_suffix(".md")):       # checked before minutes of stages
        if path.is_dir():
            raise IsADirectoryError(errno.EISDIR, "a folder has that name (--out names the "
                                    "result's JSON file)", str(path))
    groups = config.stage_groups()
    dev = jax.devices()[0]
    device_kind = getattr(dev, "device_kind", dev.platform)
    versions = package_versions(("jax", "jaxlib", "mujoco", "mujoco-mjx"))
    settings = _settings(config, groups)
    result = resumed(out, settings, device_kind, versions) if resume else None
    if result is None:
        result = dict(mode=config.mode, stages_requested=list(groups), device=str(dev),
                      device_kind=device_kind, n_devices=jax.device_count(),
                      platform=platform.platform(), versions=versions,
                      repeats=config.repeats, duration_s=config.duration_s, raw=[],
                      closed_loop=[], settings=settings)
    run = Stages(out, result, config.budget_s, quiet)
    if result.get("runs", 1) > 1:
        run.log(f"resuming {out}: {len(run.done)} stage(s) kept from earlier run(s)")
    _throughput_stages(run, config, groups, result)
    _other_stages(run, config, groups, result)
    run.write(complete=True)
    run.log(f"total {result['total_wall_s']:.1f} s; wrote {out} and {out.with_suffix('.md')}")
    return result
