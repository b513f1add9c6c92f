"""Gradient tuning (tkujax.studies.tune): finite-difference check of the rollout gradient, a short
tuning run, the reparameterisation, NaN handling, and the spec / parameter files.

Everything that runs the MJX rollout shares ONE compiled value_and_grad (module fixture
`problem`): float64, 2 pushes x 0.6 s, no servo quantisation, no remat. Compiling it takes
~4 minutes on a 2-core CPU (once; the persistent XLA cache makes reruns fast).

Finite-difference setting ("where no contact changes" is asked of it; both are stated):
  float64; pushes at 0.15 s onset, 20 ms pulse at 0.36 m; horizon 0.6 s; soft gate, 2 deg;
  servo quantisation OFF (with it the leg targets are piecewise constant in the parameters,
  so finite differences see zero while the straight-through gradient does not: by design);
  central differences in latent space, h = 1e-5; tolerance: relative error <= 1e-4 (measured
  ~1e-7..1e-9), or absolute <= 1e-10 for gradients that are zero.
  A. no step, no contact change: 0.05 N s from behind and from the front. The step is never
     triggered (the step weight stays < 1/2), so T, gamma and H_Sup cannot affect the loss: their
     gradients are exactly 0 (asserted). eps_1, eps_2, cp_gain, kalman_q, kalman_r act through
     the soft gate on x_Sup (the step-length cost) and must match the differences.
  B. a step with contact changes (foot lift-off and landing): 1.2 N s from behind and 1.0 N s
     from the front; T = 0.32 s and gamma = 0.25 so that the lift-off (gamma T / 2 = 40 ms) and
     landing (T - gamma T / 2 = 280 ms) instants fall between the 30 ms control ticks. At the
     paper's T = 0.3 s, gamma = 0.2 they coincide with ticks, where the loss has a kink in T
     and gamma and the gradient is one-sided (measured: gamma 2-60% off the central
     difference, which averages the two sides). All eight gradients, through the MJX physics,
     must match.
"""

from __future__ import annotations

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.dialects.sweep_spec import RANDOMIZE_DEFAULTS, SpecError
from tkujax.control.params_files import load_controller_params_json as load_params_json
from tkujax.studies.tune import (DEG, LossConfig, Reparam, TuneProblem, evolution_baseline,
                                 make_optimizer, optimise, params_json, parse_tune_spec,
                                 temperature_schedule)
from tkujax.studies.tune.reparam import PAPER_TUNABLE

H = 1e-5
REL_TOL = 1e-4
ABS_TOL = 1e-10
TAU = 2.0 * DEG
BATCH = 2


def two_pushes(impulse_ns, azimuth_deg) -> dict:
    """BATCH pushes at the given impulses and azimuths, the rest of each record fixed."""
    d = dict(impulse_ns=np.array(impulse_ns, float), azimuth_deg=np.array(azimuth_deg, float),
             height_m=np.full(BATCH, 0.36), duration_s=np.full(BATCH, 0.02),
             onset_s=np.full(BATCH, 0.15))
    for k, v in RANDOMIZE_DEFAULTS.items():
        d[k] = np.full(BATCH, -1.0 if v is None else v)
    return d


TINY = two_pushes([0.05, 0.05], [0.0, 180.0])
STEP = two_pushes([1.2, 1.0], [0.0, 180.0])
KEYS = jax.random.split(jax.random.PRNGKey(0), BATCH)


@pytest.fixture(scope="module")
def reparam() -> Reparam:
    return Reparam.make(PAPER_TUNABLE)


@pytest.fixture(scope="module")
def base() -> ControllerParams:
    return dataclasses.replace(ControllerParams.paper(), step_period=0.32,
                               double_support_ratio=0.25)


@pytest.fixture(scope="module")
def problem(reparam, base) -> TuneProblem:
    return TuneProblem(reparam, base, LossConfig(), duration_s=0.6, remat=False, float64=True,
                       quantise_targets=False)


def _fd_check(problem, z0, batch):
    loss, aux, grad = problem.value_and_grad(z0, TAU, batch, KEYS)
    fd = np.zeros_like(grad)
    for i in range(len(z0)):
        e = np.zeros_like(z0)
        e[i] = H
        lp = problem.value_and_grad(z0 + e, TAU, batch, KEYS)[0]
        lm = problem.value_and_grad(z0 - e, TAU, batch, KEYS)[0]
        fd[i] = (lp - lm) / (2 * H)
    return loss, aux, grad, fd


def _report(fields, grad, fd):
    for f, g, d in zip(fields, grad, fd):
        print(f"{f:22s} grad {g: .9e}  fd {d: .9e}  rel {abs(g - d) / max(abs(d), 1e-300):.2e}")


@pytest.mark.slow
def test_gradient_matches_finite_differences_without_a_step(problem, reparam, base):
    z0 = reparam.latent_of(base)
    _, aux, grad, fd = _fd_check(problem, z0, TINY)
    _report(reparam.fields, grad, fd)
    assert np.all(aux["outcomes"]["capture_point_m"] != 0.0)     # the soft gate sets x_Sup ...
    assert not np.any(aux["outcomes"]["fell"])
    for i, f in enumerate(reparam.fields):
        if f in ("step_period", "double_support_ratio", "lift_height"):
            # ... but the step never starts, so the CPG parameters cannot act.
            assert grad[i] == 0.0 and abs(fd[i]) <= ABS_TOL, f
        else:
            assert grad[i] != 0.0, f
            assert abs(grad[i] - fd[i]) <= REL_TOL * abs(fd[i]), (f, grad[i], fd[i])


@pytest.mark.slow
def test_gradient_matches_finite_differences_through_a_step(problem, reparam, base):
    z0 = reparam.latent_of(base)
    _, aux, grad, fd = _fd_check(problem, z0, STEP)
    _report(reparam.fields, grad, fd)
    # Both pushes trigger a step (forward and backward) and are recovered.
    x_sup = aux["outcomes"]["capture_point_m"]
    assert x_sup[0] > 0.02 and x_sup[1] < -0.02
    assert not np.any(aux["outcomes"]["fell"])
    for i, f in enumerate(reparam.fields):
        assert abs(grad[i]) > 1e-6, f
        assert abs(grad[i] - fd[i]) <= REL_TOL * abs(fd[i]), (f, grad[i], fd[i])


@pytest.mark.slow
def test_short_tuning_run_lowers_the_loss(problem, reparam, base):
    z0 = reparam.latent_of(base)
    step_fn = lambda z, tau: problem.value_and_grad(z, tau, STEP, KEYS)  # noqa: E731
    temps = np.full(4, TAU)
    z, hist = optimise(step_fn, z0, temps, make_optimizer(0.3, 1.0), reparam, log=print)
    before = hist[0]["loss"]
    after = problem.value_and_grad(z, TAU, STEP, KEYS)[0]
    print(f"loss before {before:.6f} after {after:.6f}")
    assert not any(r["skipped"] for r in hist)
    assert after < before
    for f, (lo, hi) in reparam.user_ranges().items():
        assert lo <= reparam.user(z)[f] <= hi


@pytest.mark.slow
def test_nan_gradient_is_skipped_and_reported(problem, reparam, base):
    z0 = reparam.latent_of(base)
    nan_push = dict(STEP, impulse_ns=np.array([np.nan, 1.0]))   # NaN into the rollout itself
    calls = []

    def step_fn(z, tau):
        calls.append(z.copy())
        batch = nan_push if len(calls) == 2 else STEP
        return problem.value_and_grad(z, tau, batch, KEYS)

    z, hist = optimise(step_fn, z0, np.full(3, TAU), make_optimizer(0.3, 1.0), reparam,
                       log=print)
    assert [r["skipped"] for r in hist] == [False, True, False]
    # The rollout's NaN guard keeps the loss finite (the NaN push counts as diverged); its
    # gradient is not, and that alone skips the step.
    assert hist[1]["n_nonfinite_grad"] > 0 and not hist[1]["finite"]
    # The skipped step changed nothing: iteration 2 starts where iteration 1 did.
    np.testing.assert_array_equal(calls[2], calls[1])
    assert not np.array_equal(calls[1], calls[0])


def test_nan_gradient_skip_keeps_optimizer_state():
    """A cheap synthetic check: NaN on step 1 leaves z and Adam's moments as they were, so the
    run equals a run without that step."""
    target = np.array([1.0, -2.0, 0.5])

    def quad(z, tau):
        g = 2 * (z - target)
        return float(np.sum((z - target) ** 2)), {}, g

    calls = {"n": 0}

    def with_nan(z, tau):
        calls["n"] += 1
        loss, aux, g = quad(z, tau)
        return (loss, aux, np.full_like(g, np.nan)) if calls["n"] == 2 else (loss, aux, g)

    opt = make_optimizer(0.1, 1.0)
    z_nan, hist = optimise(with_nan, np.zeros(3), np.zeros(4), opt, log=None)
    z_ref, _ = optimise(quad, np.zeros(3), np.zeros(3), opt, log=None)
    assert [r["skipped"] for r in hist] == [False, True, False, False]
    np.testing.assert_allclose(z_nan, z_ref, rtol=0, atol=1e-7)


def test_reparameterisation_in_range_and_round_trip(reparam):
    ranges = reparam.user_ranges()
    for z in (np.full(reparam.size, -1e3), np.full(reparam.size, 1e3),
              np.array([1e3, -1e3] * 4), np.array([np.inf, -np.inf] * 4)):
        for values in (np.asarray(reparam.values(jnp.asarray(z, jnp.float32))),
                       reparam.values_np(z)):
            assert np.all(np.isfinite(values))
            for f, v in zip(reparam.fields, values):
                lo, hi = ranges[f]
                k = DEG if f.startswith("eps") else 1.0
                assert lo * k <= v <= hi * k, (f, v)
        p = reparam.params_np(ControllerParams.paper(), z)
        p.validate()                                   # ControllerParams' own ranges
    rng = np.random.default_rng(0)
    with jax.enable_x64(True):
        for _ in range(20):
            z = rng.uniform(-8, 8, reparam.size)
            back = reparam.latent(np.asarray(reparam.values(jnp.asarray(z))))
            np.testing.assert_allclose(back, z, rtol=0, atol=1e-6)
            np.testing.assert_allclose(reparam.latent(reparam.values_np(z)), z, atol=1e-6)
    with pytest.raises(ValueError, match="step_period"):
        reparam.latent([0.7, 0.2, 0.03, 0.2, 0.03, 1.0, 1e-4, 3e-3])   # T above its range
    # Gradients are finite and zero only at saturation.
    g = jax.grad(lambda z: jnp.sum(reparam.values(z)))(jnp.zeros(reparam.size))
    assert np.all(np.asarray(g) > 0)


def test_temperature_schedule_anneals():
    t = temperature_schedule(3.0, 0.5, 5) / DEG
    np.testing.assert_allclose([t[0], t[-1]], [3.0, 0.5])
    assert np.all(np.diff(t) < 0)
    np.testing.assert_allclose(temperature_schedule(2.0, 1.0, 3, "linear") / DEG, [2, 1.5, 1])


def test_evolution_baseline_counts_evaluations():
    n = {"calls": 0}

    def loss(z):
        n["calls"] += 1
        return float(np.sum((z - 1.0) ** 2))

    z, rows = evolution_baseline(loss, np.zeros(3), 30, 0.5, 0, log=None, pushes_per_eval=8)
    assert n["calls"] == 30 and len(rows) == 30 and rows[-1]["pushes_simulated"] == 240
    assert loss(z) < 3.0


def test_params_json_is_what_sweep_reads(tmp_path, reparam):
    p = reparam.params_np(ControllerParams.paper(), np.linspace(-2, 2, reparam.size))
    path = tmp_path / "params_after.json"
    path.write_text(json.dumps(params_json(p)))
    back = load_params_json(path)
    for f in reparam.fields:
        assert math.isclose(getattr(back, f), getattr(p, f), rel_tol=1e-12)
    assert back.gate_temperature == 0.0


SPEC = {"tune": {"batch": 4, "iterations": 2, "duration_s": 1.0},
        "push": {"impulse_ns": {"uniform": [0.2, 1.0]}, "azimuth_deg": [0, 180]}}


def test_model_table_picks_the_robot_and_names_bad_keys():
    """[model]: ModelParams overrides of the robot the spec tunes (a study kept on an earlier
    robot); validated at the edge, recorded, and used by make_problem."""
    from tkujax.studies.tune import make_problem

    spec = parse_tune_spec({**SPEC, "model": {"accel_lowpass_hz": 0}})
    assert spec.model == {"accel_lowpass_hz": 0.0}
    assert spec.model_params().accel_lowpass_hz == 0.0
    assert parse_tune_spec(SPEC).model_params() is None          # the embedded default
    assert not make_problem(spec).index.imu_filtered
    assert make_problem(parse_tune_spec(SPEC)).index.imu_filtered
    for table, match in [({"no_such_field": 1.0}, "no_such_field"),
                         ({"accel_lowpass_hz": "fast"}, "model.accel_lowpass_hz"),
                         ({"accel_lowpass_hz": 1e4}, "accel_lowpass_hz")]:
        with pytest.raises(SpecError, match=match):
            parse_tune_spec({**SPEC, "model": table})


def test_spec_validation_names_key_and_range():
    spec = parse_tune_spec(SPEC)
    assert spec.params == ("step_period", "double_support_ratio", "lift_height", "eps_forward",
                           "eps_backward")
    assert spec.eval_seed != spec.seed
    bad = [({"tune": {**SPEC["tune"], "iterations": 0}}, "tune.iterations"),
           ({"tune": {**SPEC["tune"], "params": ["standing_lean"]}}, "tune.params"),
           ({"tune": {**SPEC["tune"], "ranges": {"step_period": [-0.1, 0.5]}}},
            r"tune.ranges.step_period\[0\]: -0.1 is out of range: ControllerParams.step_period "
            r"must be in \(0, 2\] s"),
           ({"tune": {**SPEC["tune"], "ranges": {"step_period": [0.2, 2.5]}}},
            r"tune.ranges.step_period\[1\]: 2.5 is out of range"),
           ({"tune": {**SPEC["tune"], "ranges": {"step_period": [0.35, 0.5]}}},
            "strictly inside"),
           ({"tune": {**SPEC["tune"], "anneal": {"start_deg": 1.0, "end_deg": 2.0}}},
            "tune.anneal.end_deg"),
           ({"tune": {**SPEC["tune"], "bogus": 1}}, "unknown key"),
           ({"evaluate": {"seed": 0}}, "evaluate.seed"),
           ({"push": {"impulse_ns": {"uniform": [0.2, 250.0]}}}, "push.impulse_ns"),
           ({"push": {"onset_s": 0.99}}, "push.onset_s")]
    for patch, match in bad:
        with pytest.raises(SpecError, match=match):
            parse_tune_spec({**SPEC, **patch})


# --- Searches under one wall-clock budget (tkujax.studies.tune.search) on a known landscape ---

class _Quadratic:
    """Stand-in for TuneProblem with a known optimum: hard loss |z - z*|^2 plus a step (a
    discontinuity the first-order gradient cannot see); the 'soft' gradient is the smooth part."""

    def __init__(self, target, step=0.0):
        self.target, self.step = np.asarray(target, float), step

    def _hard(self, z):
        z = np.asarray(z, float)
        return float(np.sum((z - self.target) ** 2) + self.step * (z[0] > 0.5))

    def forward(self, z, temperature, batch, keys):
        return self._hard(z), {}

    def population(self, zs, temperature, batch, keys):
        return np.array([self._hard(z) for z in zs])

    def grouped_value_and_grad(self, z, temperature, batch, keys, groups):
        z = np.asarray(z, float)
        g = 2 * (z - self.target)
        noise = np.random.default_rng(0).normal(0, 0.01, (groups, z.size))
        return np.full(groups, self._hard(z)), g[None] + noise


@pytest.mark.parametrize("method", ["cma", "gradient", "hybrid", "linesearch", "es"])
def test_every_search_method_improves_a_known_landscape(method):
    from tkujax.studies.tune.search import SearchConfig, run_search

    prob = _Quadratic([0.3, -0.4, 0.2])
    z0 = np.zeros(3)
    cfg = SearchConfig(budget_s=30.0, max_iterations=60, popsize=7, learning_rate=0.05)
    r = run_search(method, prob, z0, {}, np.zeros(8), cfg, seed=0, log=None)
    assert r["best_loss"] < 0.3 * prob._hard(z0), r["best_loss"]
    assert r["best_loss"] == pytest.approx(prob._hard(r["z_best"]))
    losses = [p["best_loss"] for p in r["curve"]]
    assert all(b <= a for a, b in zip(losses, losses[1:]))      # best-so-far never undone
    assert r["iterations"] <= 60 and r["curve"][-1]["pushes"] > 8


def test_warm_up_runs_the_calls_side_by_side_and_returns_what_each_returned():
    """The calls overlap (each waits for the other's signal: one after the other, the first
    would time out), the results are keyed by name, and a call's error reaches the caller."""
    import threading

    from tkujax.studies.tune.search import warm_up

    a_started, b_started = threading.Event(), threading.Event()

    def a():
        a_started.set()
        return b_started.wait(10.0)

    def b():
        b_started.set()
        return a_started.wait(10.0)

    assert warm_up({"a": a, "b": b}) == {"a": True, "b": True}
    assert warm_up({"x": lambda: 1, "y": lambda: 2}, parallel=False) == {"x": 1, "y": 2}

    def broken():
        raise ValueError("bad call")

    with pytest.raises(ValueError, match="bad call"):
        warm_up({"ok": lambda: 1, "broken": broken})


def test_iterations_override_is_checked_like_the_spec_key(tmp_path):
    from pathlib import Path

    from tkujax.dialects.sweep_spec import SpecError
    from tkujax.studies.tune import run_tune

    for bad in (0, -1, 2.5):
        with pytest.raises(SpecError, match=r"iterations \(tune.iterations\): expected an "
                           rf"integer in \[1, 100000\], got {bad!r}"):
            run_tune(Path(__file__).resolve().parents[1] / "specs" / "tune" / "tune_cpu.toml",
                     tmp_path / "t", iterations=bad)
    assert not (tmp_path / "t").exists()


class _Counting(_Quadratic):
    """_Quadratic that counts gradient calls, optionally with a gradient pointing the wrong way
    (a first-order gradient blind to what the hard loss does)."""

    def __init__(self, target, flip=False):
        super().__init__(target)
        self.flip, self.grad_calls = flip, 0

    def grouped_value_and_grad(self, z, temperature, batch, keys, groups):
        self.grad_calls += 1
        v, g = super().grouped_value_and_grad(z, temperature, batch, keys, groups)
        return v, -g if self.flip else g


def test_linesearch_takes_the_best_step_on_the_ray_and_never_a_worse_one():
    """On |z - z*|^2 from 0 along the exact direction, the ray's best radius is the one
    nearest |z*|; every accepted iterate lowers the hard loss; a new gradient follows each
    move."""
    from tkujax.studies.tune.search import SearchConfig, run_search

    target = np.array([0.6, -0.8, 0.0])                 # |z*| = 1: radius 1 is on the ray
    prob = _Counting(target)
    cfg = SearchConfig(budget_s=30.0, max_iterations=4, popsize=7, ray_radius=2.0, groups=2)
    r = run_search("linesearch", prob, np.zeros(3), {}, np.zeros(4), cfg, seed=0, log=None)
    steps = r["extra"]["step_radius"]
    assert steps[0] == pytest.approx(1.0)               # radii 2, 1, 0.5, ...: 1 is best
    assert r["best_loss"] < 1e-3 and r["extra"]["moves"] >= 1
    losses = [c["best_loss"] for c in r["curve"]]
    assert all(b <= a for a, b in zip(losses, losses[1:]))
    # One gradient at compile, then one per iteration that follows a move (and the first).
    assert prob.grad_calls == 1 + 1 + sum(1 for s in steps[:-1] if s > 0)


def test_linesearch_rejects_a_wrong_gradient_and_tries_other_directions():
    """With the gradient flipped (uphill), no point on its ray is better: the incumbent stays,
    no new gradient is computed for the same point, and the next rays use the push groups'
    directions (here as wrong), then random ones, which find descent."""
    from tkujax.studies.tune.search import SearchConfig, run_search

    start = _Quadratic([0.6, -0.8, 0.0])._hard(np.zeros(3))
    prob = _Counting([0.6, -0.8, 0.0], flip=True)
    cfg = SearchConfig(budget_s=30.0, max_iterations=3, popsize=7, ray_radius=2.0, groups=2)
    r = run_search("linesearch", prob, np.zeros(3), {}, np.zeros(4), cfg, seed=0, log=None)
    assert r["extra"]["direction"] == ["mean", "group0", "group1"]
    assert r["extra"]["step_radius"] == [0.0, 0.0, 0.0] and r["best_loss"] == start
    assert prob.grad_calls == 2                         # compile + the first: none after fails
    prob = _Counting([0.6, -0.8, 0.0], flip=True)
    r = run_search("linesearch", prob, np.zeros(3), {}, np.zeros(4),
                   dataclasses.replace(cfg, max_iterations=8), seed=0, log=None)
    kinds, steps = r["extra"]["direction"], r["extra"]["step_radius"]
    assert kinds[3] == "random" and max(steps) > 0
    assert r["best_loss"] < start                       # random rays found descent


def test_linesearch_compares_with_the_incumbent_on_the_same_pushes():
    """The ray ends with the incumbent itself: a ray point better than the incumbent's loss on
    an earlier batch but worse than its loss on this one is not taken (fresh batches); the
    radii shrink by ray_ratio."""
    from tkujax.studies.tune.searchers import LineSearcher, SearchConfig

    cfg = SearchConfig(popsize=5, ray_radius=4.0, ray_ratio=0.25)
    s = LineSearcher(np.zeros(2), 1.0, cfg, seed=0)
    points = s.ask(np.array([[1.0, 0.0], [1.0, 0.0]]))
    np.testing.assert_allclose(points[:, 0], [-4.0, -1.0, -0.25, -0.0625, 0.0])
    s.tell(points, np.array([0.8, 0.8, 0.8, 0.8, 0.5]))      # this batch: incumbent 0.5
    assert s.moves == 0 and s.loss == 0.5 and np.all(s.z == 0.0)
    s.tell(s.ask(None), np.array([0.8, 0.4, 0.8, 0.8, 0.5]))  # next direction: a move to r 1
    assert s.moves == 1 and s.loss == 0.4 and s.radii_taken[-1] == 1.0


def test_alpha_order_mix_trusts_the_lower_variance_and_rejects_bias():
    from tkujax.studies.tune.search import alpha_order_mix

    rng = np.random.default_rng(0)
    g_true = np.array([1.0, -2.0])
    eps = rng.standard_normal((64, 2))
    sigma = 0.1
    lp = eps @ g_true * sigma + rng.normal(0, 0.05, 64)     # L(z + s e) - L(z) ~ s g.e
    lm = -eps @ g_true * sigma + rng.normal(0, 0.05, 64)
    groups = g_true[None] + rng.normal(0, 1e-3, (4, 2))     # a precise, unbiased FO gradient
    g, alpha = alpha_order_mix(groups.mean(0), groups, lp, lm, eps, sigma)
    assert alpha > 0.99 and np.allclose(g, g_true, atol=0.01)
    # A first-order gradient that is precise but wrong (blind to a discontinuity): rejected.
    biased = np.array([[0.0, 0.0]] * 4) + rng.normal(0, 1e-3, (4, 2))
    g, alpha = alpha_order_mix(biased.mean(0), biased, lp, lm, eps, sigma)
    assert alpha == 0.0 and np.linalg.norm(g - g_true) < 0.5


def test_clipped_group_means_against_a_hand_computation():
    """Each push's gradient is cut to clip x the median per-push norm, then grouped means."""
    from tkujax.studies.tune.search import clipped_group_means

    per_push = np.array([[3.0, 4.0],       # norm 5
                         [0.0, 1.0],       # norm 1
                         [0.0, -2.0],      # norm 2 (the median of 1, 2, 5, 100)
                         [60.0, 80.0]])    # norm 100: a chaotic rollout
    got = clipped_group_means(per_push, groups=2, clip=1.5)      # cap 1.5 x 3.5 = 5.25
    np.testing.assert_allclose(got, [[1.5, 2.5], [0.5 * 3.15, 0.5 * (4.2 - 2.0)]])
    # A generous clip changes nothing; one group is the plain mean.
    np.testing.assert_allclose(clipped_group_means(per_push, 1, 1e6), per_push.mean(0)[None])
    # A non-finite push (a diverged rollout) counts as zero.
    bad = per_push.copy()
    bad[3] = np.nan
    np.testing.assert_allclose(clipped_group_means(bad, 1, 1e6), per_push[:3].sum(0)[None] / 4)


def test_recovery_tuning_spec_round_trips_the_recommended_set():
    """The extended controller's tuning space (specs/tune/tune_recovery.toml): the recommended set
    lies strictly inside it and maps to latents and back to itself."""
    from pathlib import Path

    from tkujax.studies.tune import load_tune_spec

    spec = load_tune_spec(
        Path(__file__).resolve().parents[1] / "specs" / "tune" / "tune_recovery.toml")
    reparam = spec.reparam()
    assert set(reparam.fields) - set(PAPER_TUNABLE) >= {"stance_ankle_kp", "accel_gate"}
    rec = ControllerParams.recommended()
    with jax.enable_x64(True):
        z = reparam.latent_of(rec)
        back = reparam.params_np(rec, z)
    for f in reparam.fields:
        assert getattr(back, f) == pytest.approx(getattr(rec, f), rel=1e-9), f


def test_searcher_registry_and_injected_cma_candidates():
    """Every method is one registered searcher; CMA-ES takes injected candidates in place of
    the generation's last samples, and its tell accepts them."""
    from tkujax.studies.tune.searchers import METHODS, SEARCHERS, SearchConfig, searcher_class

    assert METHODS == ("cma", "sepcma", "gradient", "hybrid", "linesearch", "es",
                       "guided_sepcma", "guided_cma")
    assert all(searcher_class(m) is SEARCHERS[m] for m in METHODS)
    with pytest.raises(ValueError, match="method must be one of"):
        searcher_class("adam")
    cfg = SearchConfig(popsize=5)
    for method in ("cma", "sepcma"):
        s = searcher_class(method)(np.zeros(3), 1.0, cfg, 0)
        s.inject([np.full(3, 0.25)])
        points = s.ask(None)
        assert points.shape == (5, 3) and np.all(points[-1] == 0.25)
        s.tell(points, np.sum(points ** 2, axis=1))
        assert len(s.ask(None)) == 5                    # the injection lasts one generation
        with pytest.raises(ValueError, match="at most 5"):
            s.inject(np.zeros((6, 3)))
