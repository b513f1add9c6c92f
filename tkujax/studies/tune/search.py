"""Searches over the tuning latents under one wall-clock budget, for an honest comparison.

Every method starts from the same latent z0 (the paper's values), sees the same training
batch, and gets the same wall-clock budget with compilation excluded (each method's compiled
functions are called once before the clock starts; that time is reported as compile_s). Each
records the same convergence curve: the best HARD-gate training loss found so far (the loss
that evaluation uses) against wall time and pushes simulated, and returns the best latent.

  cma       CMA-ES (the `cmaes` library): a population of `popsize` candidates per generation,
            all evaluated in one batched call on the hard loss.
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
            with a zeroth-order randomised-smoothing gradient of the hard loss (antithetic
            pairs, giving its variance): alpha = var_ZO / (var_FO + var_ZO), and alpha = 0 when
            the two disagree by more than 2 standard errors (the first-order gradient is then
            biased by a contact or gate discontinuity). Adam on the mix.
  linesearch  the clipped first-order gradient as a DIRECTION only, its step length chosen
            on the hard loss: one batched call evaluates `popsize` points along the ray
            (radii ray_radius, ray_radius/2, ...), and the best is taken only if it lowers the
            hard loss (else the next direction: a push group's own gradient, then a random
            one). A gradient is computed only after a move. The dimension study's answer to
            the gradient's climb (results/tune_dimension): on this rough loss a local
            gradient predicts the loss a step away poorly, so the step is measured, not
            trusted.
  es        the (1+1)-ES with the 1/5 success rule on the hard loss (the simple baseline).

Pushes simulated count a value-and-gradient rollout as one push.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import math
import time
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax

from tkujax.studies.tune.problem import TuneProblem
from tkujax.studies.tune.reparam import DEG

METHODS = ("cma", "sepcma", "gradient", "hybrid", "linesearch", "es")
_BIG = 1e6          # the loss a non-finite candidate gets (never selected, keeps CMA-ES sane)


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


def _finite(x) -> float:
    x = float(x)
    return x if math.isfinite(x) else _BIG


class _Tracker:
    """Best-so-far hard loss, and the convergence curve."""

    def __init__(self, z0, loss0: float, pushes_per_eval: int):
        self.z, self.loss = np.asarray(z0, float), _finite(loss0)
        self.t0 = time.perf_counter()
        self.pushes = pushes_per_eval
        self.curve = [dict(wall_s=0.0, pushes=pushes_per_eval, best_loss=self.loss)]

    def offer(self, z, loss: float) -> None:
        loss = _finite(loss)
        if loss < self.loss:
            self.z, self.loss = np.asarray(z, float), loss

    def tick(self, pushes: int) -> None:
        self.pushes += pushes
        self.curve.append(dict(wall_s=round(self.elapsed(), 3), pushes=self.pushes,
                               best_loss=self.loss))

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0


def run_search(method: str, problem: TuneProblem, z0, batch: dict, keys, cfg: SearchConfig,
               seed: int, log: Callable[[str], None] | None = None) -> dict:
    """Run one method within cfg.budget_s. Returns dict(method, seed, z_best, best_loss,
    compile_s, iterations, curve, extra)."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    n = len(keys)
    tau = cfg.temperature_deg * DEG
    z0 = np.asarray(z0, float)
    pairs = max((cfg.popsize - 1) // 2, 1)

    # Compile (excluded from the budget): call what this method uses once. The control-off
    # column of the harm weight (w_harm > 0) is computed here, once for the whole search
    # (`problem` may be any object with the four methods used below: the tests' landscapes).
    t0 = time.perf_counter()
    if hasattr(problem, "with_off_survived"):
        batch = problem.with_off_survived(batch, keys)
    hard0 = warm_up_calls(method, problem, z0, batch, keys, cfg)["forward"]
    compile_s = time.perf_counter() - t0

    track = _Tracker(z0, hard0, n)
    extra: dict = {}
    it = 0
    if method in ("cma", "sepcma"):
        from cmaes import CMA, SepCMA

        opt = (CMA if method == "cma" else SepCMA)(mean=z0.copy(), sigma=cfg.sigma0,
                                                   population_size=cfg.popsize, seed=seed)
        while it < cfg.max_iterations and track.elapsed() < cfg.budget_s:
            zs = np.stack([opt.ask() for _ in range(cfg.popsize)])
            tell_generation(opt, track, zs, problem.population(zs, 0.0, batch, keys),
                            cfg.popsize * n)
            it += 1
            if log:
                log(f"{method}  gen {it:3d}  best {track.loss:.4f}  sigma {opt._sigma:.3f}  "
                    f"{track.elapsed():.0f}/{cfg.budget_s:g} s")
    elif method == "linesearch":
        ray = RaySearch(z0, hard0, cfg, seed)
        while it < cfg.max_iterations and track.elapsed() < cfg.budget_s:
            pushes = 0
            if ray.needs_gradient:
                ray.set_directions(first_order_grads(problem.grouped_value_and_grad, ray.z, tau,
                                                     batch, keys, cfg, n))
                pushes += n
            zs = ray.candidates()
            losses = problem.population(zs, 0.0, batch, keys)
            ray.tell(zs, losses)
            for zz, v in zip(zs, losses):
                track.offer(zz, v)
            track.tick(pushes + len(zs) * n)
            it += 1
            if log:
                log(f"{method}  it {it:3d}  best {track.loss:.4f}  {ray.describe()}  "
                    f"{track.elapsed():.0f}/{cfg.budget_s:g} s")
        extra.update(ray.extra())
    elif method == "es":
        rng = jax.random.PRNGKey(seed)
        z, best, sigma = z0.copy(), _finite(hard0), cfg.sigma0
        while it < cfg.max_iterations and track.elapsed() < cfg.budget_s:
            rng, sub = jax.random.split(rng)
            cand = z + sigma * np.asarray(jax.random.normal(sub, z.shape), float)
            loss = _finite(problem.forward(cand, 0.0, batch, keys)[0])
            z, best, sigma = one_plus_one_step(z, best, sigma, cand, loss)
            track.offer(cand, loss)
            track.tick(n)
            it += 1
    else:   # gradient / hybrid: Adam on a (mixed) gradient
        optimizer = optax.chain(optax.clip_by_global_norm(cfg.clip_norm),
                                optax.adam(cfg.learning_rate))
        z = jnp.asarray(z0)
        state = optimizer.init(z)
        apply = jax.jit(lambda z, s, g: _adam(optimizer, z, s, g))
        key = np.random.default_rng(seed)
        alphas, iterate_losses = [], []
        while it < cfg.max_iterations and track.elapsed() < cfg.budget_s:
            zc = np.asarray(z, float)
            grads = first_order_grads(problem.grouped_value_and_grad, zc, tau, batch, keys,
                                      cfg, n)
            g_fo = grads.mean(0)
            pushes = n
            if method == "gradient":
                hard = _finite(problem.forward(zc, 0.0, batch, keys)[0])
                track.offer(zc, hard)
                iterate_losses.append(hard)
                g, alpha = g_fo, 1.0
                pushes += n
            else:
                eps = key.standard_normal((pairs, zc.size))
                zs = np.concatenate([zc[None], zc + cfg.zo_sigma * eps, zc - cfg.zo_sigma * eps])
                losses = np.array([_finite(v) for v in problem.population(zs, 0.0, batch, keys)])
                track.offer(zc, losses[0])
                iterate_losses.append(float(losses[0]))
                for zz, v in zip(zs[1:], losses[1:]):
                    track.offer(zz, v)
                g, alpha = alpha_order_mix(g_fo, grads, losses[1:pairs + 1],
                                           losses[pairs + 1:], eps, cfg.zo_sigma)
                pushes += len(zs) * n
            alphas.append(alpha)
            if np.all(np.isfinite(g)):
                z, state = apply(z, state, jnp.asarray(g, z.dtype))
            track.tick(pushes)
            it += 1
            if log:
                log(f"{method}  it {it:3d}  best {track.loss:.4f}  alpha {alpha:.2f}  "
                    f"{track.elapsed():.0f}/{cfg.budget_s:g} s")
        extra["alpha"] = alphas
        extra["iterate_loss"] = iterate_losses     # the hard loss of each Adam iterate
    return dict(method=method, seed=seed, z_best=track.z.tolist(), best_loss=track.loss,
                compile_s=round(compile_s, 2), iterations=it, curve=track.curve, extra=extra)


class RaySearch:
    """The linesearch method's state for one seed: the incumbent (best hard loss so far), the
    directions of its last gradient (the batch mean, then each push group's) and the ray's
    length.

    Each iteration evaluates `popsize` points z - r_j d/|d| with r_j = radius 2^-j; the best
    replaces the incumbent only if its hard loss is lower (the incumbent never gets worse on
    the training batch). After a move the next ray starts at 4 r* (capped at 4 ray_radius)
    and a new gradient is needed; after a failed ray the next direction is tried: the push
    groups' gradients, then random directions (the batch and point are the same, so the
    gradient would be too)."""

    def __init__(self, z0, loss0: float, cfg: SearchConfig, seed: int):
        self.z, self.loss = np.asarray(z0, float), _finite(loss0)
        self.cfg, self.rng = cfg, np.random.default_rng(seed)
        self.radius = cfg.ray_radius
        self.directions: list[np.ndarray] = []
        self.index = 0
        self.needs_gradient = True
        self.moves, self.radii_taken, self.kinds = 0, [], []

    def set_directions(self, group_grads: np.ndarray) -> None:
        g = np.asarray(group_grads, float)
        self.directions = [g.mean(0)] + list(g)
        self.index, self.needs_gradient = 0, False

    def _direction(self) -> tuple[np.ndarray, str]:
        if self.index < len(self.directions):
            d = self.directions[self.index]
            kind = "mean" if self.index == 0 else f"group{self.index - 1}"
            if np.all(np.isfinite(d)) and np.linalg.norm(d) > 0:
                return d, kind
        return self.rng.standard_normal(self.z.shape), "random"

    def candidates(self) -> np.ndarray:
        """(popsize, k) points along the ray from the incumbent."""
        d, self._kind = self._direction()
        d = d / np.linalg.norm(d)
        self._radii = self.radius * 0.5 ** np.arange(self.cfg.popsize)
        return self.z[None] - self._radii[:, None] * d[None]

    def tell(self, zs, losses) -> None:
        losses = np.array([_finite(v) for v in losses])
        j = int(np.argmin(losses))
        self.kinds.append(self._kind)
        if losses[j] < self.loss:
            self.z, self.loss = np.asarray(zs[j], float), float(losses[j])
            self.radius = min(4.0 * self._radii[j], 4.0 * self.cfg.ray_radius)
            self.needs_gradient = True
            self.moves += 1
            self.radii_taken.append(float(self._radii[j]))
        else:
            self.index += 1
            self.radii_taken.append(0.0)

    def describe(self) -> str:
        r = self.radii_taken[-1] if self.radii_taken else 0.0
        return f"{self._kind} step {r:.3g}" if r else f"{self._kind} no step"

    def extra(self) -> dict:
        return dict(moves=self.moves, step_radius=self.radii_taken, direction=self.kinds)


def tell_generation(opt, track: _Tracker, zs, losses, pushes: int) -> None:
    """One CMA-ES generation's losses: told to the optimiser (non-finite as _BIG), offered to
    the tracker, and the curve ticked by the pushes simulated."""
    opt.tell([(z, _finite(v)) for z, v in zip(zs, losses)])
    for z, v in zip(zs, losses):
        track.offer(z, v)
    track.tick(pushes)


def one_plus_one_step(z, best: float, sigma: float, cand, loss: float):
    """The (1+1)-ES with the 1/5 success rule: (z, best, sigma) after trying cand."""
    if loss < best:
        return cand, loss, sigma * 1.5
    return z, best, sigma * 1.5 ** -0.25


def clipped_group_means(per_push: np.ndarray, groups: int, clip: float) -> np.ndarray:
    """per_push (n, k) gradients -> (groups, k) group means after clipping each push's
    gradient to clip x the median per-push norm (non-finite pushes count as zero)."""
    g = np.where(np.isfinite(per_push), per_push, 0.0)
    norms = np.linalg.norm(g, axis=-1)
    cap = clip * np.median(norms)
    g = g * np.minimum(1.0, cap / np.maximum(norms, 1e-30))[..., None]
    n, k = g.shape
    return g.reshape(groups, n // groups, k).mean(1)


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
    """What `method` calls, each once, side by side (`warm_up`): the forward (its hard loss
    under "forward"), the population call of cfg.popsize (cma, sepcma, hybrid, linesearch) and
    the grouped first-order gradient (gradient, hybrid, linesearch). parallel=False: one after
    the other (scripts/bench_warmup_parallel.py compares the two)."""
    tau = cfg.temperature_deg * DEG
    z0 = np.asarray(z0, float)
    calls = {}
    if method in ("gradient", "hybrid", "linesearch"):
        calls["gradient"] = lambda: first_order_grads(problem.grouped_value_and_grad, z0, tau,
                                                      batch, keys, cfg, len(keys))
    if method in ("cma", "sepcma", "hybrid", "linesearch"):
        calls["population"] = lambda: problem.population(np.repeat(z0[None], cfg.popsize, 0),
                                                         0.0, batch, keys)
    calls["forward"] = lambda: problem.forward(z0, 0.0, batch, keys)[0]
    return warm_up(calls, parallel)


def first_order_grads(value_and_grad_groups, z, tau, batch, keys, cfg: SearchConfig,
                      n: int) -> np.ndarray:
    """(groups, k) first-order gradient samples: the groups' mean gradients, or with
    cfg.push_clip > 0 the clipped per-push gradients' group means (one call either way)."""
    if cfg.push_clip > 0:
        _, per_push = value_and_grad_groups(z, tau, batch, keys, n)
        return clipped_group_means(np.asarray(per_push), cfg.groups, cfg.push_clip)
    return np.asarray(value_and_grad_groups(z, tau, batch, keys, cfg.groups)[1])


def _adam(optimizer, z, state, g):
    updates, state = optimizer.update(g, state, z)
    return optax.apply_updates(z, updates), state


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
