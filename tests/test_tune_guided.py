"""The gradient-guided CMA-ES (searchers.GuidedCMASearcher, "guided_sepcma" / "guided_cma") on
cheap analytic landscapes, through the same loop as every method (search.run_search)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from tkujax.studies.tune.search import SearchConfig, calls_used, run_search
from tkujax.studies.tune.searchers import SEARCHERS, GuidedSepCMASearcher, SepCMASearcher

K = 80
CFG = SearchConfig(budget_s=1e6, max_iterations=25, popsize=15, sigma0=0.3, groups=2)


class Quadratic:
    """f(z) = sum d_i (z_i - 1)^2 / k, d_i log-spaced in [1, 10]: forward, population and
    grouped value-and-gradient as TuneProblem has them (numpy; `scale` multiplies the gradient,
    0 or NaN to test the fallback)."""

    def __init__(self, k: int = K, scale: float = 1.0):
        self.d = np.logspace(0, 1, k)
        self.scale = scale

    def f(self, z):
        return float(np.sum(self.d * (np.asarray(z) - 1.0) ** 2) / len(self.d))

    def forward(self, z, t, batch, keys):
        return self.f(z), {}

    def population(self, zs, t, batch, keys):
        return np.array([self.f(z) for z in zs])

    def grouped_value_and_grad(self, z, t, batch, keys, groups):
        g = self.scale * 2.0 * self.d * (np.asarray(z) - 1.0) / len(self.d)
        return np.full(groups, self.f(z)), np.repeat(g[None], groups, 0)


def _run(method, landscape, seed, cfg=CFG):
    return run_search(method, landscape, np.zeros(K), {}, np.zeros(4), cfg, seed=seed)


def test_guided_registered_and_calls_the_gradient():
    assert SEARCHERS["guided_sepcma"] is GuidedSepCMASearcher
    assert calls_used("guided_sepcma") == calls_used("guided_cma") == {
        "forward", "population", "gradient"}
    assert calls_used("sepcma") == {"forward", "population"}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_guided_beats_plain_sepcma_on_a_quadratic(seed):
    guided = _run("guided_sepcma", Quadratic(), seed)
    plain = _run("sepcma", Quadratic(), seed)
    assert guided["iterations"] == plain["iterations"] == CFG.max_iterations
    assert guided["best_loss"] < 0.5 * plain["best_loss"]
    # The injected candidates were often the generation's best (rank 0).
    ranks = guided["extra"]["injected_rank"]
    assert len(ranks) == CFG.max_iterations and ranks.count(0) >= CFG.max_iterations // 2


@pytest.mark.parametrize("scale", [0.0, math.nan])
def test_no_gradient_no_injection_same_as_plain(scale):
    """A zero or non-finite gradient injects nothing: the run is plain sep-CMA-ES, bit for bit
    (the same seed draws the same samples)."""
    guided = _run("guided_sepcma", Quadratic(scale=scale), 3)
    plain = _run("sepcma", Quadratic(), 3)
    assert guided["extra"]["injected_rank"] == [None] * CFG.max_iterations
    assert guided["z_best"] == plain["z_best"]
    assert [c["best_loss"] for c in guided["curve"]] == [c["best_loss"] for c in plain["curve"]]


def test_injected_points_are_told_to_cmaes():
    """The gradient candidates take the generation's last slots, evaluated where they are;
    the short one (a = 0.5) is told to cmaes as is, the long one (a = 4) with its step cut to
    the Mahalanobis length sqrt(k) + 2k/(k + 2)."""
    cfg = dataclasses.replace(CFG, guided_steps=(0.5, 4.0))
    q = Quadratic()
    s = GuidedSepCMASearcher(np.zeros(K), q.f(np.zeros(K)), cfg, seed=0)
    told = []
    real_tell = s.opt.tell
    s.opt.tell = lambda sols: (told.append([np.array(x) for x, _ in sols]), real_tell(sols))
    at = s.gradient_at()
    g = q.grouped_value_and_grad(at, 0.0, {}, None, 2)[1]
    pts = s.ask(g)
    assert pts.shape == (cfg.popsize, K)
    gm = g.mean(0)
    u = gm / np.linalg.norm(gm) * cfg.sigma0 * math.sqrt(K)
    np.testing.assert_allclose(pts[-2], at - 0.5 * u)
    np.testing.assert_allclose(pts[-1], at - 4.0 * u)
    losses = q.population(pts, 0.0, {}, None)
    s.tell(pts, losses)
    sent = told[0]
    np.testing.assert_array_equal(sent[-2], pts[-2])
    for own, x in zip(sent[:-2], pts[:-2]):
        np.testing.assert_array_equal(own, x)
    cap = math.sqrt(K) + 2 * K / (K + 2)
    step = (sent[-1] - at) / cfg.sigma0          # C = I at the start
    assert np.linalg.norm(step) == pytest.approx(cap)
    assert np.linalg.norm((pts[-1] - at) / cfg.sigma0) > 1.5 * cap
    # The next generation asks for the gradient at the new mean.
    assert not np.allclose(s.gradient_at(), at)


def test_guided_steps_must_leave_own_samples():
    with pytest.raises(ValueError, match="guided_steps"):
        GuidedSepCMASearcher(np.zeros(3), 0.0, dataclasses.replace(CFG, popsize=3), seed=0)
    SepCMASearcher(np.zeros(3), 0.0, dataclasses.replace(CFG, popsize=3), seed=0)


def test_gradients_specs_parse():
    """The comparison's specs: sectors8 (80) and mlp96 (1,272 parameters), the three methods,
    three seeds side by side, compile included, starting at the recommended controller on the
    default robot."""
    from tkujax.control.controller_params import ControllerParams
    from tkujax.dialects.sweep_spec import read_toml
    from tkujax.studies.tune import parse_tune_spec

    for path, batch in (("specs/tune/gradients.toml", 1024), ("specs/tune/gradients_cpu.toml", 16)):
        spec = parse_tune_spec(read_toml(path))
        st = spec.study
        assert [spec.policy_reparam(p).size for p in st["policies"]] == [80, 1272]
        assert st["methods"] == ["sepcma", "guided_sepcma", "gradient"]
        assert st["seeds"] == [0, 1, 2] and st["seeds_side_by_side"]
        assert st["budget_includes_compile"] and st["guided_steps"] == (0.5, 1.0, 2.0)
        assert spec.batch == batch and not spec.model
        assert spec.base_params() == ControllerParams.recommended()
