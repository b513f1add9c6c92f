"""Seeds side by side: `run_search` for S seeds of one method in lockstep, one compiled call per
step for all seeds.

At the dimension study's small batches (512 pushes x 1.5 s) one search leaves a GPU far from
saturated, so the S seeds of one (policy, method) share every compiled call: each iteration
makes ONE forward call over (S,) latents, ONE population call over (S, P) latents and ONE
grouped value-and-gradient call over (S,) latents x groups, each seed on its own training batch.

Everything else is `run_search`'s: the same loop (`search.drive`) over the same searchers
(tkujax.studies.tune.searchers), one per seed: the same start z0, each seed's own training
batch and keys, its own CMA / sep-CMA object (seeded with its seed), (1+1)-ES PRNG key, hybrid
numpy generator and Adam state, the same compile-excluded clock and `search.Tracker` curve, and
the same per-seed push counts. So a seed's iterates are those of
`run_search` for that seed, up to the float rounding of the batched program
(tests/test_tune_lockstep.py). What differs is the clock: the seeds share one wall-clock budget
(the loop stops when it is spent, every seed having done the same number of iterations), so
each seed gets a share of the device's throughput, not all of it.

The batched functions are built here from `problem.loss` (jax.vmap over a leading seed axis),
with the problem's own casting (`problem.cast_args`), precision (`problem.float64`) and the same
default compiler options as TuneProblem; they are compiled once per problem, shape and
precision and kept on the problem object.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.studies.tune.problem import to_numpy, x64
from tkujax.studies.tune.reparam import CPU_COMPILER_OPTIONS, DEG
from tkujax.studies.tune.search import SearchConfig, clipped_group_means, drive
from tkujax.studies.tune.searchers import searcher_class


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
        with x64(p.float64):
            loss, aux = self._fwd(*p.cast_args(zs, temperature, batches, keys))
            return np.asarray(loss, np.float64), aux

    def population(self, zs, temperature, batches: dict, keys) -> np.ndarray:
        """zs (S, P, k): (S, P) mean losses, seed s's candidates on seed s's batch."""
        p = self.problem
        with x64(p.float64):
            return np.asarray(self._pop(*p.cast_args(zs, temperature, batches, keys)), np.float64)

    def grouped_value_and_grad(self, zs, temperature, batches: dict, keys, groups: int):
        """zs (S, k): (losses (S, G), grads (S, G, k)) over `groups` equal groups of each seed's
        batch (numpy)."""
        p = self.problem
        S, n = keys.shape[:2]
        if n % groups:
            raise ValueError(f"batch {n} must be a multiple of the gradient groups {groups}")
        with x64(p.float64):
            z, t, b, k = p.cast_args(zs, temperature, batches, keys)
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
            parts.append(to_numpy(jax.tree_util.tree_map(lambda x, m=m: x[:, :m], aux)))
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
    compare.fell_rates, seed s's latent latents[name][s] on its own records[s], all seeds in
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
                        compiler_options: dict | None = None, select=None,
                        stream=None) -> list[dict]:
    """Run one method for every seed in `seeds` side by side within ONE cfg.budget_s of wall
    clock (compile excluded). batches: S per-seed batch dicts or one dict of (S, n) columns;
    keys: (S, n, ...) (or S arrays). Returns one dict per seed, run_search's form: (method,
    seed, z_best, best_loss, compile_s, iterations, curve, extra). select, stream: the
    validation selection and the fresh batches of tkujax.studies.tune.selection."""
    searcher_class(method)
    seeds = [int(s) for s in seeds]
    S = len(seeds)
    if S == 0:
        raise ValueError("run_search_lockstep needs at least one seed")
    return drive(method, lockstep_calls(problem, batches, keys, cfg, S, compiler_options,
                                        stream), z0, cfg, seeds, f"{method} x{S}", log, select)


def lockstep_calls(problem, batches, keys, cfg: SearchConfig, S: int,
                   compiler_options: dict | None = None, stream=None) -> LockstepCalls:
    """The LockstepCalls of run_search_lockstep for S seeds (batches and keys as it takes
    them). stream: a selection.BatchStream of fresh training batches (`next_batch`)."""
    return LockstepCalls(lockstep_functions(problem, compiler_options),
                         _stack_batches(batches, S), _stack_keys(keys, S), cfg, stream)


class LockstepCalls:
    """search.SeedCalls for S seeds side by side: each a single compiled call for all seeds,
    seed s's latents on seed s's batch and keys. With a stream, `next_batch` moves every seed
    to its next fresh batch (the same shapes: nothing compiles again)."""

    def __init__(self, fns: LockstepFunctions, batch: dict, keys, cfg: SearchConfig,
                 stream=None):
        self.fns, self.batch, self.keys, self.cfg = fns, batch, keys, cfg
        self.pushes = int(keys.shape[1])
        self.stream, self.draws = stream, 0

    def next_batch(self) -> None:
        if self.stream is None:
            return
        self.draws += 1
        batches, keys = self.stream.draw(self.draws)
        S = self.keys.shape[0]
        self.batch, self.keys = _stack_batches(batches, S), _stack_keys(keys, S)

    def forward(self, zs) -> np.ndarray:
        return self.fns.forward(zs, 0.0, self.batch, self.keys)[0]

    def population(self, zs) -> np.ndarray:
        return self.fns.population(zs, 0.0, self.batch, self.keys)

    def gradients(self, zs) -> np.ndarray:
        """(S, groups, k) first-order gradient samples, as search.first_order_grads per
        seed."""
        cfg, tau = self.cfg, self.cfg.temperature_deg * DEG
        if cfg.push_clip > 0:
            _, per_push = self.fns.grouped_value_and_grad(zs, tau, self.batch, self.keys,
                                                          self.pushes)          # (S, n, k)
            return np.stack([clipped_group_means(g, cfg.groups, cfg.push_clip)
                             for g in per_push])
        return np.asarray(self.fns.grouped_value_and_grad(zs, tau, self.batch, self.keys,
                                                          cfg.groups)[1])
