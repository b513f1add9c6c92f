"""Seeds side by side (tkujax.studies.tune.lockstep): run_search_lockstep over 2 seeds gives,
seed by seed, what run_search gives for that seed alone (same iterates, best losses and curves,
within float32 rounding of the batched program), for every method.

Most of it runs on a cheap stand-in problem: TuneProblem's own methods (forward, population,
grouped_value_and_grad, forward_padded, cast_args) over a small jnp loss of the latents, the push
records and the per-push keys, with a hard gate (temperature 0) and its soft version, so the
same code paths run in milliseconds. One `slow` test checks one method (the (1+1)-ES) through
MJX: 2 pushes x 0.3 s, float32; two forward compiles (~30 s each on a 2-core CPU with an empty
XLA cache, seconds once the persistent cache holds them)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.studies.tune.lockstep import fell_rates_lockstep, run_search_lockstep
from tkujax.studies.tune.problem import RECORD_KEYS, TuneProblem
from tkujax.studies.tune.reparam import DEG
from tkujax.studies.tune.search import SearchConfig, run_search

SEEDS = [0, 1]
N = 4                      # pushes per training batch
CFG = SearchConfig(budget_s=1e6, max_iterations=3, popsize=5, sigma0=0.3, zo_sigma=0.3,
                   groups=2, learning_rate=0.1, temperature_deg=20.0)
Z0 = np.array([0.2, -0.1, 0.3])


class StandIn:
    """TuneProblem's interface (its own methods) on a cheap loss of z and the batch."""

    float64 = False
    dtype = jnp.float32
    input_keys = RECORD_KEYS            # no robot ensemble, no control-off column (w_harm = 0)
    _robot_values = None
    cast_args = TuneProblem.cast_args
    forward = TuneProblem.forward
    population = TuneProblem.population
    grouped_value_and_grad = TuneProblem.grouped_value_and_grad
    forward_padded = TuneProblem.forward_padded

    def __init__(self):
        # As TuneProblem.__init__ builds them from its loss (the robots' values, None here,
        # are the jitted functions' last argument).
        loss0 = lambda z, t, b, k, rv: self.loss(z, t, b, k)[0]  # noqa: E731
        self._fwd = jax.jit(lambda z, t, b, k, rv: self.loss(z, t, b, k))
        self._pop = jax.jit(jax.vmap(loss0, in_axes=(0, None, None, None, None)))
        self._vg_groups = jax.jit(jax.vmap(jax.value_and_grad(loss0),
                                           in_axes=(None, None, 0, 0, None)))

    def with_off_survived(self, records, keys, batch=None):
        return records

    def loss(self, z, temperature, batch, keys):
        def one(rec, key):
            target = jnp.stack([rec["impulse_ns"] - 1.0, jnp.sin(rec["azimuth_deg"] * DEG),
                                rec["height_m"]])
            smooth = jnp.sum((z - target - 0.05 * jax.random.normal(key, (3,))) ** 2)
            x = z[0] - rec["onset_s"]             # a step: hard at temperature 0, else soft
            gate = jnp.where(temperature > 0,
                             jax.nn.sigmoid(x / jnp.maximum(temperature, 1e-6)),
                             (x > 0).astype(z.dtype))
            total = smooth + 0.5 * gate
            return total, dict(fell=total > 0.6, diverged=rec["impulse_ns"] > 1.9)

        totals, outs = jax.vmap(one)(batch, keys)
        return jnp.mean(totals), dict(terms=dict(total=totals), outcomes=outs)


def stand_records(n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    out = {k: rng.uniform(0.0, 1.0, n) for k in RECORD_KEYS}
    out["impulse_ns"] = rng.uniform(0.5, 2.0, n)
    out["azimuth_deg"] = rng.uniform(0.0, 360.0, n)
    return out


def stand_keys(n: int, seed: int):
    return jax.random.split(jax.random.PRNGKey(100 + seed), n)


@pytest.fixture(scope="module")
def stand():
    return StandIn()


def _assert_same(single: list[dict], lock: list[dict], rtol=1e-5, atol=1e-6):
    for a, b in zip(single, lock, strict=True):
        assert (b["method"], b["seed"], b["iterations"]) == (a["method"], a["seed"],
                                                            a["iterations"])
        assert set(b) == set(a)
        np.testing.assert_allclose(b["z_best"], a["z_best"], rtol=rtol, atol=atol)
        assert b["best_loss"] == pytest.approx(a["best_loss"], rel=rtol, abs=atol)
        assert [c["pushes"] for c in b["curve"]] == [c["pushes"] for c in a["curve"]]
        np.testing.assert_allclose([c["best_loss"] for c in b["curve"]],
                                   [c["best_loss"] for c in a["curve"]], rtol=rtol, atol=atol)
        assert set(b["extra"]) == set(a["extra"])
        if "alpha" in a["extra"]:
            np.testing.assert_allclose(b["extra"]["alpha"], a["extra"]["alpha"], atol=1e-4)


@pytest.mark.parametrize("method", ["cma", "sepcma", "es", "gradient", "hybrid", "linesearch",
                                    "guided_sepcma", "guided_cma"])
def test_lockstep_matches_run_search_per_seed(stand, method):
    batches = [stand_records(N, 10 + s) for s in SEEDS]
    keys = [stand_keys(N, s) for s in SEEDS]
    single = [run_search(method, stand, Z0, batches[i], keys[i], CFG, seed=s)
              for i, s in enumerate(SEEDS)]
    lines = []
    lock = run_search_lockstep(method, stand, Z0, batches, keys, CFG, SEEDS, log=lines.append)
    _assert_same(single, lock)
    assert all(r["iterations"] == CFG.max_iterations for r in lock)
    assert len(lock[0]["curve"]) == CFG.max_iterations + 1
    # The seeds really differ (their own batch, random numbers and optimiser).
    assert not np.allclose(lock[0]["z_best"], lock[1]["z_best"])
    assert len(lines) == (0 if method == "es" else CFG.max_iterations)
    # The stacked form of the batches gives the same.
    stacked = {k: np.stack([b[k] for b in batches]) for k in batches[0]}
    again = run_search_lockstep(method, stand, Z0, stacked, jnp.stack(keys), CFG, SEEDS)
    _assert_same(lock, again, rtol=0, atol=0)


@pytest.mark.parametrize("method", ["gradient", "hybrid"])
def test_lockstep_matches_run_search_with_push_clip(stand, method):
    """The clipped per-push first-order gradient (push_clip > 0) in lockstep = run_search's,
    and it changes the iterates (the clip is active on this landscape)."""
    import dataclasses

    cfg = dataclasses.replace(CFG, push_clip=0.5)
    batches = [stand_records(N, 10 + s) for s in SEEDS]
    keys = [stand_keys(N, s) for s in SEEDS]
    single = [run_search(method, stand, Z0, batches[i], keys[i], cfg, seed=s)
              for i, s in enumerate(SEEDS)]
    lock = run_search_lockstep(method, stand, Z0, batches, keys, cfg, SEEDS)
    _assert_same(single, lock)
    np.testing.assert_allclose(lock[0]["extra"]["iterate_loss"],
                               single[0]["extra"]["iterate_loss"], rtol=1e-5)
    plain = run_search_lockstep(method, stand, Z0, batches, keys, CFG, SEEDS)
    assert not np.allclose(plain[0]["z_best"], lock[0]["z_best"])


def test_lockstep_shares_one_clock(stand):
    """A budget, not the iteration cap, ends the loop: every seed has done the same number of
    iterations, and their curves end at the same wall time (one clock)."""
    batches = [stand_records(N, 10 + s) for s in SEEDS]
    keys = [stand_keys(N, s) for s in SEEDS]
    cfg = SearchConfig(budget_s=0.3, max_iterations=100_000, popsize=5, groups=2)
    lock = run_search_lockstep("cma", stand, Z0, batches, keys, cfg, SEEDS)
    its = {r["iterations"] for r in lock}
    assert len(its) == 1 and 0 < its.pop() < 100_000
    ends = [r["curve"][-1]["wall_s"] for r in lock]
    assert ends[0] >= 0.25 and abs(ends[0] - ends[1]) < 0.05


def test_lockstep_evaluation_matches_per_seed(stand):
    """fell_rates_lockstep (all seeds in one call per chunk, padded) = compare.fell_rates per
    seed."""
    from tkujax.studies.tune.method_compare import fell_rates

    n, batch = 6, N                          # 2 chunks, the last one padded
    recs = [stand_records(n, 50 + s) for s in SEEDS]
    keys = [stand_keys(n, 7 + s) for s in SEEDS]
    zs = np.array([Z0, Z0 + 0.3])
    got = fell_rates_lockstep(stand, {"best": zs}, recs, keys, batch)["best"]
    for s in range(len(SEEDS)):
        want = fell_rates(stand, {"best": zs[s]}, recs[s], keys[s], batch)["best"]
        np.testing.assert_array_equal(got[s], want)
    every = np.concatenate(got)            # the check sees falls, stands and divergences
    assert np.isnan(every).any() and {0.0, 1.0} <= set(every[np.isfinite(every)])


def test_lockstep_rejects_bad_shapes(stand):
    batches = [stand_records(N, s) for s in SEEDS]
    keys = [stand_keys(N, s) for s in SEEDS]
    with pytest.raises(ValueError, match="method"):
        run_search_lockstep("adam", stand, Z0, batches, keys, CFG, SEEDS)
    with pytest.raises(ValueError, match="2 training batches for 3 seeds"):
        run_search_lockstep("es", stand, Z0, batches, keys, CFG, [0, 1, 2])
    with pytest.raises(ValueError, match="keys need shape"):
        run_search_lockstep("es", stand, Z0, batches, keys[:1], CFG, SEEDS)


@pytest.mark.slow
def test_lockstep_matches_run_search_through_mjx():
    """The real problem (the CPU smoke spec's policy `scalars`, 2 pushes x 0.3 s, float32),
    (1+1)-ES, 3 iterations: lockstep over 2 seeds = run_search per seed (measured: identical
    iterates, losses within 3e-7 relative)."""
    from tkujax.dialects.sweep_spec import read_toml
    from tkujax.studies.tune import parse_tune_spec
    from tkujax.studies.tune.tune_spec import sample_pushes

    data = read_toml("specs/tune/tune_dimension_cpu.toml")
    data["tune"] = dict(data["tune"], batch=2, duration_s=0.3)
    data["study"] = dict(data["study"], groups=1)
    spec = parse_tune_spec(data)
    rep, base = spec.policy_reparam("scalars"), spec.base_params()
    prob = TuneProblem(rep, base, spec.loss, spec.duration_s, spec.remat,
                       quantise_targets=spec.quantise_targets)
    z0 = rep.latent_of(base)
    batches = [sample_pushes(spec, 2, 10 + s) for s in SEEDS]
    keys = [jax.random.split(jax.random.PRNGKey(10 + s), 2) for s in SEEDS]
    cfg = SearchConfig(budget_s=1e6, max_iterations=3, sigma0=0.3)
    single = [run_search("es", prob, z0, batches[i], keys[i], cfg, seed=s)
              for i, s in enumerate(SEEDS)]
    lock = run_search_lockstep("es", prob, z0, batches, keys, cfg, SEEDS)
    _assert_same(single, lock, rtol=1e-5, atol=1e-6)
    assert lock[0]["best_loss"] != lock[1]["best_loss"]


def test_compile_included_clock_runs_the_same_search(stand):
    """study_clock.clocked_search (budget counting the compiles) runs the same loop: with a
    budget that never binds, the same records as run_search_lockstep; its best-so-far
    snapshots end at the best latents; the compile charged is the longest first call of the
    method's functions."""
    from tkujax.studies.tune.lockstep import lockstep_calls
    from tkujax.studies.tune.budget_clock import clocked_search

    batches = [stand_records(N, 10 + s) for s in SEEDS]
    keys = [stand_keys(N, s) for s in SEEDS]
    for method in ("guided_sepcma", "es", "gradient"):
        want = run_search_lockstep(method, stand, Z0, batches, keys, CFG, SEEDS)
        times = {}
        got, charge, snaps = clocked_search(method, lockstep_calls(stand, batches, keys, CFG,
                                                                   2), Z0, CFG, SEEDS, method,
                                            times, [0.5])
        _assert_same(want, got, rtol=0, atol=0)
        assert charge == max(times.values()) > 0
        assert [t for t, _ in snaps] == [0.5 * CFG.budget_s]      # never reached: the end
        np.testing.assert_array_equal(snaps[0][1], [r["z_best"] for r in got])


def test_compile_included_clock_charges_and_snapshots(stand):
    """A charge recorded earlier in the process is charged again (as in a fresh process): a
    charge over the budget leaves no search, every checkpoint at the start; a charge of most of
    the budget leaves the rest of it, and the early checkpoint holds the start."""
    from tkujax.studies.tune.lockstep import lockstep_calls
    from tkujax.studies.tune.budget_clock import clocked_search

    batches = [stand_records(N, 10 + s) for s in SEEDS]
    keys = [stand_keys(N, s) for s in SEEDS]
    calls = lockstep_calls(stand, batches, keys, CFG, 2)
    cfg = SearchConfig(budget_s=2.0, max_iterations=100_000, popsize=5, groups=2)
    times = dict(forward=5.0, population=1.0)
    rs, charge, snaps = clocked_search("cma", calls, Z0, cfg, SEEDS, "cma", times, [0.25, 0.5])
    assert charge == 5.0 and rs[0]["iterations"] == 0
    assert all(np.array_equal(z, [Z0, Z0]) for _, z in snaps)
    times = dict(forward=1.7, population=0.1)
    rs, charge, snaps = clocked_search("cma", calls, Z0, cfg, SEEDS, "cma", times, [0.25, 0.9])
    assert charge == 1.7 and 0 < rs[0]["iterations"] < 100_000
    assert rs[0]["curve"][-1]["wall_s"] == pytest.approx(0.3, abs=0.1)
    np.testing.assert_array_equal(snaps[0][1], [Z0, Z0])            # 0.5 s: still compiling
    assert snaps[1][0] == pytest.approx(1.8)
