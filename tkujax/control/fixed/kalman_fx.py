"""Fixed-point force detection (Eq. 1-2): inclination by CORDIC, scalar Kalman filter.

Words: accel in `accel` (g), rates in `rate`, angles in `angle`, the estimate in `state`, the
variance in `cov`, the gain in `unit`; pitch and roll elementwise on the last axis.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.control.fixed import cordic
from tkujax.control.fixed.coefficients import Coefficients, coef_format
from tkujax.control.fixed.config import FixedPointConfig
from tkujax.control.fixed.qformat import add, div_fraction, mul, requant, sub


def accel_to_angle_fx(accel: jax.Array, config: FixedPointConfig) -> jax.Array:
    """(..., 3) accel words (g) -> (..., 2) [pitch, roll] angle words.

    Two vectorings: (a_z, a_y) gives roll = atan2(a_y, a_z) and r = sqrt(a_y^2 + a_z^2);
    (r, -a_x) gives pitch = atan2(-a_x, r), as `tkujax.control.kalman.accel_to_angle`.
    """
    spec, fa, fang = cordic.spec_of(config), config.accel, config.angle
    ax, ay, az = accel[..., 0], accel[..., 1], accel[..., 2]
    roll, r = cordic.atan2(ay, az, fa, fang, spec, fmt_mag=fa)
    pitch, _ = cordic.atan2(-ax, r, fa, fang, spec)   # -ax: words are < 2^30, no overflow
    return jnp.stack([pitch, roll], axis=-1)


def kalman_step_fx(phi: jax.Array, p: jax.Array, rate: jax.Array, accel_angle: jax.Array,
                   coef: Coefficients, config: FixedPointConfig) -> tuple[jax.Array, jax.Array]:
    """One update of Eq. 1-2 (A = 1, B = dt, H = 1) on words; returns (phi, p).

    phi (state), p (cov), rate (rate), accel_angle (angle): all (..., 2).
    """
    c, rnd = config, config.rounding
    fs, fv, fk = c.state, c.cov, c.unit
    phi = add(phi, mul(rate, c.rate, coef.dt, coef_format("dt", c), fs, rnd), fs)
    p = add(p, coef.kalman_q, fv)
    k = div_fraction(p, add(p, coef.kalman_r, fv), fk, rnd)           # p / (p + r) in [0, 1]
    innovation = sub(requant(accel_angle, c.angle, fs, rnd), phi, fs)
    phi = add(phi, mul(k, fk, innovation, fs, fs, rnd), fs)
    p = mul(sub(1 << fk.frac_bits, k, fk), fk, p, fv, fv, rnd)       # (1 - k) p
    return phi, p
