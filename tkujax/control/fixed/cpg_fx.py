"""Fixed-point stepping trajectories (Eq. 11-18, Table 2), timed in control ticks.

Time is a tick counter, as on the FPGA: n = ticks since the step started (negative before).
The phase of each oscillator is (n - t_lift) * omega dt, with t_lift in ticks and omega dt the
per-tick phase increment (coefficient registers); sines by CORDIC. The y oscillator of Eq. 14
has zero amplitude (Table 2) and is not built. With y_sup = 0 this is `cpg_feet`; otherwise
`cpg_feet_lateral` (swing foot on the falling side).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.control.fixed import cordic
from tkujax.control.fixed.coefficients import Coefficients, coef_format
from tkujax.control.fixed.config import FixedPointConfig
from tkujax.control.fixed.qformat import QFormat, add, mul, neg, sub


def unit_oscillators_fx(n_ticks: jax.Array, coef: Coefficients, config: FixedPointConfig):
    """(unit_x, unit_z) words (unit format) at tick n since the step started."""
    c, rnd, spec = config, config.rounding, cordic.spec_of(config)
    ft = coef_format("t_lift", c)
    one = 1 << c.unit.frac_bits
    n = jnp.clip(jnp.asarray(n_ticks, jnp.int32), -(1 << ft.int_bits) + 1, (1 << ft.int_bits) - 1)
    t = jnp.left_shift(n, ft.frac_bits)                   # n in the tick format
    in_swing = (t >= coef.t_lift) & (t < coef.t_land)
    landed = t >= coef.t_land
    s = sub(t, coef.t_lift, ft)
    phase_x = mul(s, ft, coef.dphase_x, coef_format("dphase_x", c), c.angle, rnd)
    phase_z = mul(s, ft, coef.dphase_z, coef_format("dphase_z", c), c.angle, rnd)
    _, sines = cordic.sincos(jnp.stack([phase_x, phase_z]), c.angle, c.unit, spec)
    sin_x, sin_z = sines[0], sines[1]
    unit_x = jnp.where(in_swing, sin_x, jnp.where(landed, one, 0))
    unit_z = jnp.where(in_swing, sin_z, 0)
    return unit_x.astype(jnp.int32), unit_z.astype(jnp.int32)


def cpg_feet_fx(n_ticks: jax.Array, x_sup: jax.Array, y_sup: jax.Array, coef: Coefficients,
                config: FixedPointConfig) -> tuple[jax.Array, jax.Array]:
    """(p_right, p_left), (..., 3) length words: ankle targets relative to the waist."""
    c, rnd, fl = config, config.rounding, config.length
    ux, uz = unit_oscillators_fx(n_ticks, coef, config)
    half = QFormat(fl.int_bits - 1, fl.frac_bits + 1)     # x/2 exactly: one more fraction bit
    half_x = mul(x_sup, half, ux, c.unit, fl, rnd)
    half_y = mul(y_sup, half, ux, c.unit, fl, rnd)
    lift = mul(coef.lift, fl, uz, c.unit, fl, rnd)
    swing_left = y_sup >= 0
    sx = jnp.where(swing_left, half_x, neg(half_x, fl))  # swing foot's x offset
    sy = jnp.where(swing_left, half_y, neg(half_y, fl))
    d_y, d_z = coef.hip_offset_y, coef.hip_to_ankle_z
    z0 = neg(d_z, fl)
    shape = jnp.shape(sx)
    p_left = jnp.stack([sx, add(jnp.broadcast_to(d_y, shape), sy, fl),
                        add(jnp.broadcast_to(z0, shape), jnp.where(swing_left, lift, 0), fl)], -1)
    p_right = jnp.stack([neg(sx, fl), sub(jnp.broadcast_to(-d_y, shape), sy, fl),
                         add(jnp.broadcast_to(z0, shape), jnp.where(swing_left, 0, lift), fl)], -1)
    return p_right, p_left
