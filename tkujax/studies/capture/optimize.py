"""Gradient-optimal step: each push's step target (x, y) by gradient ascent on the capture
margin (tkujax.sim.metrics.capture_outcomes: minus the RMS inclination deviation after onset)
through MJX, with optax. Compared with the grid's best cell and the LIP capture point.

The margin is smooth in the target wherever no contact changes (the swing foot's touchdown
moves with the target, so it is piecewise smooth); falls flatten it, which is why the
optimisation starts from a point that recovers when there is one.
"""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax

from tkujax.control.controller import StepOverride
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim.metrics import capture_outcomes, outcomes
from tkujax.sim.push import Push
from tkujax.sim.rollout_mjx import Episode, ProgramOptions, RolloutConfig, rollout
from tkujax.sim.setup import init
from tkujax.studies.tune.reparam import CPU_COMPILER_OPTIONS


@dataclasses.dataclass
class MarginProblem:
    """margin(targets (B, 2), pushes, timing (B, 3)) -> per-push margins, and its gradient.

    timing columns: start_delay_s, from_detection, period_s (StepOverride). float64 puts the
    MJX model and state in float64 and runs under jax.enable_x64 (for derivative checks)."""

    params: ControllerParams
    duration_s: float = 2.0
    float64: bool = False
    quantise: bool = True
    model_params: ModelParams | None = None

    def __post_init__(self):
        _, self.model, self.index, self.state = init(self.model_params, float64=self.float64)
        self.config = RolloutConfig(duration_s=self.duration_s, quantise_targets=self.quantise,
                                    program=ProgramOptions(remat=True))
        self.dtype = jnp.float64 if self.float64 else jnp.float32
        opts = CPU_COMPILER_OPTIONS if jax.default_backend() == "cpu" else None
        self._vg = jax.jit(jax.vmap(jax.value_and_grad(self._one, has_aux=True)),
                           compiler_options=opts)
        self._fwd = jax.jit(jax.vmap(self._one), compiler_options=opts)

    def _ctx(self):
        return jax.enable_x64(True) if self.float64 else contextlib.nullcontext()

    def _one(self, target, push: Push, timing):
        ov = StepOverride(active=jnp.ones((), self.dtype), x_m=target[0], y_m=target[1],
                          start_delay_s=timing[0], from_detection=timing[1], period_s=timing[2],
                          onset_s=push.onset_s)
        series = rollout(self.model, self.state, Episode(push, jnp.ones((), self.dtype),
                         jax.random.PRNGKey(0), 0.0, 0.0), self.params, self.config, self.index, ov)
        cap = capture_outcomes(series, push.onset_s, self.params.gravity)
        return cap["margin_deg"], outcomes(series, push.onset_s).fell

    def _cast(self, targets, pushes, timing):
        c = lambda x: jnp.asarray(x, self.dtype)  # noqa: E731
        return c(targets), jax.tree_util.tree_map(c, pushes), c(timing)

    def value_and_grad(self, targets, pushes: Push, timing):
        """(margins (B,), fell (B,), d margin / d target (B, 2)) as numpy."""
        with self._ctx():
            (m, fell), g = self._vg(*self._cast(targets, pushes, timing))
            return np.asarray(m, np.float64), np.asarray(fell), np.asarray(g, np.float64)

    def margin(self, targets, pushes: Push, timing):
        with self._ctx():
            m, fell = self._fwd(*self._cast(targets, pushes, timing))
            return np.asarray(m, np.float64), np.asarray(fell)


def optimise_steps(problem: MarginProblem, start: np.ndarray, pushes: Push, timing: np.ndarray,
                   iterations: int = 20, learning_rate: float = 0.01,
                   max_target_m: float = 0.15) -> dict:
    """Adam ascent on the margin from `start` (B, 2); targets kept in the grid's box. Returns
    the history and the best iterate per push (by margin, preferring ones that recover)."""
    opt = optax.adam(learning_rate)
    x = np.asarray(start, np.float64)
    state = opt.init(jnp.asarray(x))
    hist = []
    best_x, best_m = x.copy(), np.full(len(x), -np.inf)
    best_fell = np.ones(len(x), bool)
    for _ in range(iterations + 1):
        m, fell, g = problem.value_and_grad(x, pushes, timing)
        hist.append(dict(targets=x.tolist(), margin_deg=m.tolist(), fell=fell.tolist()))
        # Best: recovers beats falls, then the larger margin.
        better = (~fell & best_fell) | ((~fell == ~best_fell) & (m > best_m))
        best_x[better], best_m[better], best_fell[better] = x[better], m[better], fell[better]
        g = np.nan_to_num(g)
        upd, state = opt.update(jnp.asarray(-g), state)     # ascent: minimise -margin
        x = np.clip(x + np.asarray(upd, np.float64), -max_target_m, max_target_m)
    return dict(history=hist, best=best_x, best_margin_deg=best_m, best_fell=best_fell)
