"""Coefficient registers: ControllerParams -> the integer constants the datapath uses.

On the FPGA these are configuration registers loaded once (computed offline). Here they are
computed from the (possibly traced) float parameters with float math, then rounded to nearest
into a static format, so a sweep can still vary parameters without recompiling. Parameters are
never used as floats inside the datapath.

Coefficients of one signal group take that group's format; the others are `coef_bits`-bit
registers whose binary point is placed for a design range (value beyond it saturates):
  dt            s       Q0.(c-1)   < 1 s
  cp_gain       -       Q4.(c-5)   < 16
  two_sqrt_gl   1/s     Q5.(c-6)   2 sqrt(g/l) < 32  (l > 4 cm at g = 9.81)
  sqrt_hg       s       Q0.(c-1)   sqrt(h/g) < 1 s
  inv_2ltlc     1/m^2   Q7.(c-8)   1/(2 l_t l_c) < 128  (l_t l_c > 39 cm^2)
  t_lift, t_land ticks  Q10.(c-11) step phase boundaries in control periods, < 1024
  dphase_x, _z  rad/tick Q2.(c-3)  CPG phase increments omega * dt
  update_ticks  ticks  Q10.(c-11) cp_update_window / dt + 1/2: x_Sup is recomputed while the
                                  step is younger than this many periods (cp_update_window)
  cp_mid        rad    state      (eps_forward - eps_backward) / 2: which threshold cp_excess
                                  measures the excess over
  cp_excess, cp_update, lateral   mode bits (bools)
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from tkujax.control.fixed.config import FixedPointConfig
from tkujax.control.fixed.qformat import QFormat, quantize
from tkujax.control.controller_params import ControllerParams

_COEF_INT_BITS = {"dt": 0, "cp_gain": 4, "two_sqrt_gl": 5, "sqrt_hg": 0, "inv_2ltlc": 7,
                  "t_lift": 10, "t_land": 10, "dphase_x": 2, "dphase_z": 2, "update_ticks": 10}
MODE_BITS = ("lateral", "cp_excess", "cp_update")   # one-bit registers (bools)
_GROUP = {"kalman_q": "cov", "kalman_r": "cov", "eps_forward": "state", "eps_backward": "state",
          "eps_lateral": "state", "cp_mid": "state", "cp_angle_offset": "angle",
          "standing_lean": "angle",
          "leg_length": "length", "hip_offset_y": "length", "hip_to_ankle_z": "length",
          "thigh": "length", "calf": "length", "lift": "length"}


def coef_format(name: str, config: FixedPointConfig) -> QFormat:
    """Static format of coefficient `name`."""
    if name in _GROUP:
        return getattr(config, _GROUP[name])
    i = _COEF_INT_BITS[name]
    return QFormat(i, config.coef_bits - 1 - i)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Coefficients:
    """int32 scalar words, one per coefficient (formats: `coef_format`); lateral, cp_excess and
    cp_update are bools (mode bits)."""

    dt: jax.Array
    kalman_q: jax.Array
    kalman_r: jax.Array
    eps_forward: jax.Array
    eps_backward: jax.Array
    eps_lateral: jax.Array
    cp_angle_offset: jax.Array
    standing_lean: jax.Array
    cp_gain: jax.Array
    two_sqrt_gl: jax.Array
    sqrt_hg: jax.Array
    leg_length: jax.Array
    hip_offset_y: jax.Array
    hip_to_ankle_z: jax.Array
    thigh: jax.Array
    calf: jax.Array
    lift: jax.Array
    inv_2ltlc: jax.Array
    t_lift: jax.Array
    t_land: jax.Array
    dphase_x: jax.Array
    dphase_z: jax.Array
    update_ticks: jax.Array
    cp_mid: jax.Array
    lateral: jax.Array
    cp_excess: jax.Array
    cp_update: jax.Array


def coefficients(params: ControllerParams, config: FixedPointConfig) -> Coefficients:
    """Quantise the parameters (and the constants derived from them) into their registers."""
    p = params
    T, gamma, dt = p.step_period, p.double_support_ratio, p.control_period
    swing = T * (1.0 - gamma)
    values = dict(
        dt=dt, kalman_q=p.kalman_q, kalman_r=p.kalman_r, eps_forward=p.eps_forward,
        eps_backward=p.eps_backward, eps_lateral=p.eps_lateral,
        cp_angle_offset=p.cp_angle_offset, standing_lean=p.standing_lean, cp_gain=p.cp_gain,
        two_sqrt_gl=2.0 * jnp.sqrt(p.gravity / p.leg_length),
        sqrt_hg=jnp.sqrt(p.com_height / p.gravity), leg_length=p.leg_length,
        hip_offset_y=p.hip_offset_y, hip_to_ankle_z=p.hip_to_ankle_z, thigh=p.thigh_length,
        calf=p.calf_length, lift=p.lift_height,
        inv_2ltlc=1.0 / (2.0 * p.thigh_length * p.calf_length),
        t_lift=0.5 * gamma * T / dt, t_land=(T - 0.5 * gamma * T) / dt,
        dphase_x=math.pi * dt / (2.0 * swing), dphase_z=math.pi * dt / swing,
        update_ticks=p.cp_update_window / dt + 0.5, cp_mid=0.5 * (p.eps_forward - p.eps_backward))
    words = {k: quantize(jax.lax.stop_gradient(jnp.asarray(v)), coef_format(k, config), "nearest")
             for k, v in values.items()}
    return Coefficients(lateral=jnp.asarray(p.lateral_steps) > 0.5,
                        cp_excess=jnp.asarray(p.cp_excess) > 0.5,
                        cp_update=jnp.asarray(p.cp_update_window) > 0.0, **words)
