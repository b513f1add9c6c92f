"""Searches over the tuning latents under one wall-clock budget, for an honest comparison.

Every method starts from the same latent z0 (the paper's values), sees the same training
batch, and gets the same wall-clock budget with compilation excluded (each method's compiled
functions are called once before the clock starts; that time is reported as compile_s). Each
records the same convergence curve: the best HARD-gate training loss found so far (the loss
that evaluation uses) against wall time and pushes simulated, and returns the best latent.

The methods are the searchers of `tkujax.studies.tune.searchers` (registry `SEARCHERS`). One
loop, `drive`, runs any of them for one seed (`run_search`, through `OneSeedCalls`) or for
seeds side by side (`tkujax.studies.tune.lockstep`, one compiled call per step for all seeds).

Pushes simulated count a value-and-gradient rollout as one push.

Gradient options of one seed's calls (`GradientOptions`, `OneSeedCalls`; off by default, the
calls then those they always were):
  bundled gradients    with a problem whose bundle_sigma > 0, every gradient call draws fresh
                       per-push noise (a numpy Generator seeded by the run's seed; antithetic
                       pairs with bundle_antithetic) and asks for per-push gradients at
                       z + bundle_sigma * noise_i.
  diagnose_every = N   every gradient call computes per-push gradients (one compiled shape,
                       groups = n; the group means are then taken here) and records their
                       diagnostics (`tkujax.gradients.diagnostics.summary`: half-batch
                       cosine, top-5 share of the squared norm, norm quantiles); every N-th
                       call also checks the step the searcher actually takes from it: the
                       predicted change g . (z_next - z) of the differentiated loss (soft gate
                       at cfg.temperature_deg, the same batch) against the measured one, by a
                       forward at z and one at z_next (same compiled forward; inside the
                       budget clock, their time reported as diagnostics_s).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Protocol

import numpy as np

from tkujax.gradients.bundled import bundle_noise
from tkujax.gradients.diagnostics import cosine, summary
from tkujax.studies.tune.reparam import DEG
from tkujax.studies.tune.selection import ValidationSelector, incumbent
from tkujax.dialects.validation import SpecError, boolean, integer, number
from tkujax.studies.tune.searchers import (METHODS, SearchConfig, alpha_order_mix, finite_loss,
                                           searcher_class)

__all__ = ["METHODS", "SearchConfig", "alpha_order_mix", "run_search", "drive", "warm_up",
           "calls_used",
           "warm_up_calls", "first_order_grads", "clipped_group_means", "OneSeedCalls",
           "GradientOptions"]



class Tracker:
    """Best-so-far hard loss, and the convergence curve."""

    def __init__(self, z0, loss0: float, pushes_per_eval: int, t0: float | None = None):
        self.z, self.loss = np.asarray(z0, float), finite_loss(loss0)
        self.t0 = time.perf_counter() if t0 is None else t0
        self.pushes = pushes_per_eval
        self.curve = [dict(wall_s=0.0, pushes=pushes_per_eval, best_loss=self.loss)]

    def offer(self, z, loss: float) -> None:
        loss = finite_loss(loss)
        if loss < self.loss:
            self.z, self.loss = np.asarray(z, float), loss

    def tick(self, pushes: int) -> None:
        self.pushes += pushes
        self.curve.append(dict(wall_s=round(self.elapsed(), 3), pushes=self.pushes,
                               best_loss=self.loss))

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0


class SeedCalls(Protocol):
    """The compiled calls a search makes, over a leading seed axis S (one training batch and
    key set per seed, bound in). `pushes` is the batch size n."""

    pushes: int

    def forward(self, zs: np.ndarray) -> np.ndarray: ...          # (S, k) -> (S,) hard loss

    def population(self, zs: np.ndarray) -> np.ndarray: ...       # (S, P, k) -> (S, P)

    def gradients(self, zs: np.ndarray) -> np.ndarray: ...        # (S, k) -> (S, groups, k)


@dataclasses.dataclass(frozen=True)
class GradientOptions:
    """What a seed's gradient calls add (module docstring); the defaults add nothing."""

    diagnose_every: int = 0          # 0: no diagnostics; N: per-push diagnostics, step check
    bundle_antithetic: bool = False  # antithetic bundle noise (problem.bundle_sigma > 0)


def parse_gradient_options(tune: dict, batch: int) -> dict:
    """tune.gradient_window_ticks, timing_gradient, bundle_sigma, bundle_antithetic,
    diagnose_every (TuneSpec fields by name)."""
    window = tune.get("gradient_window_ticks")
    out = dict(
        gradient_window_ticks=None if window is None else integer(
            "tune.gradient_window_ticks", window, 1, 100_000),
        timing_gradient=boolean("tune.timing_gradient", tune.get("timing_gradient", False)),
        bundle_sigma=number("tune.bundle_sigma", tune.get("bundle_sigma", 0.0), 0.0, 10.0,
                            "(latent units)"),
        bundle_antithetic=boolean("tune.bundle_antithetic",
                                  tune.get("bundle_antithetic", False)),
        diagnose_every=integer("tune.diagnose_every", tune.get("diagnose_every", 10), 0,
                               1_000_000))
    if out["bundle_antithetic"] and batch % 2:
        raise SpecError(f"tune.bundle_antithetic: antithetic pairs need an even tune.batch, "
                        f"got {batch}")
    return out


class OneSeedCalls:
    """SeedCalls for one seed (S = 1) through the problem's own forward, population and
    grouped value-and-gradient (any object with those methods: the tests' landscapes too).
    options / seed: bundled gradients and diagnostics (module docstring); `diagnostics` holds
    one record per gradient call, `step_checks` one per checked step."""

    def __init__(self, problem, batch: dict, keys, cfg: SearchConfig,
                 options: GradientOptions = GradientOptions(), seed: int = 0):
        self.problem, self.batch, self.keys, self.cfg = problem, batch, keys, cfg
        self.pushes = len(keys)
        self.options, self.rng = options, np.random.default_rng(seed)
        self.sigma = float(getattr(problem, "bundle_sigma", 0.0))
        self.diagnostics: list[dict] = []
        self.step_checks: list[dict] = []
        self.diagnostics_s = 0.0
        self._pending = None           # (call, z, g, soft loss at z) of a step to check

    def forward(self, zs) -> np.ndarray:
        return np.array([float(self.problem.forward(zs[0], 0.0, self.batch, self.keys)[0])])

    def population(self, zs) -> np.ndarray:
        return np.asarray(self.problem.population(zs[0], 0.0, self.batch, self.keys),
                          np.float64)[None]

    def gradients(self, zs) -> np.ndarray:
        tau = self.cfg.temperature_deg * DEG
        if not self.sigma and not self.options.diagnose_every:
            return first_order_grads(self.problem.grouped_value_and_grad, zs[0], tau,
                                     self.batch, self.keys, self.cfg, self.pushes)[None]
        z, n = np.asarray(zs[0], float), self.pushes
        extra = {}
        if self.sigma:
            extra["noise"] = bundle_noise(self.rng, n, z.size, self.options.bundle_antithetic)
        losses, per_push = self.problem.grouped_value_and_grad(z, tau, self.batch, self.keys,
                                                               n, **extra)
        per_push = np.asarray(per_push, float)
        if self.options.diagnose_every:
            self._diagnose(z, tau, np.asarray(losses, float), per_push)
        if self.cfg.push_clip > 0:
            return clipped_group_means(per_push, self.cfg.groups, self.cfg.push_clip)[None]
        g = np.where(np.isfinite(per_push), per_push, 0.0)
        return g.reshape(self.cfg.groups, n // self.cfg.groups, -1).mean(1)[None]

    def _soft_loss(self, z, tau) -> float:
        return float(self.problem.forward(z, tau, self.batch, self.keys)[0])

    def _diagnose(self, z, tau, losses, per_push) -> None:
        """Record this call's per-push diagnostics; finish the pending step check at z (the
        point the searcher moved to); start one every diagnose_every calls."""
        t0 = time.perf_counter()
        call = len(self.diagnostics)
        finite = np.all(np.isfinite(per_push), axis=1)
        g = np.where(finite[:, None], per_push, 0.0)
        rec = dict(call=call, loss=float(np.nanmean(losses)), nonfinite=int((~finite).sum()),
                   **summary(g))
        self.diagnostics.append(rec)
        if self._pending is not None:
            c, z0, g0, l0 = self._pending
            dz = z - z0
            self.step_checks.append(dict(
                call=c, step_norm=float(np.linalg.norm(dz)), cos_step_neg_grad=cosine(dz, -g0),
                predicted=float(g0 @ dz), measured=self._soft_loss(z, tau) - l0))
            self._pending = None
        if call % self.options.diagnose_every == 0:
            self._pending = (call, z, g.mean(0), self._soft_loss(z, tau))
        self.diagnostics_s += time.perf_counter() - t0

    def reset_diagnostics(self) -> None:
        """Forget what the warm-up's gradient call recorded (called by `drive` when the clock
        starts)."""
        self.diagnostics, self.step_checks, self.diagnostics_s = [], [], 0.0
        self._pending = None

    def record(self) -> dict:
        """The run record's gradient_diagnostics."""
        return dict(diagnose_every=self.options.diagnose_every, bundle_sigma=self.sigma,
                    bundle_antithetic=self.options.bundle_antithetic,
                    diagnostics_s=round(self.diagnostics_s, 3), per_call=self.diagnostics,
                    step_checks=self.step_checks)


def run_search(method: str, problem, z0, batch: dict, keys, cfg: SearchConfig,
               seed: int, log: Callable[[str], None] | None = None,
               options: GradientOptions = GradientOptions(),
               select: ValidationSelector | None = None) -> dict:
    """Run one method within cfg.budget_s. Returns dict(method, seed, z_best, best_loss,
    compile_s, iterations, curve, extra), and gradient_diagnostics (`OneSeedCalls.record`)
    when options.diagnose_every > 0 and the method uses gradients."""
    cls = searcher_class(method)
    # The control-off column of the harm weight (w_harm > 0) is computed here, once for the
    # whole search, before the clock starts.
    if hasattr(problem, "with_off_survived"):
        batch = problem.with_off_survived(batch, keys)
    calls = OneSeedCalls(problem, batch, keys, cfg, options, seed)
    out = drive(method, calls, z0, cfg, [seed], method, log, select)[0]
    if options.diagnose_every and cls.uses_gradient:
        out["gradient_diagnostics"] = calls.record()
    return out


def warm_up_plan(cls, calls: SeedCalls, Z0: np.ndarray, cfg: SearchConfig) -> dict:
    """What searcher class `cls` calls, each once at the loop's shapes (Z0: (S, k) start
    latents), the longest compile (the gradient) first and the forward (the start losses)
    last."""
    plan = {}
    if cls.uses_gradient:
        plan["gradient"] = lambda: calls.gradients(Z0)
    width = cls.population_width(cfg)
    if width is not None:
        plan["population"] = lambda: calls.population(np.repeat(Z0[:, None], width, 1))
    plan["forward"] = lambda: calls.forward(Z0)
    return plan


def calls_used(method: str) -> set[str]:
    """The compiled calls `method` makes, by their warm-up names: "forward" always,
    "population" and "gradient" as its searcher asks."""
    cls = searcher_class(method)
    out = {"forward"}
    if cls.population_width(SearchConfig()) is not None:
        out.add("population")
    if cls.uses_gradient:
        out.add("gradient")
    return out


def drive(method: str, calls: SeedCalls, z0, cfg: SearchConfig, seeds: Sequence[int],
          label: str, log: Callable[[str], None] | None = None,
          select: ValidationSelector | None = None) -> list[dict]:
    """Run `method`'s searcher for every seed side by side through `calls` within ONE
    cfg.budget_s (compile excluded: the calls are warmed up first). label starts each
    progress line. Returns one dict per seed: (method, seed, z_best, best_loss, compile_s,
    iterations, curve, extra).

    select: z_best is the selector's best by the validation fall rate (the selection's
    record added), not the lowest training loss (tkujax.studies.tune.selection). Calls with a
    `next_batch()` method are moved to a fresh training batch after every iteration."""
    cls = searcher_class(method)
    z0 = np.asarray(z0, float)
    t0 = time.perf_counter()
    hard0 = warm_up(warm_up_plan(cls, calls, np.repeat(z0[None], len(seeds), 0), cfg))
    compile_s = time.perf_counter() - t0
    if isinstance(calls, OneSeedCalls):
        calls.reset_diagnostics()
    clock = time.perf_counter()                       # one clock for every seed
    tracks = [Tracker(z0, h, calls.pushes, clock) for h in hard0["forward"]]
    searchers = [cls(z0, h, cfg, s) for h, s in zip(hard0["forward"], seeds)]
    if select is not None:
        select.start(np.repeat(z0[None], len(seeds), 0), tracks[0].elapsed())
    next_batch = getattr(calls, "next_batch", None)
    it, offered = 0, True
    while it < cfg.max_iterations and tracks[0].elapsed() < cfg.budget_s:
        _iterate(searchers, tracks, calls, cls.population_width(cfg) is None)
        it += 1
        if next_batch is not None:
            next_batch()
        offered = select is None or select.due(tracks[0].elapsed())
        if select is not None and offered:
            select.offer(np.stack([incumbent(s) for s in searchers]), tracks[0].elapsed())
        if log and cls.progress_label is not None:
            log(f"{label}  {cls.counter} {it:3d}  best "
                + " ".join(f"{tr.loss:.4f}" for tr in tracks) + f"  {cls.progress_label}"
                + cls.progress_join.join(s.progress() for s in searchers)
                + f"  {tracks[0].elapsed():.0f}/{cfg.budget_s:g} s")
    if not offered:                                   # the last iterate, always looked at
        select.offer(np.stack([incumbent(s) for s in searchers]), tracks[0].elapsed())
    out = [dict(method=method, seed=s, z_best=tr.z.tolist(), best_loss=tr.loss,
                compile_s=round(compile_s, 2), iterations=it, curve=tr.curve,
                extra=searcher.extra())
           for s, tr, searcher in zip(seeds, tracks, searchers)]
    if select is not None:
        for i, rec in enumerate(out):
            rec.update(z_best=select.best_z[i].tolist(), **select.record(i))
    return out


def _iterate(searchers: list, tracks: list[Tracker], calls: SeedCalls, one_point: bool) -> None:
    """One iteration of every seed: the gradients asked for (one call for all seeds, counted
    for all), the points asked for (one call), told back, offered to the trackers."""
    wanted = [s.gradient_at() for s in searchers]
    grads: list = [None] * len(searchers)
    pushes = 0
    if any(w is not None for w in wanted):
        fill = next(w for w in wanted if w is not None)
        g = calls.gradients(np.stack([fill if w is None else w for w in wanted]))
        grads = [None if w is None else gi for w, gi in zip(wanted, g)]
        pushes = calls.pushes
    points = np.stack([s.ask(g) for s, g in zip(searchers, grads)])            # (S, P, k)
    losses = calls.forward(points[:, 0])[:, None] if one_point else calls.population(points)
    for searcher, tr, zz, ll in zip(searchers, tracks, points, losses):
        searcher.tell(zz, ll)
        for z, v in zip(zz, ll):
            tr.offer(z, v)
        tr.tick(pushes + len(zz) * calls.pushes)


def warm_up(calls: dict[str, Callable[[], object]], parallel: bool = True) -> dict:
    """Call each function once ({name: result}): the first call of a jitted function compiles
    it. parallel: in one thread each, started in the order given (the longest compile first),
    so that XLA's compiles, which release the GIL, overlap; only the tracing stays serial. A
    call's error is raised here. The results are the same either way (the same programs)."""
    if not parallel or len(calls) < 2:
        return {name: call() for name, call in calls.items()}
    with concurrent.futures.ThreadPoolExecutor(len(calls), "tkujax-warm-up") as pool:
        futures = {name: pool.submit(call) for name, call in calls.items()}
        return {name: f.result() for name, f in futures.items()}


def warm_up_calls(method: str, problem, z0, batch: dict, keys, cfg: SearchConfig,
                  parallel: bool = True) -> dict:
    """What `method` calls for one seed, each once, side by side (`warm_up`): the forward (its
    hard loss under "forward"), the population call (cma, sepcma, hybrid, linesearch) and the
    grouped first-order gradient (gradient, hybrid, linesearch). parallel=False: one after
    the other (scripts/bench_warmup_parallel.py compares the two)."""
    plan = warm_up_plan(searcher_class(method), OneSeedCalls(problem, batch, keys, cfg),
                        np.asarray(z0, float)[None], cfg)
    out = warm_up(plan, parallel)
    out["forward"] = out["forward"][0]
    return out


def clipped_group_means(per_push: np.ndarray, groups: int, clip: float) -> np.ndarray:
    """per_push (n, k) gradients -> (groups, k) group means after clipping each push's
    gradient to clip x the median per-push norm (non-finite pushes count as zero)."""
    g = np.where(np.isfinite(per_push), per_push, 0.0)
    norms = np.linalg.norm(g, axis=-1)
    cap = clip * np.median(norms)
    g = g * np.minimum(1.0, cap / np.maximum(norms, 1e-30))[..., None]
    n, k = g.shape
    return g.reshape(groups, n // groups, k).mean(1)


def first_order_grads(value_and_grad_groups, z, tau, batch, keys, cfg: SearchConfig,
                      n: int) -> np.ndarray:
    """(groups, k) first-order gradient samples: the groups' mean gradients, or with
    cfg.push_clip > 0 the clipped per-push gradients' group means (one call either way)."""
    if cfg.push_clip > 0:
        _, per_push = value_and_grad_groups(z, tau, batch, keys, n)
        return clipped_group_means(np.asarray(per_push), cfg.groups, cfg.push_clip)
    return np.asarray(value_and_grad_groups(z, tau, batch, keys, cfg.groups)[1])
