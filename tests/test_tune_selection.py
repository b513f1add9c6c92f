"""Validation selection and fresh batches (tkujax.studies.tune.selection) in the search loop.

The selector is checked against a known fall-rate landscape: it keeps the start until a
latent is strictly better, records what it looked at, and the loop returns its best instead of
the lowest training loss. Fresh batches: the lockstep calls move to the stream's draws, one per
iteration, and the same stream gives the same run twice. All on the cheap stand-in problem of
test_tune_lockstep (milliseconds)."""

from __future__ import annotations

import numpy as np
import pytest

from tkujax.studies.tune.lockstep import lockstep_calls, run_search_lockstep
from tkujax.studies.tune.search import SearchConfig
from tkujax.studies.tune.searchers import searcher_class
from tkujax.studies.tune.selection import (FRESH_DRAW_SEED_STRIDE, BatchStream,
                                           ValidationSelector, incumbent)
from tkujax.studies.tune.tune_spec_tables import parse_study
from tkujax.dialects.validation import SpecError
from tests.test_tune_lockstep import N, SEEDS, Z0, StandIn, stand_keys, stand_records

CFG = SearchConfig(budget_s=1e6, max_iterations=4, popsize=5, sigma0=0.3, groups=2,
                   learning_rate=0.1, temperature_deg=20.0)


@pytest.fixture(scope="module")
def stand():
    return StandIn()


def _distance_rates(target):
    """Fall rate = distance of each seed's latent to `target`: a landscape with a known best."""
    return lambda zs: np.linalg.norm(np.asarray(zs) - target, axis=1)


def test_selector_keeps_start_until_strictly_better():
    target = np.array([1.0, 0.0])
    sel = ValidationSelector(_distance_rates(target), every_s=5.0)
    Z0 = np.array([[0.0, 0.0], [2.0, 0.0]])
    sel.start(Z0, 0.0)
    np.testing.assert_array_equal(sel.start_fall, [1.0, 1.0])
    assert not sel.due(4.9) and sel.due(5.0)
    sel.offer(np.array([[0.5, 0.0], [3.0, 0.0]]), 5.0)        # seed 0 better, seed 1 worse
    np.testing.assert_array_equal(sel.best_z, [[0.5, 0.0], [2.0, 0.0]])
    sel.offer(np.array([[1.5, 0.0], [0.0, 0.0]]), 10.0)       # a tie for each: kept
    np.testing.assert_array_equal(sel.best_z, [[0.5, 0.0], [2.0, 0.0]])
    rec = sel.record(0)
    assert rec["validation_fall"] == 0.5 and rec["start_validation_fall"] == 1.0
    assert [c["fall"] for c in rec["selection_curve"]] == [1.0, 0.5, 0.5]
    assert [c["wall_s"] for c in rec["selection_curve"]] == [0.0, 5.0, 10.0]


def test_selector_never_picks_a_non_finite_rate():
    sel = ValidationSelector(lambda zs: np.array([np.nan]), every_s=1.0)
    sel.start(np.zeros((1, 2)), 0.0)
    sel.offer(np.ones((1, 2)), 1.0)
    np.testing.assert_array_equal(sel.best_z, np.zeros((1, 2)))


def test_incumbent_is_the_cma_mean_or_the_iterate():
    cma = searcher_class("sepcma")(Z0, 1.0, CFG, 0)
    np.testing.assert_allclose(incumbent(cma), Z0)
    adam = searcher_class("gradient")(Z0, 1.0, CFG, 0)
    np.testing.assert_allclose(incumbent(adam), Z0)


@pytest.mark.parametrize("method", ["sepcma", "gradient", "guided_sepcma"])
def test_search_returns_the_selectors_best(stand, method):
    """The loop offers every incumbent (every_s tiny) and returns the selector's best, which
    the known landscape confirms; the start is returned when nothing beats it."""
    batches = [stand_records(N, 10 + s) for s in SEEDS]
    keys = [stand_keys(N, s) for s in SEEDS]
    target = np.array([0.0, 0.0, 0.0])
    sel = ValidationSelector(_distance_rates(target), every_s=1e-9)
    rs = run_search_lockstep(method, stand, Z0, batches, keys, CFG, SEEDS, select=sel)
    for r in rs:
        curve = r["selection_curve"]
        assert len(curve) == r["iterations"] + 1               # the start + every iteration
        assert r["validation_fall"] == min(c["fall"] for c in curve)
        np.testing.assert_allclose(np.linalg.norm(np.asarray(r["z_best"]) - target),
                                   r["validation_fall"])
    unreachable = ValidationSelector(lambda zs: np.linalg.norm(zs - Z0, axis=1) - 1.0, 1e-9)
    rs = run_search_lockstep(method, stand, Z0, batches, keys, CFG, SEEDS, select=unreachable)
    for r in rs:                          # any move is worse than the start (distance 0)
        np.testing.assert_array_equal(r["z_best"], Z0)


def test_fresh_batches_follow_the_stream(stand):
    seen = []

    def sample(seed):
        seen.append(seed)
        return stand_records(N, seed), stand_keys(N, seed % 1000)

    stream = BatchStream(sample, SEEDS, base_seed=7)
    batches = [stand_records(N, 7 + s) for s in SEEDS]
    keys = [stand_keys(N, 7 + s) for s in SEEDS]
    calls = lockstep_calls(stand, batches, keys, CFG, len(SEEDS), stream=stream)
    calls.next_batch()
    assert seen == [7 + s + FRESH_DRAW_SEED_STRIDE for s in SEEDS]
    np.testing.assert_array_equal(calls.batch["impulse_ns"][1],
                                  stand_records(N, 8 + FRESH_DRAW_SEED_STRIDE)["impulse_ns"])
    a = run_search_lockstep("gradient", stand, Z0, batches, keys, CFG, SEEDS, stream=stream)
    b = run_search_lockstep("gradient", stand, Z0, batches, keys, CFG, SEEDS, stream=stream)
    fixed = run_search_lockstep("gradient", stand, Z0, batches, keys, CFG, SEEDS)
    np.testing.assert_array_equal(a[0]["z_best"], b[0]["z_best"])
    assert [c["best_loss"] for c in a[0]["curve"]] != [c["best_loss"] for c in fixed[0]["curve"]]


def test_study_selection_keys_are_validated():
    base = dict(policies=["scalars"], methods=["gradient"], seeds=[0])
    got = parse_study(dict(base, select="validation", select_every_s=5.0), batch=8)
    assert (got["select"], got["select_n"], got["select_every_s"]) == ("validation", 16, 5.0)
    with pytest.raises(SpecError, match="study.select: expected one of"):
        parse_study(dict(base, select="best"), batch=8)
    with pytest.raises(SpecError, match="study.fresh_batches: needs study.seeds_side_by_side"):
        parse_study(dict(base, fresh_batches=True), batch=8)
    with pytest.raises(SpecError, match="study.select_every_s"):
        parse_study(dict(base, select_every_s=0.0), batch=8)
