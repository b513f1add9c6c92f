"""Which latent a search returns: its best-so-far by the hard fall rate on validation pushes.

A search's own best-so-far (`search.Tracker`) is the lowest training loss it has seen on its
training batch. On one fixed batch that choice over-fits the batch, and the tuning loss is not
the fall rate: results/gradients (the first comparison) found every method's best-so-far by
the margin loss RAISING the held-out fall rate above the start's. With fresh training batches
per iteration the training losses are not even comparable across iterations.

`ValidationSelector` therefore keeps, per seed, the latent with the lowest HARD fall rate on a
fixed validation set of pushes drawn from the training distribution (its own seed, never one
of the evaluation sets), looking at each seed's incumbent (`incumbent`: the Adam iterate, the
CMA-ES mean, ...) every `every_s` seconds of the search's clock and at its end. The start is
evaluated first, so a search that finds nothing better returns its start. A later latent
replaces the best only when its fall rate is strictly lower. These evaluations run inside the
search's clock, for every method alike (tests/test_tune_selection.py).

`BatchStream` gives a search a fresh training batch per iteration (the same draws for every
method: draw d of seed s is the same pushes in every run).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

# Seed offsets of the pushes the selection and the fresh batches draw, beside the evaluation
# sets' (evaluate.seed + s, + 1000 + s, + 2000 + s; tkujax.studies.tune.dimension_study).
VALIDATION_SEED_OFFSET = 3000
FRESH_DRAW_SEED_STRIDE = 100_000

SELECT_MODES = ("training", "validation")


def incumbent(searcher) -> np.ndarray:
    """The point a searcher stands on: the CMA-ES mean for the CMA-ES family, else its iterate
    `z` (Adam, the hybrid, the (1+1)-ES, the line search)."""
    opt = getattr(searcher, "opt", None)
    if opt is not None and hasattr(opt, "mean"):
        return np.array(opt.mean, float)
    return np.array(searcher.z, float)


class ValidationSelector:
    """Best-so-far per seed by the validation fall rate (module docstring).

    fall_rates((S, k) latents) -> (S,) hard fall rates, seed s's latent on seed s's
    validation pushes (diverged pushes not counted)."""

    def __init__(self, fall_rates: Callable[[np.ndarray], np.ndarray], every_s: float):
        if not every_s > 0:
            raise ValueError(f"every_s must be > 0 s, got {every_s!r}")
        self.fall_rates, self.every_s = fall_rates, float(every_s)
        self.best_z: np.ndarray | None = None
        self.best_fall: np.ndarray | None = None
        self.start_fall: np.ndarray | None = None
        self.curve: list[dict] = []
        self.last_s = -math.inf
        self.seconds = 0.0

    def _rates(self, zs: np.ndarray) -> np.ndarray:
        rates = np.asarray(self.fall_rates(np.asarray(zs, float)), float)
        return np.where(np.isfinite(rates), rates, math.inf)

    def start(self, Z0: np.ndarray, t_s: float) -> None:
        """Evaluate the start latents (S, k) at clock time t_s."""
        self.best_z = np.array(Z0, float)
        self.best_fall = self.start_fall = self._rates(self.best_z)
        self._log(t_s, self.best_fall)

    def due(self, t_s: float) -> bool:
        return t_s - self.last_s >= self.every_s

    def offer(self, zs: np.ndarray, t_s: float) -> None:
        """Evaluate the incumbents zs (S, k); keep those strictly better than each seed's
        best."""
        rates = self._rates(zs)
        better = rates < self.best_fall
        self.best_z = np.where(better[:, None], np.asarray(zs, float), self.best_z)
        self.best_fall = np.where(better, rates, self.best_fall)
        self._log(t_s, rates)

    def _log(self, t_s: float, rates: np.ndarray) -> None:
        self.last_s = t_s
        self.curve.append(dict(wall_s=round(float(t_s), 3),
                               fall=[float(r) for r in rates],
                               best=[float(b) for b in self.best_fall]))

    def record(self, s: int) -> dict:
        """Seed index s's part of the run record."""
        return dict(select="validation", validation_fall=float(self.best_fall[s]),
                    start_validation_fall=float(self.start_fall[s]),
                    selection_curve=[dict(wall_s=c["wall_s"], fall=c["fall"][s],
                                          best=c["best"][s]) for c in self.curve])


class BatchStream:
    """Fresh training batches: draw(d) -> per-seed (batch, keys) for draw d >= 1 (draw 0 is the
    run's first training batch, given to the calls at construction)."""

    def __init__(self, sample: Callable[[int], tuple[dict, object]], seeds: Sequence[int],
                 base_seed: int):
        self.sample, self.seeds, self.base_seed = sample, [int(s) for s in seeds], base_seed

    def draw(self, d: int) -> tuple[list[dict], list]:
        pairs = [self.sample(self.base_seed + s + FRESH_DRAW_SEED_STRIDE * d)
                 for s in self.seeds]
        return [p[0] for p in pairs], [p[1] for p in pairs]
