"""The bounded DCM margin on hand-made series: the hull distance's closed form, the window
closing at the first low clearance, no gradient after it, NaN guards, bounds."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.sim.records import Series
from tkujax.gradients.margin import (MarginConfig, dcm_xy, hull_signed_distance,
                                     margin_loss, push_margin, window_mask)

N = 20
DT = 0.03


def _series(com_x, lowest=None, pelvis=None) -> Series:
    """Feet at x = 0, y = -+0.045 (z 0.03); CoM at height 0.25 m moving along x as given."""
    n = len(com_x)
    z = jnp.zeros(n)
    com = jnp.stack([jnp.asarray(com_x, jnp.float32), z, z + 0.25], -1)
    r = jnp.tile(jnp.array([0.0, -0.045, 0.03]), (n, 1))
    lo = jnp.full(n, 0.1) if lowest is None else jnp.asarray(lowest, jnp.float32)
    pz = jnp.full(n, 0.3) if pelvis is None else jnp.asarray(pelvis, jnp.float32)
    two = jnp.zeros((n, 2))
    return Series(t=DT * jnp.arange(1, n + 1), pitch=z, roll=z, pitch_est=z, roll_est=z,
                  zmp=two, fsr_total=z, com=com, r_ankle=r, l_ankle=r * jnp.array([1, -1, 1]),
                  pelvis_z=pz, lowest_body_z=lo, gate=z, x_sup=z, y_sup=z, step_weight=z,
                  reachable=z)


def test_hull_signed_distance_closed_form():
    box = jnp.array([[1.0, 1.0], [1.0, -1.0], [-1.0, -1.0], [-1.0, 1.0]])
    assert float(hull_signed_distance(jnp.array([2.0, 0.0]), box)) == pytest.approx(1.0, abs=1e-6)
    assert float(hull_signed_distance(jnp.array([0.0, 0.0]), box)) == pytest.approx(-1.0, abs=1e-6)
    assert float(hull_signed_distance(jnp.array([0.5, -0.2]), box)) == pytest.approx(-0.5, abs=1e-6)
    # Outside a corner: the distance to the corner, sqrt(2), up to the direction grid.
    d = float(hull_signed_distance(jnp.array([2.0, 2.0]), box, 32))
    assert np.sqrt(2) * np.cos(np.pi / 32) - 1e-6 <= d <= np.sqrt(2) + 1e-6


def test_dcm_is_com_plus_velocity_over_omega():
    x = 0.01 * np.arange(N)                       # 1 cm per tick: v = 1/3 m/s
    xi = dcm_xy(_series(x))
    omega = np.sqrt(9.81 / 0.25)
    np.testing.assert_allclose(np.asarray(xi[1:, 0]), x[1:] + (0.01 / DT) / omega, rtol=1e-5)
    assert float(xi[0, 0]) == pytest.approx(0.0)


def test_window_closes_at_first_low_clearance_and_stops_the_gradient():
    lowest = np.full(N, 0.1)
    lowest[12:] = 0.0                               # clearance < 1 cm from tick 12
    mask = np.asarray(window_mask(_series(np.zeros(N), lowest), 0.1))
    assert mask[3:13].all() and not mask[13:].any() and not mask[:3].any()

    def margin_of(com_x):
        return push_margin(_series(com_x, lowest), 0.1)

    g = np.asarray(jax.grad(margin_of)(jnp.asarray(0.02 * np.arange(N), jnp.float32)))
    assert np.all(g[13:] == 0.0) and np.any(g[:13] != 0.0)
    out = margin_loss(_series(0.02 * np.arange(N), lowest), 0.1)
    assert bool(out["fell_window"]) and 0.0 < float(out["total"]) < 1.0


def test_margin_orders_pushes_and_is_bounded():
    """A CoM drifting out of the feet has a larger margin than one at rest; the loss stays in
    (0, 1) and its gradient vanishes far outside (squashed)."""
    still = float(push_margin(_series(np.zeros(N)), 0.1))
    drift = float(push_margin(_series(0.01 * np.arange(N)), 0.1))
    assert still < 0 < drift
    cfg = MarginConfig(scale_m=0.01)
    far = lambda a: margin_loss(_series(a * np.arange(N)), 0.1, cfg)["total"]  # noqa: E731
    assert 0.0 < float(far(0.001)) < float(far(0.05)) <= 1.0
    assert abs(float(jax.grad(far)(0.05))) < 1e-3 * abs(float(jax.grad(far)(0.003)))


def test_non_finite_ticks_close_the_window_with_finite_gradients():
    x = 0.005 * np.arange(N)
    x[15] = np.nan
    s = _series(x)
    assert not bool(window_mask(s, 0.1)[16])
    g = jax.grad(lambda c: push_margin(dataclasses.replace(s, com=c), 0.1))(s.com)
    assert np.all(np.isfinite(np.asarray(g)))
    assert np.isfinite(float(push_margin(s, 0.1)))


def test_window_s_closes_the_window_early():
    mask = np.asarray(window_mask(_series(np.zeros(N)), 0.1, MarginConfig(window_s=0.2)))
    t = DT * np.arange(1, N + 1)
    np.testing.assert_array_equal(mask, (t > 0.1) & (t <= 0.3 + 1e-6))
    far = push_margin(_series(0.01 * np.arange(N)), 0.1, MarginConfig(window_s=0.2))
    assert float(far) < float(push_margin(_series(0.01 * np.arange(N)), 0.1))
