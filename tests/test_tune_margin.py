"""The tuner's gradient options: tune.loss.kind = "margin" (on hand-made series and through a
tiny TuneProblem), the spec keys (gradient_window_ticks, timing_gradient, bundle_sigma,
bundle_antithetic, diagnose_every) and their refusals, options off leaving the program as it
was, bundled noise, and the gradient diagnostics a gradient run records in its history."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.sim.records import Series
from tkujax.gradients.bundled import bundle_noise
from tkujax.dialects.sweep_spec import SpecError
from tkujax.studies.tune import DEG, LossConfig, Reparam, TuneProblem, parse_tune_spec
from tkujax.studies.tune.loss import push_loss
from tkujax.studies.tune.reparam import PAPER_TUNABLE
from tkujax.studies.tune.tune_outputs import gradient_section
from tkujax.studies.tune.search import GradientOptions, SearchConfig, run_search
from tests.test_tune import BATCH, two_pushes

DT = 0.03
MARGIN = LossConfig(kind="margin")


def _series(com_x, lowest=None, pitch=None) -> Series:
    """Feet at x = 0, y = -+0.045; CoM at 0.25 m moving along x as given; onset at 0."""
    n = len(com_x)
    z = jnp.zeros(n)
    com = jnp.stack([jnp.asarray(com_x, jnp.float32), z, z + 0.25], -1)
    r = jnp.tile(jnp.array([0.0, -0.045, 0.03]), (n, 1))
    lo = jnp.full(n, 0.1) if lowest is None else jnp.asarray(lowest, jnp.float32)
    p = z if pitch is None else jnp.asarray(pitch, jnp.float32)
    return Series(t=DT * jnp.arange(-3, n - 3), pitch=p, roll=z, pitch_est=z, roll_est=z,
                  zmp=jnp.zeros((n, 2)), fsr_total=z, com=com, r_ankle=r,
                  l_ankle=r * jnp.array([1, -1, 1]), pelvis_z=jnp.full(n, 0.3),
                  lowest_body_z=lo, gate=z, x_sup=z, y_sup=z, step_weight=z, reachable=z)


def _fallen(n=30, fall_tick=12):
    """CoM runs out 2 cm per tick; the body touches the floor at fall_tick and lies there,
    pitched over by 90 deg."""
    x = 0.02 * np.maximum(np.arange(n) - 3, 0)
    lowest = np.where(np.arange(n) >= fall_tick, 0.0, 0.1)
    pitch = np.where(np.arange(n) >= fall_tick, np.pi / 2, 0.02 * np.maximum(np.arange(n) - 3,
                                                                              0))
    return x, lowest, pitch


def test_margin_kind_is_bounded_for_a_fallen_push_and_blind_after_the_fall():
    x, lowest, pitch = _fallen()
    s = _series(x, lowest, pitch)
    soft = push_loss(s, 0.0, LossConfig())
    terms = push_loss(s, 0.0, MARGIN)
    assert 0.99 < float(terms["fall"]) < 1.0               # the squash saturates
    assert float(soft["fall"]) > 2.0                        # the soft loss: unbounded
    # Recovery over the ticks before the fall only: it does not see the body lying at 90 deg.
    ref = MARGIN.incl_ref_deg * DEG
    before_fall = np.log1p((pitch[4:13] / ref) ** 2).mean()
    assert float(terms["recovery"]) == pytest.approx(before_fall, rel=1e-5)
    assert float(terms["total"]) < 1.0 + before_fall + 1e-3
    # No gradient through the ticks after the fall.
    def total(pitch_in, com_x):
        return push_loss(dataclasses.replace(s, pitch=pitch_in, com=s.com.at[:, 0].set(com_x)),
                         0.0, MARGIN)["total"]
    gp, gx = jax.grad(total, argnums=(0, 1))(s.pitch, s.com[:, 0])
    assert np.all(np.asarray(gp)[13:] == 0) and np.all(np.asarray(gx)[13:] == 0)
    assert np.any(np.asarray(gp)[4:13] != 0)


def test_margin_kind_equals_the_margin_module_for_a_survivor_and_soft_kind_is_unchanged():
    from tkujax.gradients.margin import margin_loss

    s = _series(0.002 * np.arange(30), pitch=0.01 * np.sin(np.arange(30)))
    terms = push_loss(s, 0.0, MARGIN)
    ref = margin_loss(s, 0.0, MARGIN.margin_config())
    assert float(terms["fall"]) == float(ref["total"])
    assert float(terms["recovery"]) == float(push_loss(s, 0.0, LossConfig())["recovery"])
    assert float(terms["fall"]) < 0.5


def _spec(**tune):
    return parse_tune_spec({"tune": dict(batch=8, duration_s=1.0, **tune),
                            "push": {"onset_s": 0.2}})


def test_spec_keys_parse_with_defaults_off():
    spec = _spec()
    assert (spec.loss.kind, spec.gradient_window_ticks, spec.timing_gradient,
            spec.bundle_sigma, spec.bundle_antithetic, spec.diagnose_every) == (
        "soft", None, False, 0.0, False, 10)
    spec = _spec(loss=dict(kind="margin", window_s=0.3, offset_m=0.01, scale_m=0.03,
                           softmax_m=0.004), gradient_window_ticks=5, timing_gradient=True,
                 bundle_sigma=0.05, bundle_antithetic=True, diagnose_every=0)
    assert spec.loss.margin_config().window_s == 0.3 and spec.loss.scale_m == 0.03
    assert (spec.gradient_window_ticks, spec.timing_gradient, spec.bundle_sigma,
            spec.bundle_antithetic, spec.diagnose_every) == (5, True, 0.05, True, 0)


@pytest.mark.parametrize("tune, words", [
    (dict(loss=dict(kind="hard")), ["tune.loss.kind", "'soft'", "'margin'", "'hard'"]),
    (dict(loss=dict(kind="margin", scale_m=0.0)), ["tune.loss.scale_m", "0.001", "0.0"]),
    (dict(loss=dict(kind="margin", window_s=99.0)), ["tune.loss.window_s", "30.0", "99.0"]),
    (dict(loss=dict(window_s=0.3)), ["tune.loss.window_s", "kind = \"margin\""]),
    (dict(gradient_window_ticks=0), ["tune.gradient_window_ticks", "[1, 100000]", "0"]),
    (dict(gradient_window_ticks=1.5), ["tune.gradient_window_ticks", "1.5"]),
    (dict(timing_gradient=1), ["tune.timing_gradient", "true or false", "1"]),
    (dict(bundle_sigma=-0.1), ["tune.bundle_sigma", "[0.0, 10.0]", "-0.1"]),
    (dict(bundle_antithetic=True, batch=7), ["tune.bundle_antithetic", "even", "7"]),
    (dict(diagnose_every=-1), ["tune.diagnose_every", "-1"]),
])
def test_spec_keys_are_refused_with_key_range_and_value(tune, words):
    with pytest.raises(SpecError) as err:
        parse_tune_spec({"tune": {"batch": 8, "duration_s": 1.0, **tune},
                         "push": {"onset_s": 0.2}})
    for w in words:
        assert w in str(err.value), (w, str(err.value))


def test_spec_options_reach_the_problem_and_saved_params_stay_plain():
    from tkujax.control.controller import has_timing_gradient
    from tkujax.studies.tune.held_out_gate import params_json
    from tkujax.studies.tune.tune_spec import make_problem

    spec = _spec(loss=dict(kind="margin", window_s=0.3), gradient_window_ticks=5,
                 timing_gradient=True, bundle_sigma=0.05)
    p = make_problem(spec)
    assert p.config.program.gradient_window_ticks == 5
    assert p.loss_cfg.kind == "margin" and p.loss_cfg.window_s == 0.3
    assert p.timing_gradient and p.bundle_sigma == 0.05
    z = p.reparam.latent_of(p.base)
    assert has_timing_gradient(p._params(jnp.asarray(z), 0.0)[0])     # in the loss
    saved = p.reparam.params_np(p.base, z)                             # what is written
    assert type(saved) is ControllerParams and type(p.base) is ControllerParams
    assert params_json(saved.validate()) == pytest.approx(params_json(spec.base_params()))
    off = make_problem(_spec())
    assert off.config.program.gradient_window_ticks is None
    assert not has_timing_gradient(off._params(jnp.asarray(z), 0.0)[0])


def test_bundle_noise_antithetic_pairs_and_seeded():
    a = bundle_noise(np.random.default_rng(3), 6, 4, antithetic=True)
    np.testing.assert_array_equal(a[3:], -a[:3])
    b = bundle_noise(np.random.default_rng(3), 6, 4)
    assert b.shape == (6, 4) and not np.allclose(b[3:], -b[:3])
    with pytest.raises(ValueError, match="even"):
        bundle_noise(np.random.default_rng(0), 5, 2, antithetic=True)


class _PerPush:
    """A landscape with per-push structure: push i's loss |z - t_i|^2 (t_i = target + a
    spread), the 'soft' loss equal to the hard one; grouped_value_and_grad takes noise when
    bundle_sigma > 0 and records what it was given."""

    def __init__(self, target, n=8, bundle_sigma=0.0):
        rng = np.random.default_rng(1)
        self.t = np.asarray(target, float) + 0.05 * rng.standard_normal((n, len(target)))
        self.bundle_sigma, self.noises = bundle_sigma, []

    def forward(self, z, temperature, batch, keys):
        return float(np.mean(np.sum((np.asarray(z) - self.t) ** 2, 1))), {}

    def population(self, zs, temperature, batch, keys):
        return np.array([self.forward(z, 0, batch, keys)[0] for z in zs])

    def grouped_value_and_grad(self, z, temperature, batch, keys, groups, noise=None):
        zi = np.asarray(z, float)[None] + (0.0 if noise is None else self.bundle_sigma * noise)
        if noise is not None:
            self.noises.append(noise)
        losses, grads = np.sum((zi - self.t) ** 2, 1), 2 * (zi - self.t)
        m = len(self.t) // groups
        return losses.reshape(groups, m).mean(1), grads.reshape(groups, m, -1).mean(1)


def test_gradient_run_records_diagnostics_and_first_order_step_checks():
    prob = _PerPush([0.3, -0.4, 0.2])
    cfg = SearchConfig(budget_s=30.0, max_iterations=12, learning_rate=0.02, groups=4)
    r = run_search("gradient", prob, np.zeros(3), {}, np.zeros(8), cfg, seed=0,
                   options=GradientOptions(diagnose_every=5))
    d = r["gradient_diagnostics"]
    assert len(d["per_call"]) == 12                      # one per iteration, warm-up dropped
    first = d["per_call"][0]
    assert first["half_cosine"] > 0.99                   # every push pulls the same way
    assert 5 / 8 <= first["top_share"] < 1.0
    assert first["norm_quantiles"][0.0] <= first["norm_quantiles"][0.5]
    assert [c["call"] for c in d["step_checks"]] == [0, 5, 10]
    for c in d["step_checks"]:                           # a small step on a quadratic
        assert c["predicted"] < 0 and c["measured"] == pytest.approx(c["predicted"], rel=0.2)
        assert c["cos_step_neg_grad"] > 0.5             # Adam: a sign-like step
    text = "\n".join(gradient_section(d))
    assert "half-batch cosine" in text and "| 5 |" in text
    # Without diagnostics: no record, and the run is the same.
    plain = run_search("gradient", _PerPush([0.3, -0.4, 0.2]), np.zeros(3), {}, np.zeros(8),
                       cfg, seed=0)
    assert "gradient_diagnostics" not in plain
    np.testing.assert_allclose(plain["z_best"], r["z_best"], rtol=1e-12)
    # Zeroth-order methods record none.
    cma = run_search("cma", prob, np.zeros(3), {}, np.zeros(8),
                     dataclasses.replace(cfg, max_iterations=2), seed=0,
                     options=GradientOptions(diagnose_every=5))
    assert "gradient_diagnostics" not in cma


def test_bundled_run_draws_fresh_antithetic_noise_per_gradient_call():
    prob = _PerPush([0.3, -0.4, 0.2], bundle_sigma=0.1)
    cfg = SearchConfig(budget_s=30.0, max_iterations=3, learning_rate=0.02, groups=4)
    r = run_search("gradient", prob, np.zeros(3), {}, np.zeros(8), cfg, seed=0,
                   options=GradientOptions(diagnose_every=1, bundle_antithetic=True))
    assert len(prob.noises) == 4                         # the warm-up and 3 iterations
    for eps in prob.noises:
        assert eps.shape == (8, 3)
        np.testing.assert_array_equal(eps[4:], -eps[:4])
    assert not np.allclose(prob.noises[1], prob.noises[2])
    assert r["gradient_diagnostics"]["bundle_sigma"] == 0.1


# -- through a tiny TuneProblem (compiles MJX: slow) ---------------------------------------
KEYS = jax.random.split(jax.random.PRNGKey(0), BATCH)


def _problem(**kw) -> TuneProblem:
    base = dataclasses.replace(ControllerParams.paper(), step_period=0.32,
                               double_support_ratio=0.25)
    return TuneProblem(Reparam.make(PAPER_TUNABLE), base, kw.pop("loss_cfg", MARGIN),
                       duration_s=kw.pop("duration_s", 0.6), remat=False,
                       float64=kw.pop("float64", True), quantise_targets=False, **kw)


def test_options_off_trace_the_program_they_always_were():
    """Explicitly-off options (no window, no timing gradient, bundle_sigma 0) trace the very
    jaxpr of the default problem; the margin kind, a window and the timing gradient do not."""
    recs = two_pushes([0.5, 0.5], [0.0, 180.0])

    def jaxpr(p):
        z = np.zeros(p.reparam.size)
        return str(jax.make_jaxpr(lambda *a: p._loss(*a, p._robot_values))(
            *p.cast_args(z, 2.0 * DEG, recs, KEYS)))

    kw = dict(duration_s=0.15, float64=False)
    default = jaxpr(_problem(loss_cfg=LossConfig(), **kw))
    assert jaxpr(_problem(loss_cfg=LossConfig(kind="soft"), rollout_options={
        "gradient_window_ticks": None}, timing_gradient=False, bundle_sigma=0.0, **kw)) == default
    for changed in (dict(loss_cfg=MARGIN), dict(loss_cfg=LossConfig(), timing_gradient=True),
                    dict(loss_cfg=LossConfig(), rollout_options={"gradient_window_ticks": 2})):
        assert jaxpr(_problem(**changed, **kw)) != default, changed


def test_bundled_problem_needs_noise_exactly_when_on():
    p = _problem(duration_s=0.15, float64=False)
    with pytest.raises(ValueError, match="noise"):
        p.grouped_value_and_grad(np.zeros(p.reparam.size), 0.0, two_pushes([0.5, 0.5], [0, 180]),
                                 KEYS, 2, noise=np.zeros((2, p.reparam.size)))
    with pytest.raises(ValueError, match="bundle_sigma"):
        _problem(duration_s=0.15, float64=False, bundle_sigma=-1.0)


@pytest.mark.slow
def test_margin_loss_through_the_tuner_matches_finite_differences():
    """float64, 2 pushes (1.2 and 1.0 N s) x 0.6 s, soft gate 2 deg: the margin loss and its
    gradient are finite, the fall term is in (0, 1), and the gradient in two latents matches
    central differences (h = 1e-5) to 1e-3 relative."""
    p = _problem()
    recs = two_pushes([1.2, 1.0], [0.0, 180.0])
    z0 = np.zeros(p.reparam.size)
    tau = 2.0 * DEG
    loss, aux, grad = p.value_and_grad(z0, tau, recs, KEYS)
    assert np.isfinite(loss) and np.all(np.isfinite(grad))
    assert np.all((aux["terms"]["fall"] > 0) & (aux["terms"]["fall"] < 1))
    h = 1e-5
    for i in (0, 1):
        e = np.zeros_like(z0)
        e[i] = h
        fd = (p.forward(z0 + e, tau, recs, KEYS)[0] - p.forward(z0 - e, tau, recs, KEYS)[0]) / (
            2 * h)
        assert grad[i] == pytest.approx(fd, rel=1e-3, abs=1e-9), (i, grad[i], fd)


@pytest.mark.slow
def test_bundled_gradient_with_zero_noise_is_the_plain_one():
    p = _problem(bundle_sigma=0.1)
    q = _problem()
    recs = two_pushes([1.2, 1.0], [0.0, 180.0])
    z0 = np.zeros(p.reparam.size)
    lb, gb = p.grouped_value_and_grad(z0, 2 * DEG, recs, KEYS, 2,
                                      noise=np.zeros((2, z0.size)))
    lq, gq = q.grouped_value_and_grad(z0, 2 * DEG, recs, KEYS, 2)
    np.testing.assert_array_equal(lb, lq)
    np.testing.assert_allclose(gb, gq, rtol=1e-9, atol=1e-12)
