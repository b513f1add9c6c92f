"""Fixed-point push recovery (Eq. 5-10, Algorithm 1) with the hard gate of the paper.

x_Sup = l sin(theta) + l cos(theta) * [2 sqrt(g/l) sin(theta/2)] * sqrt(h/g), the same smooth,
signed form as `tkujax.control.capture_point.capture_point`; sin/cos by CORDIC.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.control.fixed import cordic
from tkujax.control.fixed.coefficients import Coefficients, coef_format
from tkujax.control.fixed.config import FixedPointConfig
from tkujax.control.fixed.qformat import QFormat, add, mul


def capture_point_fx(theta: jax.Array, coef: Coefficients, config: FixedPointConfig) -> jax.Array:
    """Capture point (length word, without cp_gain) of the pendulum angle word theta (angle)."""
    c, rnd, spec = config, config.rounding, cordic.spec_of(config)
    fa, fu, fl = c.angle, c.unit, c.length
    # One CORDIC pass for theta and theta / 2 in a format with one more fraction bit: theta is
    # the word shifted left, theta / 2 the word itself (both exact).
    fine = QFormat(fa.int_bits, fa.frac_bits + 1)
    theta = jnp.asarray(theta, jnp.int32)
    cos_b, sin_b = cordic.sincos(jnp.stack([jnp.left_shift(theta, 1), theta]), fine, fu, spec)
    cos_t, sin_t, sin_half = cos_b[0], sin_b[0], sin_b[1]
    phidot = mul(coef.two_sqrt_gl, coef_format("two_sqrt_gl", c), sin_half, fu, c.rate, rnd)
    a = mul(phidot, c.rate, coef.sqrt_hg, coef_format("sqrt_hg", c), fu, rnd)   # phidot sqrt(h/g)
    x_com = mul(coef.leg_length, fl, sin_t, fu, fl, rnd)
    l_cos = mul(coef.leg_length, fl, cos_t, fu, fl, rnd)
    return add(x_com, mul(l_cos, fl, a, fu, fl, rnd), fl)


def step_length_fx(theta: jax.Array, coef: Coefficients, config: FixedPointConfig) -> jax.Array:
    """cp_gain * capture point, length word."""
    cp = capture_point_fx(theta, coef, config)
    return mul(coef.cp_gain, coef_format("cp_gain", config), cp, config.length, config.length,
               config.rounding)


def band_gate_fx(angle: jax.Array, lower: jax.Array, upper: jax.Array) -> jax.Array:
    """bool: angle outside (lower, upper) (words of one format): a pair of comparators."""
    return (angle > upper) | (angle < lower)
