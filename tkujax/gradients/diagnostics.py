"""Diagnostics of per-push gradients G (n_pushes, n_params), numpy.

  half_batch_cosine   cosine between the mean gradients of the two halves of the batch: near 1
                      when the batch agrees on a direction, near 0 (or below) when noise rules.
  top_k_share         share of the summed squared norm carried by the k largest per-push
                      gradients: near k / n when every push counts alike, near 1 when a few do.
  norm_quantiles      per-push gradient norms at the given quantiles.
  step_check          the loss's change along -g/|g| by a step (parameter units): predicted to
                      first order (-step |g|) against measured (loss(z - step g/|g|) - loss(z)).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

QUANTILES = (0.0, 0.1, 0.5, 0.9, 0.99, 1.0)


def _rows(grads) -> np.ndarray:
    g = np.asarray(grads, float)
    if g.ndim != 2:
        raise ValueError(f"per-push gradients must be (n_pushes, n_params), got {g.shape}")
    return g


def cosine(a, b) -> float:
    """Cosine of two vectors; NaN when either is zero."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    return float(a @ b / (na * nb)) if na > 0 and nb > 0 else float("nan")


def half_batch_cosine(grads) -> float:
    """Cosine between the mean of the first and of the second half of the rows."""
    g = _rows(grads)
    half = g.shape[0] // 2
    return cosine(g[:half].mean(0), g[half:2 * half].mean(0))


def top_k_share(grads, k: int = 5) -> float:
    """Share of sum_i |g_i|^2 in the k rows of largest norm (NaN when all are zero)."""
    sq = np.sum(_rows(grads) ** 2, axis=1)
    total = sq.sum()
    return float(np.sort(sq)[::-1][:k].sum() / total) if total > 0 else float("nan")


def norm_quantiles(grads, quantiles=QUANTILES) -> dict[float, float]:
    """{q: quantile of the per-push norms}."""
    norms = np.linalg.norm(_rows(grads), axis=1)
    return {float(q): float(v) for q, v in zip(quantiles, np.quantile(norms, quantiles))}


def clip_rows(grads, max_norm: float) -> np.ndarray:
    """Each row scaled down to norm <= max_norm (the tuner's per-push clip)."""
    g = _rows(grads)
    norms = np.linalg.norm(g, axis=1, keepdims=True)
    return g * np.minimum(1.0, max_norm / np.maximum(norms, 1e-300))


@dataclasses.dataclass(frozen=True)
class StepCheck:
    step: float
    predicted: float      # -step |g| (first order)
    measured: float       # loss(z - step g/|g|) - loss(z)

    @property
    def ratio(self) -> float:
        """measured / predicted: 1 when the first order holds, < 0 when the loss rose."""
        return self.measured / self.predicted if self.predicted else float("nan")


def step_check(loss: Callable[[np.ndarray], float], z, grad, steps) -> list[StepCheck]:
    """Predicted against measured change of `loss` along the unit direction -grad/|grad| for
    each step size (parameter units). loss(z) is evaluated once, then once per step."""
    z, g = np.asarray(z, float), np.asarray(grad, float)
    norm = np.linalg.norm(g)
    if norm == 0:
        raise ValueError("step_check: zero gradient")
    base = float(loss(z))
    return [StepCheck(float(s), -float(s) * norm, float(loss(z - s * g / norm)) - base)
            for s in steps]


def summary(grads, k: int = 5) -> dict:
    """The diagnostics of one set of per-push gradients, as a JSON-ready dict (the mean's norm,
    half-batch cosine, top-k share, norm quantiles), also after the per-push clip at the
    median norm."""
    g = _rows(grads)
    med = float(np.median(np.linalg.norm(g, axis=1)))
    clipped = clip_rows(g, med) if med > 0 else g
    return dict(n=int(g.shape[0]), mean_norm=float(np.linalg.norm(g.mean(0))),
                half_cosine=half_batch_cosine(g), top_share=top_k_share(g, k), top_k=k,
                norm_quantiles=norm_quantiles(g), half_cosine_clipped=half_batch_cosine(clipped),
                top_share_clipped=top_k_share(clipped, k))
