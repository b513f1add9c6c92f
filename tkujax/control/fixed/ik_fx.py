"""Fixed-point leg inverse kinematics (Eq. 19-28), the exact form of `tkujax.control.ik` and
`tkujax.control.solve`, every trig function by CORDIC.

Per leg, on length words (m) -> angle words (rad):
  pelvis frame: p' = R_y(lean)^T (p - hip)           (sin/cos of the lean by CORDIC rotation)
  hip_roll, L' = atan2(p_y, -p_z), |(p_y, p_z)|      (vectoring)
  target, D    = atan2(-p_x, L'), |(p_x, L')|        (vectoring)
  cos knee     = (D^2 - l_t^2 - l_c^2) / (2 l_t l_c), D clipped to [|l_t - l_c|, l_t + l_c]
  knee         = acos(cos knee) = atan2(sqrt((1 - c)(1 + c)), c)   (hyperbolic sqrt + vectoring)
  hip_pitch    = target - atan2(l_c sin knee, l_t + l_c cos knee)
  sole level:  sole_pitch = atan2(-sin lean, cos roll cos lean),
               ankle_roll = atan2(-sin roll cos lean, |(sin lean, cos roll cos lean)|),
               ankle_pitch = sole_pitch - hip_pitch - knee.
Unlike the float IK, D is clipped to the exact shell (no 1e-6 margin): integers have no
infinite derivative to avoid.

Internal lengths (the pelvis-frame ankle position, L', D, the law-of-cosines offsets) are words
of `config.ik_length`: the `length` format with `ik_guard_bits` more fraction bits. The CPG's
targets enter in `length` and are shifted left exactly. Why: the knee moves
dknee/dD = 2 D / (2 l_t l_c sin knee) = 22 rad/m at the stand pose (D = 0.2 m, l_t = l_c =
0.11 m), so rounding D to the 7.6 um `length` LSB alone moved the knee by up to 0.17 mrad (the
measured stand-pose knee error was 0.21 mrad, 0.14 of the servo's 1.53 mrad step). Commands that
close to a servo rounding boundary flip by one servo step against the float controller.

What remains (bound): with the guard bits the commands differ from the float ones by eps ~
0.1-0.2 mrad before the servos' rounding (measured), so after it by at most one servo step
s = 2 pi / 4096 per joint, and only where the float value lies within eps of a rounding
boundary. Moving joint j by dq moves the ankle by exactly 2 r_j sin(dq / 2) <= r_j dq, r_j the
ankle's distance from that axis (<= l_t + l_c for hip roll and hip pitch, l_c for the knee, 0
for the ankle axes; hip yaw is 0). Over both legs the commanded step (left ankle x - right
ankle x) therefore differs by <= 2 dq (2 l_t + 3 l_c): 1.69 mm with dq = s, and 2 eps (2 l_t +
3 l_c) before rounding (tests/test_fixed_point.py::test_commanded_step_length_within_its_bound).
The realised step in the physics has no such bound (contact amplifies a one-step flip; see
results/fpga/README.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.control.fixed import cordic
from tkujax.control.fixed.coefficients import Coefficients, coef_format
from tkujax.control.fixed.config import FixedPointConfig
from tkujax.control.fixed.qformat import QFormat, add, mul, neg, requant, sub


def area_format(config: FixedPointConfig) -> QFormat:
    """m^2 words of D^2 and l^2: 4 more fraction bits than the IK's lengths, within 31 bits."""
    i = 2 * config.length.int_bits + 1
    return QFormat(i, min(config.ik_length.frac_bits + 4, 30 - i))


def leg_ik_fx(p: jax.Array, thigh: jax.Array, calf: jax.Array, inv_2ltlc: jax.Array,
              config: FixedPointConfig):
    """(..., 3) ankle-from-hip words of `config.ik_length` in the pelvis frame; thigh, calf:
    `length` words -> (hip_roll, hip_pitch, knee, reachable), angles in `angle`."""
    c, rnd, spec = config, config.rounding, cordic.spec_of(config)
    fu, fa, fq = c.unit, c.angle, area_format(config)
    fl = c.ik_length
    th, ca = (requant(v, c.length, fl, rnd) for v in (thigh, calf))   # exact left shifts
    px, py, pz = p[..., 0], p[..., 1], p[..., 2]
    hip_roll, l_plane = cordic.atan2(py, neg(pz, fl), fl, fa, spec, fmt_mag=fl)
    target, dist = cordic.atan2(neg(px, fl), l_plane, fl, fa, spec, fmt_mag=fl)
    lo = jnp.abs(sub(th, ca, fl))
    hi = add(th, ca, fl)
    reachable = (dist >= lo) & (dist <= hi)
    d = jnp.clip(dist, lo, hi)
    sq = lambda v: mul(v, fl, v, fl, fq, rnd)            # noqa: E731
    num = sub(sub(sq(d), sq(th), fq), sq(ca), fq)
    cos_k = mul(num, fq, inv_2ltlc, coef_format("inv_2ltlc", c), fu, rnd)
    one = 1 << fu.frac_bits
    cos_k = jnp.clip(cos_k, -one, one)
    sin_k = cordic.sqrt(mul(one - cos_k, fu, one + cos_k, fu, fu, rnd), fu, fu, spec)
    knee, _ = cordic.atan2(sin_k, cos_k, fu, fa, spec)     # = cordic.acos(cos_k)
    off_y = mul(calf, c.length, sin_k, fu, fl, rnd)
    off_x = add(th, mul(calf, c.length, cos_k, fu, fl, rnd), fl)
    offset, _ = cordic.atan2(off_y, off_x, fl, fa, spec)
    hip_pitch = sub(target, offset, fa)
    return hip_roll, hip_pitch, knee, reachable


def solve_leg_fx(p_ankle: jax.Array, hip_y: jax.Array, coef: Coefficients,
                 config: FixedPointConfig):
    """One leg: (..., 3) ankle word relative to the waist (level frame) -> ((..., 6) angle
    words [hip_yaw, hip_roll, hip_pitch, knee, ankle_pitch, ankle_roll], reachable)."""
    c, rnd, spec = config, config.rounding, cordic.spec_of(config)
    fl, fu, fa, fk = c.length, c.unit, c.angle, c.ik_length
    cos_l, sin_l = cordic.sincos(coef.standing_lean, fa, fu, spec)
    x, y, z = p_ankle[..., 0], sub(p_ankle[..., 1], hip_y, fl), p_ankle[..., 2]
    m = lambda a, b: mul(a, fl, b, fu, fk, rnd)          # noqa: E731
    p = jnp.stack([sub(m(x, cos_l), m(z, sin_l), fk), requant(y, fl, fk, rnd),
                   add(m(x, sin_l), m(z, cos_l), fk)], -1)
    hip_roll, hip_pitch, knee, ok = leg_ik_fx(p, coef.thigh, coef.calf, coef.inv_2ltlc, c)
    cos_r, sin_r = cordic.sincos(hip_roll, fa, fu, spec)
    m22 = mul(cos_r, fu, cos_l, fu, fu, rnd)
    m12 = mul(sin_r, fu, cos_l, fu, fu, rnd)
    sole_pitch, hyp = cordic.atan2(neg(sin_l, fu), m22, fu, fa, spec, fmt_mag=fu)
    ankle_roll, _ = cordic.atan2(neg(m12, fu), hyp, fu, fa, spec)
    ankle_pitch = sub(sub(sole_pitch, hip_pitch, fa), knee, fa)
    zero = jnp.zeros_like(knee)
    return jnp.stack([zero, hip_roll, hip_pitch, knee, ankle_pitch, ankle_roll], -1), ok


def solve_legs_fx(p_right: jax.Array, p_left: jax.Array, coef: Coefficients,
                  config: FixedPointConfig):
    """Both legs -> ((..., 12) angle words in LEG_ACTUATORS order, reachable).

    The legs are stacked on one axis so each CORDIC is built once for both (half the program).
    """
    d_y = coef.hip_offset_y
    p = jnp.stack([p_right, p_left], -2)
    hip_y = jnp.broadcast_to(jnp.stack([-d_y, d_y]), p.shape[:-1])
    angles, ok = solve_leg_fx(p, hip_y, coef, config)
    return angles.reshape(angles.shape[:-2] + (12,)), ok[..., 0] & ok[..., 1]
