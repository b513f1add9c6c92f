"""Q-format fixed-point arithmetic on int32 words, as an FPGA datapath does it.

A signal in QFormat(i, f) is a signed two's-complement integer `raw` of 1 + i + f bits whose
value is raw * 2^-f (i may be negative for small signals such as a covariance).

Width policy (independent of jax's x64 flag, bit-identical with it on or off):
  * storage is int32 and every word is at most MAX_WORD_BITS = 31 bits, so |raw| <= 2^30 and
    the sum or difference of two words of one format never wraps int32 before saturating;
  * products are exact 62-bit products built from 16-bit limbs in uint32 (`_umul64`), then
    rounded and saturated once, the way a DSP multiplier followed by a rounding/saturation
    stage does; no int64 is ever needed;
  * rounding is "nearest" (add half an LSB, then floor: ties go up, as the usual hardware
    rounding adder) or "truncate" (floor: drop the low bits of the two's-complement word).
Everything saturates at the destination format's limits instead of wrapping.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

MAX_WORD_BITS = 31
ROUNDING_MODES = ("nearest", "truncate")


@dataclasses.dataclass(frozen=True)
class QFormat:
    """Signed fixed-point format: 1 sign bit, int_bits integer bits, frac_bits fraction bits."""

    int_bits: int
    frac_bits: int

    @property
    def word_bits(self) -> int:
        return 1 + self.int_bits + self.frac_bits

    @property
    def max_raw(self) -> int:
        return (1 << (self.word_bits - 1)) - 1

    @property
    def min_raw(self) -> int:
        return -(1 << (self.word_bits - 1))

    @property
    def lsb(self) -> float:
        return 2.0 ** -self.frac_bits

    def widened(self, int_bits: int = 0, frac_bits: int = 0) -> QFormat:
        """This format with extra integer / fraction bits (e.g. CORDIC headroom, guard bits)."""
        return QFormat(self.int_bits + int_bits, self.frac_bits + frac_bits)

    def check(self) -> QFormat:
        if not 2 <= self.word_bits <= MAX_WORD_BITS or self.frac_bits < 0:
            raise ValueError(f"QFormat{(self.int_bits, self.frac_bits)} needs frac_bits >= 0 and "
                             f"a word of [2, {MAX_WORD_BITS}] bits, got {self.word_bits}")
        return self


def saturate(raw: jax.Array, fmt: QFormat) -> jax.Array:
    return jnp.clip(raw, fmt.min_raw, fmt.max_raw).astype(jnp.int32)


def quantize(x, fmt: QFormat, rounding: str = "nearest") -> jax.Array:
    """Float -> raw int32 in fmt (the ADC / register-load boundary). NaN maps to 0.

    x * 2^f is exact in floating point (a power-of-two scale), and the rounding is done with
    floor and an exact fractional-part test, so the result is the exactly rounded value.
    """
    x = jnp.asarray(x)
    x = x.astype(jnp.result_type(x.dtype, jnp.float32))
    y = x * (2.0 ** fmt.frac_bits)
    r = jnp.floor(y)
    if rounding == "nearest":
        r = r + (y - r >= 0.5)
    r = jnp.where(jnp.isnan(r), 0.0, jnp.clip(r, fmt.min_raw, fmt.max_raw))
    return saturate(r.astype(jnp.int32), fmt)


def to_float(raw: jax.Array, fmt: QFormat, dtype=jnp.float32) -> jax.Array:
    """Raw -> float value (exact while the word fits the float's mantissa)."""
    return jnp.asarray(raw).astype(dtype) * (2.0 ** -fmt.frac_bits)


def straight_through(x_float: jax.Array, value: jax.Array) -> jax.Array:
    """`value` in the forward pass, d/dx = 1 in the backward pass (straight-through estimator).

    Written sg(value) + (x - sg(x)) rather than x + sg(value - x): x - x is exactly 0, so the
    forward value is bit-exactly `value`, not value up to a float rounding of the sum.
    """
    sg = jax.lax.stop_gradient
    return sg(value) + (x_float - sg(x_float))


def shift_right(raw: jax.Array, shift: int, rounding: str) -> jax.Array:
    """raw * 2^-shift rounded (static shift >= 0), no saturation needed (magnitude shrinks)."""
    if shift <= 0:
        return raw
    if shift >= MAX_WORD_BITS:           # |raw| <= 2^30 < 2^(shift-1): rounds to 0 or floors to -1
        return jnp.where(raw < 0, -1, 0).astype(jnp.int32) if rounding == "truncate" \
            else jnp.zeros_like(raw, jnp.int32)
    bias = (1 << (shift - 1)) if rounding == "nearest" else 0
    return jnp.right_shift(raw + bias, shift).astype(jnp.int32)   # |raw| + bias < 2^31


def shift_left_sat(raw: jax.Array, shift: int, out: QFormat) -> jax.Array:
    """raw * 2^shift (static shift >= 0), saturated to `out`."""
    if shift <= 0:
        return saturate(raw, out)
    hi, lo = out.max_raw >> shift, -((-out.min_raw) >> shift)
    shifted = jnp.left_shift(jnp.clip(raw, lo, hi), shift)
    return saturate(jnp.where(raw > hi, out.max_raw,
                              jnp.where(raw < lo, out.min_raw, shifted)), out)


def requant(raw: jax.Array, src: QFormat, dst: QFormat, rounding: str) -> jax.Array:
    """Convert a word from src to dst: align the binary point (rounding), then saturate."""
    d = src.frac_bits - dst.frac_bits
    if d >= 0:
        return saturate(shift_right(raw, d, rounding), dst)
    return shift_left_sat(raw, -d, dst)


def add(a: jax.Array, b: jax.Array, fmt: QFormat) -> jax.Array:
    """Saturating a + b, both in fmt (cannot wrap int32: words are <= 31 bits)."""
    return saturate(a + b, fmt)


def sub(a: jax.Array, b: jax.Array, fmt: QFormat) -> jax.Array:
    return saturate(a - b, fmt)


def neg(a: jax.Array, fmt: QFormat) -> jax.Array:
    return saturate(-a, fmt)


def _umul64(a: jax.Array, b: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Exact product of uint32 a, b < 2^31 as (hi, lo) uint32 limbs, from 16-bit halves."""
    m16 = jnp.uint32(0xFFFF)
    al, ah = a & m16, a >> 16
    bl, bh = b & m16, b >> 16
    ll = al * bl                              # < 2^32
    mid = al * bh + ah * bl                   # each < 2^31, sum < 2^32
    lo = ll + (mid << 16)                     # mod 2^32
    carry = (lo < ll).astype(jnp.uint32)
    hi = ah * bh + (mid >> 16) + carry
    return hi, lo


def _split(v: int) -> tuple[int, int]:
    return v >> 32, v & 0xFFFFFFFF


def mul(a: jax.Array, fa: QFormat, b: jax.Array, fb: QFormat, out: QFormat,
        rounding: str) -> jax.Array:
    """Saturating a * b rounded once into `out` (exact up to the final rounding).

    Works on magnitudes (|a|, |b| <= 2^30 fit uint32); the rounding bias depends on the sign so
    that the result equals floor(a*b*2^-s) ("truncate") or floor(a*b*2^-s + 1/2) ("nearest") of
    the signed product, as a two's-complement multiplier would give.
    """
    u32 = jnp.uint32
    a, b = jnp.asarray(a, jnp.int32), jnp.asarray(b, jnp.int32)
    negative = (a < 0) != (b < 0)
    hi, lo = _umul64(jnp.abs(a).astype(u32), jnp.abs(b).astype(u32))
    s = fa.frac_bits + fb.frac_bits - out.frac_bits
    if s > 0:
        # floor(-m/2^s) = -floor((m + 2^s - 1)/2^s);
        # floor(-m/2^s + 1/2) = -floor((m + 2^(s-1) - 1)/2^s)
        b_pos = (1 << (s - 1)) if rounding == "nearest" else 0
        b_neg = (1 << (s - 1)) - 1 if rounding == "nearest" else (1 << s) - 1
        (ph, pl), (nh, nl) = _split(b_pos), _split(b_neg)
        bias_hi = jnp.where(negative, u32(nh), u32(ph))
        bias_lo = jnp.where(negative, u32(nl), u32(pl))
        lo2 = lo + bias_lo
        hi = hi + bias_hi + (lo2 < lo).astype(u32)
        lo = lo2
        if s >= 32:
            hi, lo = jnp.zeros_like(hi), hi >> (s - 32) if s > 32 else hi
        else:
            hi, lo = hi >> s, (lo >> s) | (hi << (32 - s))
    elif s < 0:
        k = -s                                # exact left shift; overflow detected below
        over_k = (hi != 0) | (lo >= u32(1 << (32 - k))) if k < 32 else (hi != 0) | (lo != 0)
        hi = jnp.where(over_k, u32(1), u32(0))
        lo = lo << k if k < 32 else jnp.zeros_like(lo)
    limit = jnp.where(negative, u32(-out.min_raw), u32(out.max_raw))
    mag = jnp.where((hi != 0) | (lo > limit), limit, lo).astype(jnp.int32)   # <= 2^30
    return jnp.where(negative, -mag, mag).astype(jnp.int32)


def div_fraction(num: jax.Array, den: jax.Array, out: QFormat, rounding: str) -> jax.Array:
    """num / den in [0, 1] for words 0 <= num <= den of one format: a restoring divider.

    One quotient bit per cycle, out.frac_bits cycles, then an optional rounding bit. num is
    clamped to [0, den] and den to >= 1, so the result is always in [0, 1] (hardware guard).
    """
    den = jnp.maximum(jnp.asarray(den, jnp.int32), 1)
    r = jnp.clip(jnp.asarray(num, jnp.int32), 0, den)
    q = jnp.zeros_like(r)
    whole = r >= den                          # num == den: quotient exactly 1
    r = jnp.where(whole, 0, r)
    for _ in range(out.frac_bits):
        r = r << 1                            # r < den <= 2^30, so 2r < 2^31
        bit = r >= den
        r = jnp.where(bit, r - den, r)
        q = (q << 1) | bit.astype(jnp.int32)
    if rounding == "nearest":
        q = q + ((r << 1) >= den).astype(jnp.int32)
    q = jnp.where(whole, 1 << out.frac_bits, q)
    return saturate(q, out)


def shift_var(raw: jax.Array, shift: jax.Array, out: QFormat, rounding: str) -> jax.Array:
    """raw * 2^-shift for a traced shift (negative = left), rounded and saturated to `out`.

    A barrel shifter; used where the shift depends on data (the sqrt normaliser).
    """
    raw = jnp.asarray(raw, jnp.int32)
    shift = jnp.asarray(shift, jnp.int32)
    r = jnp.clip(shift, 0, MAX_WORD_BITS - 1)
    bias = jnp.where(r > 0, jnp.left_shift(1, jnp.maximum(r - 1, 0)), 0) \
        if rounding == "nearest" else 0
    right = jnp.right_shift(raw + bias, r)
    k = jnp.clip(-shift, 0, MAX_WORD_BITS - 1)
    hi, lo = jnp.right_shift(out.max_raw, k), -jnp.right_shift(-out.min_raw, k)
    left = jnp.where(raw > hi, out.max_raw,
                     jnp.where(raw < lo, out.min_raw, jnp.left_shift(jnp.clip(raw, lo, hi), k)))
    return saturate(jnp.where(shift >= 0, right, left), out)
