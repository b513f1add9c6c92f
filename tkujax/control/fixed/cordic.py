"""CORDIC sin/cos, atan2 (+ vector magnitude), sqrt and acos on fixed-point words.

Iterations run in a `lax.scan` over the (shift, ROM angle) table: fully unrolled, the dozens
of CORDICs of one control step make one giant integer fusion that XLA's CPU backend takes
minutes to compile for batched inputs. Micro-rotation shifts are arithmetic right shifts that
truncate (a hardware CORDIC just wires the bits); the atan / gain ROM constants are rounded to
nearest; the final result is rounded with the configured mode and saturated.

Register formats (guard bits g, n iterations):
  rotation   x, y: Q1.(f_out + g);  z: Q(max(i_in + 1, 3)).(f_in + g)
  vectoring  x, y: Q(i_in + 2).(f_in + g) (gain 1.65 * sqrt 2 < 4);  z: Q3.(f_angle + g)
  sqrt       x, y: Q2.(f_out + g), input normalised by an even shift into [1/4, 1)
Convergence: rotation mode for |z| <= sum atan 2^-i = 1.743 rad, so the input is first wrapped
to [-pi, pi] and folded into [-pi/2, pi/2] (negating the result); vectoring pre-rotates by pi
when x < 0; hyperbolic sqrt uses x = v + 1/4, y = v - 1/4 and repeats iterations 4, 13, 40.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from tkujax.control.fixed.qformat import QFormat, mul, quantize, requant, saturate, shift_var


@dataclasses.dataclass(frozen=True)
class CordicSpec:
    iterations: int = 16
    guard_bits: int = 2
    coef_bits: int = 18
    rounding: str = "nearest"


def spec_of(config) -> CordicSpec:
    """The CORDIC settings of a FixedPointConfig."""
    return CordicSpec(config.cordic_iterations, config.cordic_guard_bits, config.coef_bits,
                      config.rounding)


def _round(v: float) -> int:
    return math.floor(v + 0.5)


def atan_table(n: int, frac_bits: int) -> list[int]:
    """ROM: atan(2^-i) for i < n, rounded to nearest in frac_bits."""
    return [_round(math.atan(2.0 ** -i) * 2 ** frac_bits) for i in range(n)]


def circular_gain(n: int) -> float:
    """K_n = prod_{i<n} sqrt(1 + 2^-2i) (~1.6468)."""
    return math.prod(math.sqrt(1.0 + 4.0 ** -i) for i in range(n))


def hyperbolic_sequence(n: int) -> list[int]:
    """Shift sequence 1, 2, 3, 4, 4, 5, ..., 13, 13, ... (repeats at 4, 13, 40), n entries."""
    seq, i, repeat = [], 1, 4
    while len(seq) < n:
        seq.append(i)
        if i == repeat:
            seq.append(i)
            repeat = 3 * repeat + 1
        i += 1
    return seq[:n]


def hyperbolic_gain(n: int) -> float:
    return math.prod(math.sqrt(1.0 - 4.0 ** -i) for i in hyperbolic_sequence(n))


def _table(shifts, angles) -> tuple[jax.Array, jax.Array]:
    """Per-iteration (shift, ROM angle) as int32 arrays, scanned over."""
    return jnp.asarray(list(shifts), jnp.int32), jnp.asarray(list(angles), jnp.int32)


def _const(v: float, fmt: QFormat) -> int:
    return max(fmt.min_raw, min(fmt.max_raw, _round(v * 2 ** fmt.frac_bits)))


def rotation_formats(fmt_in: QFormat, fmt_out: QFormat, g: int) -> tuple[QFormat, QFormat]:
    return (QFormat(1, fmt_out.frac_bits + g),
            QFormat(max(fmt_in.int_bits + 1, 3), fmt_in.frac_bits + g))


def sincos(theta: jax.Array, fmt_in: QFormat, fmt_out: QFormat, spec: CordicSpec):
    """(cos theta, sin theta) in fmt_out for an angle word theta (rad) in fmt_in, |theta| < 3 pi."""
    g, n = spec.guard_bits, spec.iterations
    fxy, fz = rotation_formats(fmt_in, fmt_out, g)
    pi, half_pi = _const(math.pi, fz), _const(math.pi / 2, fz)
    z = jnp.left_shift(jnp.asarray(theta, jnp.int32), g)
    z = jnp.where(z > pi, z - 2 * pi, z)
    z = jnp.where(z < -pi, z + 2 * pi, z)
    flip = (z > half_pi) | (z < -half_pi)                 # cos, sin (theta -+ pi) = -cos, -sin
    z = jnp.where(z > half_pi, z - pi, jnp.where(z < -half_pi, z + pi, z))
    x = jnp.full_like(z, _const(1.0 / circular_gain(n), fxy))
    y = jnp.zeros_like(z)

    def step(carry, ia):
        x, y, z = carry
        i, a = ia
        up = z >= 0
        dx, dy = jnp.right_shift(y, i), jnp.right_shift(x, i)
        return (jnp.where(up, x - dx, x + dx), jnp.where(up, y + dy, y - dy),
                jnp.where(up, z - a, z + a)), None

    (x, y, z), _ = jax.lax.scan(step, (x, y, z), _table(range(n), atan_table(n, fz.frac_bits)))
    x, y = jnp.where(flip, -x, x), jnp.where(flip, -y, y)
    return requant(x, fxy, fmt_out, spec.rounding), requant(y, fxy, fmt_out, spec.rounding)


def vector_formats(fmt_in: QFormat, fmt_angle: QFormat, g: int) -> tuple[QFormat, QFormat]:
    return fmt_in.widened(2, g), QFormat(3, fmt_angle.frac_bits + g)


def atan2(y: jax.Array, x: jax.Array, fmt_in: QFormat, fmt_angle: QFormat, spec: CordicSpec,
          fmt_mag: QFormat | None = None):
    """Vectoring mode: (atan2(y, x) in fmt_angle, |(x, y)| in fmt_mag or None).

    x, y are words of fmt_in. atan2(0, 0) = 0 (as safe_atan2); the magnitude is x_n / K_n.
    """
    g, n = spec.guard_bits, spec.iterations
    fxy, fz = vector_formats(fmt_in, fmt_angle, g)
    y0 = jnp.asarray(y, jnp.int32)
    x0 = jnp.asarray(x, jnp.int32)
    X, Y = jnp.left_shift(x0, g), jnp.left_shift(y0, g)
    flip = X < 0
    X, Y = jnp.where(flip, -X, X), jnp.where(flip, -Y, Y)
    pi = _const(math.pi, fz)
    z = jnp.where(flip, jnp.where(y0 >= 0, pi, -pi), 0).astype(jnp.int32)

    def step(carry, ia):
        X, Y, z = carry
        i, a = ia
        down = Y >= 0
        dx, dy = jnp.right_shift(Y, i), jnp.right_shift(X, i)
        return (jnp.where(down, X + dx, X - dx), jnp.where(down, Y - dy, Y + dy),
                jnp.where(down, z + a, z - a)), None

    (X, Y, z), _ = jax.lax.scan(step, (X, Y, z), _table(range(n), atan_table(n, fz.frac_bits)))
    z = jnp.where((x0 == 0) & (y0 == 0), 0, z)
    angle = requant(z, fz, fmt_angle, spec.rounding)
    if fmt_mag is None:
        return angle, None
    kf = QFormat(0, spec.coef_bits - 1)
    mag = mul(X, fxy, jnp.int32(_const(1.0 / circular_gain(n), kf)), kf, fmt_mag, spec.rounding)
    return angle, mag


def sqrt_formats(fmt_out: QFormat, g: int) -> QFormat:
    return QFormat(2, fmt_out.frac_bits + g)


def sqrt(v: jax.Array, fmt_in: QFormat, fmt_out: QFormat, spec: CordicSpec) -> jax.Array:
    """sqrt(v) in fmt_out for a word v >= 0 of fmt_in (negative inputs read as 0).

    A leading-zero count picks an even shift e bringing v into [1/4, 1) of the internal format
    (F fraction bits); hyperbolic vectoring gives K_h sqrt(v'); the result is de-normalised by
    a barrel shift of (F - e - f_in) / 2.
    """
    g, n = spec.guard_bits, spec.iterations
    fi = sqrt_formats(fmt_out, g)
    F = fi.frac_bits
    V = jnp.maximum(jnp.asarray(v, jnp.int32), 0)
    bitlen = 32 - jax.lax.clz(V)
    e = F - bitlen - ((fmt_in.frac_bits - bitlen) & 1)     # bit length F or F - 1, parity ok
    Vn = jnp.where(e >= 0, jnp.left_shift(V, jnp.maximum(e, 0)),
                   jnp.right_shift(V, jnp.maximum(-e, 0)))
    quarter = 1 << (F - 2)
    X, Y = Vn + quarter, Vn - quarter

    def step(carry, i):
        X, Y = carry
        down = Y >= 0
        dx, dy = jnp.right_shift(Y, i), jnp.right_shift(X, i)
        return (jnp.where(down, X - dx, X + dx), jnp.where(down, Y - dy, Y + dy)), None

    (X, Y), _ = jax.lax.scan(step, (X, Y), jnp.asarray(hyperbolic_sequence(n), jnp.int32))
    kf = QFormat(1, spec.coef_bits - 2)
    root = mul(X, fi, jnp.int32(_const(1.0 / hyperbolic_gain(n), kf)), kf, fi, spec.rounding)
    # root has F fraction bits and is sqrt(v') ; sqrt(v) = sqrt(v') * 2^k, k = (F - e - f_in)/2
    k = (F - e - fmt_in.frac_bits) >> 1
    out = shift_var(root, F - fmt_out.frac_bits - k, fmt_out, spec.rounding)
    return jnp.where(V == 0, 0, out).astype(jnp.int32)


def acos(c: jax.Array, fmt_unit: QFormat, fmt_angle: QFormat, spec: CordicSpec) -> jax.Array:
    """acos(c) = atan2(sqrt((1 - c)(1 + c)), c) for a unit word c (clipped to [-1, 1])."""
    one = 1 << fmt_unit.frac_bits
    c = jnp.clip(jnp.asarray(c, jnp.int32), -one, one)
    s2 = mul(one - c, fmt_unit, one + c, fmt_unit, fmt_unit, spec.rounding)
    s = sqrt(s2, fmt_unit, fmt_unit, spec)
    return atan2(s, c, fmt_unit, fmt_angle, spec)[0]


def to_angle_word(theta, fmt: QFormat, rounding: str = "nearest") -> jax.Array:
    """Convenience: float radians -> angle word."""
    return saturate(quantize(theta, fmt, rounding), fmt)
