"""Gradient diagnostics, bundled gradients, AUC and the margin on hand-made inputs with
closed-form answers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.gradients import diagnostics as dg
from tkujax.gradients.auc import roc_auc
from tkujax.gradients.bundled import bundled_value_and_grad


def test_half_batch_cosine_closed_form():
    g = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 1.0]])
    assert dg.half_batch_cosine(g) == pytest.approx(0.0)
    g = np.array([[1.0, 1.0], [3.0, 3.0], [2.0, 2.0], [0.0, 0.0]])
    assert dg.half_batch_cosine(g) == pytest.approx(1.0)
    g = np.array([[1.0, 0.0], [-1.0, 0.0]])
    assert dg.half_batch_cosine(g) == pytest.approx(-1.0)


def test_top_k_share_and_quantiles_closed_form():
    # norms 1, 2, 3, 4 (squared 1, 4, 9, 16; total 30): the top 2 carry 25 / 30.
    g = np.array([[1.0, 0.0], [0.0, 2.0], [3.0, 0.0], [0.0, -4.0]])
    assert dg.top_k_share(g, 2) == pytest.approx(25 / 30)
    assert dg.top_k_share(g, 4) == pytest.approx(1.0)
    q = dg.norm_quantiles(g, (0.0, 0.5, 1.0))
    assert q == {0.0: pytest.approx(1.0), 0.5: pytest.approx(2.5), 1.0: pytest.approx(4.0)}
    clipped = dg.clip_rows(g, 2.5)
    assert np.allclose(np.linalg.norm(clipped, axis=1), [1.0, 2.0, 2.5, 2.5])


def test_step_check_on_a_quadratic():
    """loss = |z|^2 / 2 at z = (3, 4): |g| = 5; along -g/|g| by s the loss changes by
    -5 s + s^2 / 2 exactly, first order -5 s."""
    loss = lambda z: 0.5 * float(z @ z)  # noqa: E731
    z = np.array([3.0, 4.0])
    checks = dg.step_check(loss, z, z, [0.1, 1.0, 20.0])
    for c, s in zip(checks, [0.1, 1.0, 20.0]):
        assert c.predicted == pytest.approx(-5 * s)
        assert c.measured == pytest.approx(-5 * s + s * s / 2)
    assert checks[0].ratio == pytest.approx(0.99)
    assert checks[2].ratio < 0          # overshoot: the loss rose


def test_summary_keys_and_values():
    g = np.array([[1.0, 0.0], [0.0, 2.0], [3.0, 0.0], [0.0, -4.0]])
    s = dg.summary(g, k=1)
    assert s["top_share"] == pytest.approx(16 / 30)
    assert s["mean_norm"] == pytest.approx(np.hypot(1.0, -0.5))


def test_bundled_gradient_of_a_quadratic():
    """Per-push loss (z - c_i)^2 / 2: its gradient at z + sigma eps_i is z + sigma eps_i - c_i,
    so the bundled mean is z - mean(c) + sigma mean(eps); antithetic noise makes it exact."""
    c = jnp.arange(8.0).reshape(4, 2)
    z = jnp.array([1.0, -1.0])
    per_push = jax.value_and_grad(lambda zz, ci: 0.5 * jnp.sum((zz - ci) ** 2))
    b = bundled_value_and_grad(per_push, z, c, jax.random.PRNGKey(0), 0.3, antithetic=True)
    np.testing.assert_allclose(b.grad, z - c.mean(0), atol=1e-6)
    np.testing.assert_allclose(b.grads, z + 0.3 * b.noise - c, atol=1e-6)
    b = bundled_value_and_grad(per_push, z, c, jax.random.PRNGKey(1), 0.3)
    np.testing.assert_allclose(b.grad, z - c.mean(0) + 0.3 * b.noise.mean(0), atol=1e-6)
    assert float(jnp.abs(b.noise.mean(0)).max()) > 0          # plain noise: not exact
    with pytest.raises(ValueError):
        bundled_value_and_grad(per_push, z, c[:3], jax.random.PRNGKey(0), 0.3, antithetic=True)


def test_roc_auc_closed_form():
    assert roc_auc([0.1, 0.2, 0.8, 0.9], [0, 0, 1, 1]) == 1.0
    assert roc_auc([0.1, 0.2, 0.8, 0.9], [1, 1, 0, 0]) == 0.0
    # one inverted pair out of 4: 3 / 4; a tie counts 1/2.
    assert roc_auc([0.1, 0.5, 0.4, 0.9], [0, 0, 1, 1]) == pytest.approx(0.75)
    assert roc_auc([0.5, 0.5], [0, 1]) == pytest.approx(0.5)
    assert np.isnan(roc_auc([0.1, 0.2], [1, 1]))
