"""Seeds side by side: `run_search` for S seeds of one method in lockstep, one compiled call per
step for all seeds.

At the dimension study's small batches (512 pushes x 1.5 s) one search leaves a GPU far from
saturated, so the S seeds of one (policy, method) share every compiled call: each iteration
makes ONE forward call over (S,) latents, ONE population call over (S, P) latents and ONE
grouped value-and-gradient call over (S,) latents x groups, each seed on its own training batch.

Everything else is `run_search`'s (tkujax.studies.tune.search), seed by seed: the same start
z0, each seed's own training batch and keys, its own CMA / sep-CMA object (seeded with its
seed), (1+1)-ES PRNG key, hybrid numpy generator and Adam state, the same compile-excluded clock
and `_Tracker` curve, and the same per-seed push counts. So a seed's iterates are those of
`run_search` for that seed, up to the float rounding of the batched program
(tests/test_tune_lockstep.py). What differs is the clock: the seeds share one wall-clock budget
(the loop stops when it is spent, every seed having done the same number of iterations), so
each seed gets a share of the device's throughput, not all of it.

The batched functions are built here from `problem.loss` (jax.vmap over a leading seed axis),
with the problem's own casting (`problem._args`), precision (`problem.float64`) and the same
default compiler options as TuneProblem; they are compiled once per problem, shape and
precision and kept on the problem object.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from tkujax.studies.tune.problem import _np, _x64
from tkujax.studies.tune.reparam import CPU_COMPILER_OPTIONS, DEG
from tkujax.studies.tune.search import (METHODS, RaySearch, SearchConfig, _adam, _finite,
                                        _Tracker, alpha_order_mix, clipped_group_means,
                                        one_plus_one_step, tell_generation, warm_up)


class LockstepFunctions:
    """The problem's loss batched over a leading seed axis (S): forward, population and grouped
    value-and-gradient, each one jitted call for all seeds. Latents, batches and keys carry the
    seed axis first; the temperature is shared."""

    def __init__(self, problem, compiler_options: dict | None = None):
        if compiler_options is None and jax.default_backend() == "cpu":
            compiler_options = CPU_COMPILER_OPTIONS        # as TuneProblem
        opts = compiler_options or None
        self.problem = problem
        loss = problem.loss

        def loss0(z, t, b, k):
            return loss(z, t, b, k)[0]

        seeds = (0, None, 0, 0)          # latents, temperature, batch, keys
        self._fwd = jax.jit(jax.vmap(loss, in_axes=seeds), compiler_options=opts)
        self._pop = jax.jit(jax.vmap(jax.vmap(loss0, in_axes=(0, None, None, None)),
                                     in_axes=seeds), compiler_options=opts)
        self._vg_groups = jax.jit(jax.vmap(jax.vmap(jax.value_and_grad(loss0),
                                                    in_axes=(None, None, 0, 0)),
                                           in_axes=seeds), compiler_options=opts)

    def forward(self, zs, temperature, batches: dict, keys):
        """zs (S, k), batches {column: (S, n)}, keys (S, n, ...) -> (losses (S,) numpy,
        aux with leading (S, n) axes, left on the device)."""
        p = self.problem
        with _x64(p.float64):
            loss, aux = self._fwd(*p._args(zs, temperature, batches, keys))
            return np.asarray(loss, np.float64), aux

    def population(self, zs, temperature, batches: dict, keys) -> np.ndarray:
        """zs (S, P, k): (S, P) mean losses, seed s's candidates on seed s's batch."""
        p = self.problem
        with _x64(p.float64):
            return np.asarray(self._pop(*p._args(zs, temperature, batches, keys)), np.float64)

    def grouped_value_and_grad(self, zs, temperature, batches: dict, keys, groups: int):
        """zs (S, k): (losses (S, G), grads (S, G, k)) over `groups` equal groups of each seed's
        batch (numpy)."""
        p = self.problem
        S, n = keys.shape[:2]
        if n % groups:
            raise ValueError(f"batch {n} must be a multiple of the gradient groups {groups}")
        with _x64(p.float64):
            z, t, b, k = p._args(zs, temperature, batches, keys)
            split = lambda x: x.reshape((S, groups, n // groups) + x.shape[2:])  # noqa: E731
            loss, g = self._vg_groups(z, t, {c: split(v) for c, v in b.items()}, split(k))
            return np.asarray(loss, np.float64), np.asarray(g, np.float64)

    def forward_padded(self, zs, temperature, records: Sequence[dict], keys: Sequence,
                       batch: int) -> list[dict]:
        """Seed s's latent zs[s] over its own records[s] (the same count for every seed) in
        chunks of `batch`: one compiled shape, (S, batch), the search's forward shape when
        `batch` is the training batch. Returns the per-push aux of each seed, numpy."""
        S = len(records)
        n = len(records[0]["impulse_ns"])
        if any(len(r["impulse_ns"]) != n for r in records):
            raise ValueError("every seed needs the same number of records")
        cols = [c for c in records[0] if np.ndim(records[0][c]) >= 1]
        parts = []
        for lo in range(0, n, batch):
            sel = np.resize(np.arange(lo, min(lo + batch, n)), batch)
            chunk = {c: np.stack([np.asarray(r[c])[sel] for r in records]) for c in cols}
            kk = jnp.stack([jnp.asarray(k)[sel] for k in keys])
            _, aux = self.forward(zs, temperature, chunk, kk)
            m = min(batch, n - lo)
            parts.append(_np(jax.tree_util.tree_map(lambda x, m=m: x[:, :m], aux)))
        whole = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, axis=1), *parts)
        return [jax.tree_util.tree_map(lambda x, s=s: x[s], whole) for s in range(S)]


def lockstep_functions(problem, compiler_options: dict | None = None) -> LockstepFunctions:
    """The problem's LockstepFunctions, made once per problem and compiler options (kept on
    the problem, so a study's methods share the compiled calls, as run_search's do)."""
    cache = vars(problem).setdefault("_lockstep_functions", {})
    key = None if compiler_options is None else tuple(sorted(compiler_options.items()))
    if key not in cache:
        cache[key] = LockstepFunctions(problem, compiler_options)
    return cache[key]


def fell_rates_lockstep(problem, latents: dict, records: Sequence[dict], keys: Sequence,
                        batch: int, compiler_options: dict | None = None) -> dict:
    """{name: [per seed (n,) fell as float, NaN where the rollout diverged]}: as
    compare._fell_rates, seed s's latent latents[name][s] on its own records[s], all seeds in
    one call per chunk."""
    fns = lockstep_functions(problem, compiler_options)
    out = {}
    for name, zs in latents.items():
        per_seed = []
        for aux in fns.forward_padded(np.asarray(zs, float), 0.0, records, keys, batch):
            fell = np.asarray(aux["outcomes"]["fell"], float)
            diverged = aux["outcomes"].get("diverged")
            if diverged is not None:
                fell = np.where(np.asarray(diverged, bool), np.nan, fell)
            per_seed.append(fell)
        out[name] = per_seed
    return out


def _stack_batches(batches, S: int) -> dict:
    """A list of S per-seed batch dicts, or one dict of (S, n) columns -> {column: (S, n)}."""
    if isinstance(batches, Mapping):
        out = {c: np.asarray(v) for c, v in batches.items()}
    else:
        batches = list(batches)
        if len(batches) != S:
            raise ValueError(f"{len(batches)} training batches for {S} seeds")
        out = {c: np.stack([np.asarray(b[c]) for b in batches]) for c in batches[0]}
    bad = [c for c, v in out.items() if v.ndim < 2 or v.shape[0] != S]
    if bad:
        raise ValueError(f"batch columns {bad} need a leading seed axis of {S}")
    return out


def _stack_keys(keys, S: int):
    keys = jnp.stack([jnp.asarray(k) for k in keys]) if isinstance(keys, (list, tuple)) \
        else jnp.asarray(keys)
    if keys.ndim < 2 or keys.shape[0] != S:
        raise ValueError(f"keys need shape (S={S}, n, ...), got {keys.shape}")
    return keys


def run_search_lockstep(method: str, problem, z0, batches, keys, cfg: SearchConfig,
                        seeds: Sequence[int], log: Callable[[str], None] | None = None, *,
                        compiler_options: dict | None = None) -> list[dict]:
    """Run one method for every seed in `seeds` side by side within ONE cfg.budget_s of wall
    clock (compile excluded). batches: S per-seed batch dicts or one dict of (S, n) columns;
    keys: (S, n, ...) (or S arrays). Returns one dict per seed, run_search's form: (method,
    seed, z_best, best_loss, compile_s, iterations, curve, extra)."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    seeds = [int(s) for s in seeds]
    S = len(seeds)
    if S == 0:
        raise ValueError("run_search_lockstep needs at least one seed")
    batch = _stack_batches(batches, S)
    keys = _stack_keys(keys, S)
    n = int(keys.shape[1])
    fns = lockstep_functions(problem, compiler_options)
    tau = cfg.temperature_deg * DEG
    z0 = np.asarray(z0, float)
    Z0 = np.repeat(z0[None], S, 0)
    pairs = max((cfg.popsize - 1) // 2, 1)

    # Compile (excluded from the budget): call what this method uses once, at the shapes the
    # loop uses (every seed's start loss comes from the forward call, as in run_search).
    # Side by side (search.warm_up): the compiles overlap, the longest (the gradient) first.
    t0 = time.perf_counter()
    calls = {}
    if method in ("gradient", "hybrid", "linesearch"):
        calls["gradient"] = lambda: _first_order(fns, Z0, tau, batch, keys, cfg, n)
    if method in ("cma", "sepcma", "hybrid", "linesearch"):
        width = 1 + 2 * pairs if method == "hybrid" else cfg.popsize
        calls["population"] = lambda: fns.population(np.repeat(Z0[:, None], width, 1), 0.0,
                                                     batch, keys)
    calls["forward"] = lambda: fns.forward(Z0, 0.0, batch, keys)[0]
    hard0 = warm_up(calls)["forward"]
    compile_s = time.perf_counter() - t0

    tracks = [_Tracker(z0, h, n) for h in hard0]
    for tr in tracks[1:]:
        tr.t0 = tracks[0].t0          # one shared clock
    clock = tracks[0]
    extras: list[dict] = [{} for _ in seeds]
    it = 0

    def running() -> bool:
        return it < cfg.max_iterations and clock.elapsed() < cfg.budget_s

    def best() -> str:
        return " ".join(f"{tr.loss:.4f}" for tr in tracks)

    if method in ("cma", "sepcma"):
        from cmaes import CMA, SepCMA

        opts = [(CMA if method == "cma" else SepCMA)(mean=z0.copy(), sigma=cfg.sigma0,
                                                     population_size=cfg.popsize, seed=s)
                for s in seeds]
        while running():
            zs = np.stack([np.stack([o.ask() for _ in range(cfg.popsize)]) for o in opts])
            losses = fns.population(zs, 0.0, batch, keys)                    # (S, P)
            for o, tr, zz, ll in zip(opts, tracks, zs, losses):
                tell_generation(o, tr, zz, ll, cfg.popsize * n)
            it += 1
            if log:
                log(f"{method} x{S}  gen {it:3d}  best {best()}  sigma "
                    + " ".join(f"{o._sigma:.3f}" for o in opts)
                    + f"  {clock.elapsed():.0f}/{cfg.budget_s:g} s")
    elif method == "linesearch":
        rays = [RaySearch(z0, h, cfg, s) for h, s in zip(hard0, seeds)]
        while running():
            pushes = 0
            if any(r.needs_gradient for r in rays):     # one call for all seeds
                grads = _first_order(fns, np.stack([r.z for r in rays]), tau, batch, keys,
                                     cfg, n)                                    # (S, G, k)
                for r, g in zip(rays, grads):
                    if r.needs_gradient:
                        r.set_directions(g)
                pushes += n
            zs = np.stack([r.candidates() for r in rays])                       # (S, P, k)
            losses = fns.population(zs, 0.0, batch, keys)                       # (S, P)
            for r, tr, zz, ll in zip(rays, tracks, zs, losses):
                r.tell(zz, ll)
                for z, v in zip(zz, ll):
                    tr.offer(z, v)
                tr.tick(pushes + cfg.popsize * n)
            it += 1
            if log:
                log(f"{method} x{S}  it {it:3d}  best {best()}  "
                    + "; ".join(r.describe() for r in rays)
                    + f"  {clock.elapsed():.0f}/{cfg.budget_s:g} s")
        for e, r in zip(extras, rays):
            e.update(r.extra())
    elif method == "es":
        rngs = [jax.random.PRNGKey(s) for s in seeds]
        zs = [z0.copy() for _ in seeds]
        bests = [_finite(h) for h in hard0]
        sigmas = [cfg.sigma0] * S
        while running():
            cands = []
            for i in range(S):
                rngs[i], sub = jax.random.split(rngs[i])
                cands.append(zs[i] + sigmas[i] * np.asarray(jax.random.normal(sub, z0.shape),
                                                            float))
            losses = fns.forward(np.stack(cands), 0.0, batch, keys)[0]
            for i, tr in enumerate(tracks):
                loss = _finite(losses[i])
                zs[i], bests[i], sigmas[i] = one_plus_one_step(zs[i], bests[i], sigmas[i],
                                                               cands[i], loss)
                tr.offer(cands[i], loss)
                tr.tick(n)
            it += 1
    else:   # gradient / hybrid: Adam on a (mixed) gradient, one optimiser state per seed
        optimizer = optax.chain(optax.clip_by_global_norm(cfg.clip_norm),
                                optax.adam(cfg.learning_rate))
        zj = [jnp.asarray(z0) for _ in seeds]
        states = [optimizer.init(z) for z in zj]
        apply = jax.jit(lambda z, s, g: _adam(optimizer, z, s, g))
        gens = [np.random.default_rng(s) for s in seeds]
        alphas: list[list[float]] = [[] for _ in seeds]
        iterate_losses: list[list[float]] = [[] for _ in seeds]
        while running():
            zc = np.stack([np.asarray(z, float) for z in zj])                 # (S, k)
            grads = _first_order(fns, zc, tau, batch, keys, cfg, n)            # (S, G, k)
            pushes = n
            if method == "gradient":
                hard = fns.forward(zc, 0.0, batch, keys)[0]
                mixed = []
                for i, tr in enumerate(tracks):
                    tr.offer(zc[i], hard[i])
                    iterate_losses[i].append(_finite(hard[i]))
                    mixed.append((grads[i].mean(0), 1.0))
                pushes += n
            else:
                eps = [g.standard_normal((pairs, z0.size)) for g in gens]
                zs = np.stack([np.concatenate([zc[i][None], zc[i] + cfg.zo_sigma * eps[i],
                                               zc[i] - cfg.zo_sigma * eps[i]])
                               for i in range(S)])                             # (S, 1+2p, k)
                pop = fns.population(zs, 0.0, batch, keys)
                mixed = []
                for i, tr in enumerate(tracks):
                    losses = np.array([_finite(v) for v in pop[i]])
                    tr.offer(zc[i], losses[0])
                    iterate_losses[i].append(float(losses[0]))
                    for zz, v in zip(zs[i][1:], losses[1:]):
                        tr.offer(zz, v)
                    mixed.append(alpha_order_mix(grads[i].mean(0), grads[i],
                                                 losses[1:pairs + 1], losses[pairs + 1:],
                                                 eps[i], cfg.zo_sigma))
                pushes += zs.shape[1] * n
            for i, (g, alpha) in enumerate(mixed):
                alphas[i].append(alpha)
                if np.all(np.isfinite(g)):
                    zj[i], states[i] = apply(zj[i], states[i], jnp.asarray(g, zj[i].dtype))
                tracks[i].tick(pushes)
            it += 1
            if log:
                log(f"{method} x{S}  it {it:3d}  best {best()}  alpha "
                    + " ".join(f"{m[1]:.2f}" for m in mixed)
                    + f"  {clock.elapsed():.0f}/{cfg.budget_s:g} s")
        for e, a, h in zip(extras, alphas, iterate_losses):
            e["alpha"] = a
            e["iterate_loss"] = h             # the hard loss of each Adam iterate
    return [dict(method=method, seed=s, z_best=tr.z.tolist(), best_loss=tr.loss,
                 compile_s=round(compile_s, 2), iterations=it, curve=tr.curve, extra=e)
            for s, tr, e in zip(seeds, tracks, extras)]


def _first_order(fns, zs, tau, batch, keys, cfg: SearchConfig, n: int) -> np.ndarray:
    """(S, groups, k) first-order gradient samples, as search.first_order_grads per seed."""
    if cfg.push_clip > 0:
        _, per_push = fns.grouped_value_and_grad(zs, tau, batch, keys, n)      # (S, n, k)
        return np.stack([clipped_group_means(g, cfg.groups, cfg.push_clip) for g in per_push])
    return np.asarray(fns.grouped_value_and_grad(zs, tau, batch, keys, cfg.groups)[1])
