"""A study run whose wall-clock budget counts its own compiles (`study.budget_includes_compile`),
and the best-so-far latents at checkpoints of that clock (for a held-out fall curve over time).

`clocked_search` wraps the run's compiled calls (`search.SeedCalls`, one seed or seeds side by
side) in `ClockedCalls`, calls each function the method uses once before the search (the
compile; in parallel threads, as `search.warm_up`) and charges the run the compile time of its
functions: the longest of them (they compile side by side), as first measured in this process
for this policy and shape. So a method whose functions another method compiled earlier in the
same process is still charged their compile, as if it had run alone in a fresh process. The
search (`search.drive`, the same loop as every run) then gets budget_s - charge of wall clock.
Its own warm-up calls are answered from the pre-warm's results (the same inputs, so the same
outputs), so no work is repeated.

The run's clock: t = charge + the time since the search began. ClockedCalls follows the best
hard loss of every seed exactly as `search.Tracker` does (the start from the forward warm-up,
then every point of every forward or population call of the search) and keeps, for each
checkpoint time c, the best latents of the calls that ended by c (the start for every c before
the search began). The checkpoints' held-out fall rates are computed after the search.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence

import numpy as np

from tkujax.studies.tune.search import SearchConfig, drive, warm_up
from tkujax.studies.tune.searchers import finite_loss, searcher_class

CALL_NAMES = {"gradient": "gradients", "population": "population", "forward": "forward"}


def warm_up_inputs(cls, Z0: np.ndarray, cfg: SearchConfig) -> dict[str, np.ndarray]:
    """{call: latents} of `search.warm_up_plan` for searcher class cls (Z0: (S, k))."""
    out = {}
    if cls.uses_gradient:
        out["gradients"] = Z0
    width = cls.population_width(cfg)
    if width is not None:
        out["population"] = np.repeat(Z0[:, None], width, 1)
    out["forward"] = Z0
    return out


class ClockedCalls:
    """search.SeedCalls around `calls`: answers each function's first call from the pre-warm
    (`prewarm`) when its input is the same, and follows the best-so-far latents per seed."""

    def __init__(self, calls):
        self.calls, self.pushes = calls, calls.pushes
        self.cached: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.t0 = time.perf_counter()
        self.pending: list[float] = []
        self.snapshots: list[tuple[float, np.ndarray]] = []
        self.best_z: np.ndarray | None = None
        self.best_loss: np.ndarray | None = None
        self.selector = None           # a selection.ValidationSelector: its best is followed

    def prewarm(self, inputs: dict[str, np.ndarray]) -> dict[str, float]:
        """Call each function once (side by side); {call: seconds it took}."""
        def timed(name, zs):
            def call():
                t = time.perf_counter()
                out = getattr(self.calls, name)(zs)
                return out, time.perf_counter() - t
            return call

        got = warm_up({n: timed(n, z) for n, z in inputs.items()})
        self.cached = {n: (inputs[n], r[0]) for n, r in got.items()}
        return {n: r[1] for n, r in got.items()}

    def start(self, charge_s: float, checkpoints_s: Sequence[float]) -> None:
        """The run's clock starts charge_s in the past; checkpoints in run time (s)."""
        self.t0 = time.perf_counter() - charge_s
        self.pending = sorted(float(c) for c in checkpoints_s)

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def _call(self, name: str, zs) -> np.ndarray:
        zs = np.asarray(zs)
        hit = self.cached.pop(name, None)
        if hit is not None and hit[0].shape == zs.shape and np.array_equal(hit[0], zs):
            if name == "forward":                       # the start, as search.Tracker's
                self.best_z, self.best_loss = zs.astype(float).copy(), np.array(
                    [finite_loss(v) for v in hit[1]])
            return hit[1]
        out = getattr(self.calls, name)(zs)
        if name != "gradients":
            self._snapshot(self.elapsed())
            self._offer(zs.reshape(len(zs), -1, zs.shape[-1]), np.asarray(out).reshape(
                len(zs), -1))
        return out

    def _snapshot(self, t: float) -> None:
        best = self.best_z if self.selector is None or self.selector.best_z is None \
            else self.selector.best_z
        while self.pending and self.pending[0] <= t:
            self.snapshots.append((self.pending.pop(0), best.copy()))

    def next_batch(self) -> None:
        getattr(self.calls, "next_batch", lambda: None)()

    def _offer(self, zs: np.ndarray, losses: np.ndarray) -> None:
        for s in range(len(zs)):
            for z, v in zip(zs[s], losses[s]):
                v = finite_loss(v)
                if v < self.best_loss[s]:
                    self.best_z[s], self.best_loss[s] = z, v

    def finish(self) -> list[tuple[float, np.ndarray]]:
        """The checkpoints not reached by a call get the final best; [(c, (S, k))]."""
        self._snapshot(float("inf"))
        return self.snapshots

    def forward(self, zs) -> np.ndarray:
        return self._call("forward", zs)

    def population(self, zs) -> np.ndarray:
        return self._call("population", zs)

    def gradients(self, zs) -> np.ndarray:
        return self._call("gradients", zs)


def clocked_search(method: str, calls, z0, cfg: SearchConfig, seeds: Sequence[int],
                   label: str, compile_times: dict[str, float], fractions: Sequence[float],
                   log: Callable[[str], None] | None = None, select=None):
    """`search.drive` within ONE cfg.budget_s that counts the run's compiles. compile_times:
    {call: seconds of its first (compiling) call} for this policy and shape, updated here.
    Returns (drive's records, the charged compile seconds, [(t, (S, k) best latents)] at the
    checkpoints fractions x budget_s of the run's clock). select: as `search.drive`'s; the
    checkpoints then hold its best-so-far."""
    cls = searcher_class(method)
    clocked = ClockedCalls(calls)
    clocked.selector = select
    Z0 = np.repeat(np.asarray(z0, float)[None], len(seeds), 0)
    inputs = warm_up_inputs(cls, Z0, cfg)
    for name, seconds in clocked.prewarm(inputs).items():
        compile_times.setdefault(name, seconds)
    charge = max(compile_times[n] for n in inputs)
    clocked.start(charge, [f * cfg.budget_s for f in fractions])
    left = dataclasses.replace(cfg, budget_s=max(cfg.budget_s - charge, 0.0))
    records = drive(method, clocked, z0, left, seeds, label, log, select)
    return records, charge, clocked.finish()
