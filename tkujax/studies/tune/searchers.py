"""The tuning methods, one searcher object each, behind one ask/tell protocol.

A searcher holds ONE seed's search state. Each iteration the driver (`search.drive`, for one
seed or for seeds side by side) does:

    at = searcher.gradient_at()        # latent (k,) whose first-order gradient it wants, or None
    points = searcher.ask(group_grads) # (P, k) latents whose HARD loss it wants; group_grads is
                                       # the (groups, k) gradient samples at `at` (None if none)
    searcher.tell(points, losses)      # their hard losses (P,)

A zeroth-order searcher never asks for a gradient (`uses_gradient = False`).
`population_width(cfg)` is the number of points each ask returns, or None for one point
evaluated by the plain forward call (the (1+1)-ES, the gradient method's iterate).
`progress()` is the searcher's part of the progress line, `extra()` what it adds to the run
record. `SEARCHERS` maps the method name to its class, built as cls(z0, loss0, cfg, seed).

  cma       CMA-ES (the `cmaes` library): a population of `popsize` candidates per generation,
            all evaluated in one batched call on the hard loss. Accepts injected candidates
            (`inject`): they replace the last samples of the next generation and are told to
            `cmaes` like its own samples.
  sepcma    separable CMA-ES (`cmaes.SepCMA`, Ros and Hansen 2008): a diagonal covariance,
            O(n) per sample instead of O(n^2), and a faster learning rate of the variances in
            high dimension (the dimension study uses it from `study.sep_cma_from` parameters).
  gradient  Adam on the first-order gradient of the soft-gate loss at a FIXED small gate
            temperature (no annealing schedule that could undo progress); the iterate kept is
            the one with the best hard loss (one hard forward per step). With push_clip > 0
            each push's gradient is clipped to push_clip x the batch's median per-push norm
            before the mean: per-push gradients through contact are heavy-tailed (a few
            chaotic rollouts carry most of the squared norm, docs/tuning.md), and the clipped
            mean trades a bias for far less variance.
  hybrid    the alpha-order gradient of Suh, Simchowitz, Zhang and Tedrake (ICML 2022): the
            first-order gradient (soft gate, per group of pushes, giving its variance) mixed
            with a zeroth-order smoothing gradient of the hard loss (antithetic pairs):
            alpha = var_ZO / (var_FO + var_ZO), and alpha = 0 when
            the two disagree by more than 2 standard errors (the first-order gradient is then
            biased by a contact or gate discontinuity). Adam on the mix.
  linesearch  the clipped first-order gradient as a DIRECTION only, its step length measured
            on the hard loss along a ray, against the incumbent on the same pushes
            (`LineSearcher`). The dimension study's answer to the gradient's climb
            (results/tune_dimension): on this rough loss the step is measured, not trusted.
  es        the (1+1)-ES with the 1/5 success rule on the hard loss (the simple baseline).
  guided_sepcma, guided_cma  sep-CMA-ES / CMA-ES whose generations also try m - sigma sqrt(k)
            a g/|g| along the gradient g at the mean, one per step multiplier a (`guided_steps`),
            in place of the last samples (`GuidedCMASearcher`).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import ClassVar, Protocol

import jax
import jax.numpy as jnp
import numpy as np
import optax

BIG_LOSS = 1e6      # the loss a non-finite candidate gets (never selected, keeps CMA-ES sane)

@dataclasses.dataclass(frozen=True)
class SearchConfig:
    budget_s: float = 60.0            # wall clock per method and seed, compile excluded
    max_iterations: int = 10_000
    popsize: int = 9                  # CMA-ES population; hybrid uses (popsize - 1) / 2 pairs
    sigma0: float = 0.5               # CMA-ES / ES initial step (latent units)
    zo_sigma: float = 0.3             # smoothing radius of the zeroth-order gradient (latent)
    groups: int = 4                   # push groups of the first-order gradient
    learning_rate: float = 0.1
    clip_norm: float = 1.0
    temperature_deg: float = 0.5      # soft gate of first-order gradients
    push_clip: float = 0.0            # > 0: clip each push's gradient at push_clip x median
    ray_radius: float = 2.0           # linesearch: the longest step of the first ray (latent)
    ray_ratio: float = 0.5            # linesearch: each radius of a ray over the previous one
    guided_steps: tuple[float, ...] = (0.5, 1.0, 2.0)   # guided_*: step multipliers along -g

    @property
    def pairs(self) -> int:
        """The hybrid's antithetic pairs per iteration."""
        return max((self.popsize - 1) // 2, 1)


def cma_step_size(opt) -> float:
    """The step size sigma of a `cmaes` optimiser, which has no public accessor for it."""
    return float(opt._sigma)


def finite_loss(x) -> float:
    """x as a float, BIG_LOSS where it is not finite."""
    x = float(x)
    return x if math.isfinite(x) else BIG_LOSS


class Searcher(Protocol):
    """One seed's search (see the module's docstring)."""

    uses_gradient: ClassVar[bool]
    counter: ClassVar[str]              # "gen" or "it" in the progress line
    progress_label: ClassVar[str | None]  # None: no progress line
    progress_join: ClassVar[str]

    def __init__(self, z0: np.ndarray, loss0: float, cfg: SearchConfig, seed: int): ...

    @staticmethod
    def population_width(cfg: SearchConfig) -> int | None: ...

    def gradient_at(self) -> np.ndarray | None: ...

    def ask(self, group_grads: np.ndarray | None) -> np.ndarray: ...

    def tell(self, points: np.ndarray, losses: np.ndarray) -> None: ...

    def progress(self) -> str: ...

    def extra(self) -> dict: ...


class _ZerothOrder:
    """What every searcher without a gradient shares."""

    uses_gradient: ClassVar[bool] = False
    counter: ClassVar[str] = "it"
    progress_label: ClassVar[str | None] = None
    progress_join: ClassVar[str] = " "

    def gradient_at(self) -> np.ndarray | None:
        return None

    def progress(self) -> str:
        return ""

    def extra(self) -> dict:
        return {}


class CMASearcher(_ZerothOrder):
    """CMA-ES through `cmaes.CMA`, seeded with the run's seed."""

    counter = "gen"
    progress_label = "sigma "

    def __init__(self, z0, loss0: float, cfg: SearchConfig, seed: int):
        self.popsize = cfg.popsize
        self.opt = self._strategy()(mean=np.asarray(z0, float).copy(), sigma=cfg.sigma0,
                                    population_size=cfg.popsize, seed=seed)
        self.injected: list[np.ndarray] = []

    @staticmethod
    def _strategy():
        from cmaes import CMA

        return CMA

    @staticmethod
    def population_width(cfg: SearchConfig) -> int | None:
        return cfg.popsize

    def inject(self, points) -> None:
        """External candidates (e.g. gradient steps) for the next generation, at most popsize;
        they take the place of the generation's last samples."""
        points = [np.asarray(z, float) for z in points]
        if len(self.injected) + len(points) > self.popsize:
            raise ValueError(f"at most {self.popsize} injected candidates per generation")
        self.injected += points

    def ask(self, group_grads=None) -> np.ndarray:
        own = [self.opt.ask() for _ in range(self.popsize - len(self.injected))]
        points, self.injected = np.stack(own + self.injected), []
        return points

    def tell(self, points, losses) -> None:
        self.opt.tell([(z, finite_loss(v)) for z, v in zip(points, losses)])

    def progress(self) -> str:
        return f"{cma_step_size(self.opt):.3f}"


class SepCMASearcher(CMASearcher):
    """Separable CMA-ES through `cmaes.SepCMA`."""

    @staticmethod
    def _strategy():
        from cmaes import SepCMA

        return SepCMA


def one_plus_one_step(z, best: float, sigma: float, cand, loss: float):
    """The (1+1)-ES with the 1/5 success rule: (z, best, sigma) after trying cand."""
    if loss < best:
        return cand, loss, sigma * 1.5
    return z, best, sigma * 1.5 ** -0.25


class OnePlusOneSearcher(_ZerothOrder):
    """The (1+1)-ES: one candidate z + sigma N(0, I) (jax.random, keyed by the seed) per
    iteration, evaluated by the forward call."""

    def __init__(self, z0, loss0: float, cfg: SearchConfig, seed: int):
        self.rng = jax.random.PRNGKey(seed)
        self.z, self.best, self.sigma = np.asarray(z0, float).copy(), finite_loss(loss0), \
            cfg.sigma0

    @staticmethod
    def population_width(cfg: SearchConfig) -> int | None:
        return None

    def ask(self, group_grads=None) -> np.ndarray:
        self.rng, sub = jax.random.split(self.rng)
        cand = self.z + self.sigma * np.asarray(jax.random.normal(sub, self.z.shape), float)
        return cand[None]

    def tell(self, points, losses) -> None:
        self.z, self.best, self.sigma = one_plus_one_step(
            self.z, self.best, self.sigma, points[0], finite_loss(losses[0]))


@functools.cache
def adam_step(learning_rate: float, clip_norm: float):
    """(optimizer, jitted apply(z, state, g) -> (z, state)): Adam after a global-norm clip,
    one compiled step shared by every searcher of the same settings."""
    optimizer = optax.chain(optax.clip_by_global_norm(clip_norm), optax.adam(learning_rate))
    return optimizer, jax.jit(functools.partial(adam_update, optimizer))


def adam_update(optimizer, z, state, g):
    """One optax update: (z, state) after the gradient g."""
    updates, state = optimizer.update(g, state, z)
    return optax.apply_updates(z, updates), state


class GradientSearcher:
    """Adam on the first-order gradient; its iterate's hard loss by the forward call."""

    uses_gradient: ClassVar[bool] = True
    counter: ClassVar[str] = "it"
    progress_label: ClassVar[str | None] = "alpha "
    progress_join: ClassVar[str] = " "

    def __init__(self, z0, loss0: float, cfg: SearchConfig, seed: int):
        self.cfg = cfg
        self.optimizer, self._apply = adam_step(cfg.learning_rate, cfg.clip_norm)
        self.z = jnp.asarray(np.asarray(z0, float))
        self.state = self.optimizer.init(self.z)
        self.alphas: list[float] = []
        self.iterate_losses: list[float] = []     # the hard loss of each Adam iterate
        self.grads = None

    @staticmethod
    def population_width(cfg: SearchConfig) -> int | None:
        return None

    def gradient_at(self) -> np.ndarray:
        return np.asarray(self.z, float)

    def ask(self, group_grads) -> np.ndarray:
        self.grads = np.asarray(group_grads)
        return np.asarray(self.z, float)[None]

    def tell(self, points, losses) -> None:
        hard = finite_loss(losses[0])
        self.iterate_losses.append(hard)
        self._step(self.grads.mean(0), 1.0)

    def _step(self, g, alpha: float) -> None:
        self.alphas.append(alpha)
        if np.all(np.isfinite(g)):
            self.z, self.state = self._apply(self.z, self.state, jnp.asarray(g, self.z.dtype))

    def progress(self) -> str:
        return f"{self.alphas[-1]:.2f}"

    def extra(self) -> dict:
        return dict(alpha=self.alphas, iterate_loss=self.iterate_losses)


class HybridSearcher(GradientSearcher):
    """Adam on Suh et al.'s alpha-order mix of the first-order gradient and a zeroth-order
    one from antithetic pairs (a numpy generator seeded with the seed)."""

    def __init__(self, z0, loss0: float, cfg: SearchConfig, seed: int):
        super().__init__(z0, loss0, cfg, seed)
        self.rng = np.random.default_rng(seed)
        self.eps = None

    @staticmethod
    def population_width(cfg: SearchConfig) -> int | None:
        return 1 + 2 * cfg.pairs

    def ask(self, group_grads) -> np.ndarray:
        self.grads = np.asarray(group_grads)
        zc = np.asarray(self.z, float)
        self.eps = self.rng.standard_normal((self.cfg.pairs, zc.size))
        return np.concatenate([zc[None], zc + self.cfg.zo_sigma * self.eps,
                               zc - self.cfg.zo_sigma * self.eps])

    def tell(self, points, losses) -> None:
        losses = np.array([finite_loss(v) for v in losses])
        pairs = self.cfg.pairs
        self.iterate_losses.append(float(losses[0]))
        self._step(*alpha_order_mix(self.grads.mean(0), self.grads, losses[1:pairs + 1],
                                    losses[pairs + 1:], self.eps, self.cfg.zo_sigma))


def alpha_order_mix(g_fo: np.ndarray, group_grads: np.ndarray, loss_plus: np.ndarray,
                    loss_minus: np.ndarray, eps: np.ndarray, sigma: float):
    """Suh et al.'s alpha-order gradient: (g, alpha).

    g_fo: first-order batch gradient; group_grads (G, k): its per-group samples. loss_plus /
    loss_minus (N,): hard losses at z +- sigma eps_i; eps (N, k) standard normal."""
    g_fo = np.asarray(g_fo, float)
    samples = ((loss_plus - loss_minus) / (2.0 * sigma))[:, None] * eps        # (N, k)
    g_zo = samples.mean(0)
    var_zo = float(np.sum(samples.var(0, ddof=1)) / len(samples)) if len(samples) > 1 else math.inf
    G = len(group_grads)
    var_fo = float(np.sum(group_grads.var(0, ddof=1)) / G) if G > 1 else 0.0
    if not np.all(np.isfinite(g_fo)) or not math.isfinite(var_fo):
        return g_zo, 0.0
    if not math.isfinite(var_zo):
        return g_fo, 1.0
    # Bias check: a first-order gradient further from the (unbiased, smoothed) zeroth-order one
    # than their combined standard error allows is not trusted.
    if np.linalg.norm(g_fo - g_zo) > 2.0 * math.sqrt(var_fo + var_zo):
        return g_zo, 0.0
    alpha = var_zo / (var_fo + var_zo) if var_fo + var_zo > 0 else 1.0
    return alpha * g_fo + (1.0 - alpha) * g_zo, float(alpha)


class LineSearcher:
    """The linesearch method: the incumbent (best hard loss so far), the directions of its
    last gradient (the batch mean, then each push group's) and the ray's length.

    Each iteration evaluates popsize - 1 points z - r_j d/|d| with r_j = radius ray_ratio^j,
    and the incumbent z itself (last): the best point replaces the incumbent only if its hard
    loss is lower than the incumbent's on the same pushes, so the comparison stays paired when
    every iteration draws a fresh batch (study.fresh_batches). After a move the next ray
    starts at 4 r* (capped at 4 ray_radius) and a new gradient is needed; after a failed ray
    the next direction is tried: the push groups' gradients, then random directions (the
    point is the same, so the gradient would be too)."""

    uses_gradient: ClassVar[bool] = True
    counter: ClassVar[str] = "it"
    progress_label: ClassVar[str | None] = ""
    progress_join: ClassVar[str] = "; "

    def __init__(self, z0, loss0: float, cfg: SearchConfig, seed: int):
        self.z, self.loss = np.asarray(z0, float), finite_loss(loss0)
        self.cfg, self.rng = cfg, np.random.default_rng(seed)
        self.radius = cfg.ray_radius
        self.directions: list[np.ndarray] = []
        self.index = 0
        self.needs_gradient = True
        self.moves, self.radii_taken, self.kinds = 0, [], []

    @staticmethod
    def population_width(cfg: SearchConfig) -> int | None:
        return cfg.popsize

    def gradient_at(self) -> np.ndarray | None:
        return self.z if self.needs_gradient else None

    def ask(self, group_grads) -> np.ndarray:
        """(popsize, k) points along the ray from the incumbent."""
        if group_grads is not None:
            g = np.asarray(group_grads, float)
            self.directions = [g.mean(0)] + list(g)
            self.index, self.needs_gradient = 0, False
        d, self._kind = self._direction()
        d = d / np.linalg.norm(d)
        self._radii = self.radius * self.cfg.ray_ratio ** np.arange(self.cfg.popsize - 1)
        return np.concatenate([self.z[None] - self._radii[:, None] * d[None], self.z[None]])

    def _direction(self) -> tuple[np.ndarray, str]:
        if self.index < len(self.directions):
            d = self.directions[self.index]
            kind = "mean" if self.index == 0 else f"group{self.index - 1}"
            if np.all(np.isfinite(d)) and np.linalg.norm(d) > 0:
                return d, kind
        return self.rng.standard_normal(self.z.shape), "random"

    def tell(self, points, losses) -> None:
        losses = np.array([finite_loss(v) for v in losses])
        self.loss = float(losses[-1])               # the incumbent, on this iteration's pushes
        j = int(np.argmin(losses[:-1]))
        self.kinds.append(self._kind)
        if losses[j] < self.loss:
            self.z, self.loss = np.asarray(points[j], float), float(losses[j])
            self.radius = min(4.0 * self._radii[j], 4.0 * self.cfg.ray_radius)
            self.needs_gradient = True
            self.moves += 1
            self.radii_taken.append(float(self._radii[j]))
        else:
            self.index += 1
            self.radii_taken.append(0.0)

    def progress(self) -> str:
        r = self.radii_taken[-1] if self.radii_taken else 0.0
        return f"{self._kind} step {r:.3g}" if r else f"{self._kind} no step"

    def extra(self) -> dict:
        return dict(moves=self.moves, step_radius=self.radii_taken, direction=self.kinds)


class GuidedCMASearcher(CMASearcher):
    """CMA-ES with gradient candidates injected (Hansen 2011, "Injecting external solutions
    into CMA-ES"): each generation asks for the first-order gradient g (the push groups' mean)
    at the mean m and injects m - sigma sqrt(k) a g/|g| for each a in cfg.guided_steps (sigma
    sqrt(k): a typical sample's length) in place of the generation's last samples; nothing
    when g is not finite or zero (the generation is then plain CMA-ES). Injection, not Guided
    ES's sampling in the subspace of recent gradients (Maheswaranathan et al. 2019): it leaves
    CMA-ES's own samples, ranking and adaptation as they are, so a biased gradient (contacts,
    the gate) costs only the injected slots and a useful one is taken up by the ranking,
    where a subspace sampler would bend every sample toward a gradient that is often wrong
    here. As Hansen prescribes, an injected point is evaluated where it is but told to CMA-ES
    with its step (x - m)/sigma shortened to the Mahalanobis length sqrt(k) + 2k/(k + 2), so
    a long step (a = 2) cannot derail the adaptation. extra(): per generation the rank (0:
    best) of the best injected candidate, None when nothing was injected."""

    uses_gradient: ClassVar[bool] = True

    def __init__(self, z0, loss0: float, cfg: SearchConfig, seed: int):
        super().__init__(z0, loss0, cfg, seed)
        if not 0 < len(cfg.guided_steps) < cfg.popsize:
            raise ValueError(f"guided_steps: 1..{cfg.popsize - 1} multipliers, "
                             f"got {cfg.guided_steps!r}")
        self.steps = tuple(float(a) for a in cfg.guided_steps)
        self.n_injected = 0
        self.injected_rank: list[int | None] = []

    def gradient_at(self) -> np.ndarray:
        return np.asarray(self.opt.mean, float).copy()

    def gradient_points(self, g) -> list[np.ndarray]:
        """The candidates along -g from the mean ([] for a non-finite or zero g)."""
        g = np.asarray(g, float)
        norm = float(np.linalg.norm(g)) if np.all(np.isfinite(g)) else 0.0
        if not norm > 0:
            return []
        m, sigma = np.asarray(self.opt.mean, float), cma_step_size(self.opt)
        u = g / norm * sigma * math.sqrt(g.size)
        return [m - a * u for a in self.steps]

    def ask(self, group_grads=None) -> np.ndarray:
        points = [] if group_grads is None else self.gradient_points(
            np.asarray(group_grads, float).mean(0))
        self.inject(points)
        self.n_injected = len(points)
        return super().ask()

    def mahalanobis(self, y: np.ndarray) -> float:
        """|C^-1/2 y| under the strategy's covariance (diagonal for sep-CMA)."""
        c = np.asarray(self.opt._C, float)
        return float(math.sqrt(y @ (y / c if c.ndim == 1 else np.linalg.solve(c, y))))

    def tell(self, points, losses) -> None:
        points, k = np.array(points, float), len(points[0])
        cap = math.sqrt(k) + 2.0 * k / (k + 2.0)
        m, sigma = np.asarray(self.opt.mean, float), cma_step_size(self.opt)
        first = len(points) - self.n_injected
        for i in range(first, len(points)):
            y = (points[i] - m) / sigma
            if self.mahalanobis(y) > cap:
                points[i] = m + sigma * y * (cap / self.mahalanobis(y))
        order = np.argsort([finite_loss(v) for v in losses], kind="stable")
        self.injected_rank.append(int(np.argmax(order >= first)) if self.n_injected else None)
        super().tell(points, losses)

    def extra(self) -> dict:
        return dict(injected_rank=self.injected_rank, guided_steps=list(self.steps))


class GuidedSepCMASearcher(GuidedCMASearcher):
    """GuidedCMASearcher on separable CMA-ES (`cmaes.SepCMA`)."""

    @staticmethod
    def _strategy():
        from cmaes import SepCMA

        return SepCMA


SEARCHERS: dict[str, type] = {
    "cma": CMASearcher,
    "sepcma": SepCMASearcher,
    "gradient": GradientSearcher,
    "hybrid": HybridSearcher,
    "linesearch": LineSearcher,
    "es": OnePlusOneSearcher,
    "guided_sepcma": GuidedSepCMASearcher,
    "guided_cma": GuidedCMASearcher,
}
METHODS = tuple(SEARCHERS)


def searcher_class(method: str) -> type:
    """The registered searcher of `method` (ValueError naming the methods otherwise)."""
    if method not in SEARCHERS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    return SEARCHERS[method]
