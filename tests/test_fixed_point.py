"""Fixed-point controller twin (tkujax.control.fixed).

(a) bit-exact against an independent reference in plain Python ints (below: no numpy or jax in
    it, Python's >> is the floor of a two's-complement shift and its ints never overflow);
(b) CORDIC errors within their theoretical bounds for each iteration count;
(c) with wide words the fixed-point controller_step tracks the float one over a push trace.
"""

from __future__ import annotations

import functools
import math
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control import ControllerParams, Sensors, controller_init, controller_step
from tkujax.control.fixed import (FixedPointConfig, QFormat, accel_to_angle_fx, coef_format,
                                  coefficients, controller_init_fx, controller_step_fx,
                                  cpg_feet_fx, kalman_step_fx, quantize, servo_switch_substep,
                                  solve_legs_fx, step_length_fx)
from tkujax.control.fixed import cordic, qformat

# ------------------------------------------------------------------ plain-int reference


def r_sat(v, f):
    lim = 1 << (1 + f.int_bits + f.frac_bits - 1)
    return max(-lim, min(lim - 1, v))


def r_rshift(v, s, rnd):
    if s <= 0:
        return v << -s
    return (v + ((1 << (s - 1)) if rnd == "nearest" else 0)) >> s


def r_requant(v, src, dst, rnd):
    return r_sat(r_rshift(v, src.frac_bits - dst.frac_bits, rnd), dst)


def r_mul(a, fa, b, fb, fo, rnd):
    return r_sat(r_rshift(a * b, fa.frac_bits + fb.frac_bits - fo.frac_bits, rnd), fo)


def r_div(num, den, fo, rnd):
    den = max(den, 1)
    num = max(0, min(num, den)) << fo.frac_bits
    q = num // den if rnd == "truncate" else (2 * num + den) // (2 * den)
    return r_sat(q, fo)


def r_quantize(x, f, rnd):
    y = Fraction(float(x)) * 2 ** f.frac_bits
    return r_sat(math.floor(y + (Fraction(1, 2) if rnd == "nearest" else 0)), f)


def r_const(v, f):
    return r_sat(math.floor(v * 2 ** f.frac_bits + 0.5), f)


def r_sincos(theta, fin, fout, n, g, cb, rnd):
    fxy = QFormat(1, fout.frac_bits + g)
    fz = QFormat(max(fin.int_bits + 1, 3), fin.frac_bits + g)
    pi, hp = r_const(math.pi, fz), r_const(math.pi / 2, fz)
    z = theta << g
    if z > pi:
        z -= 2 * pi
    if z < -pi:
        z += 2 * pi
    flip = abs(z) > hp
    if z > hp:
        z -= pi
    elif z < -hp:
        z += pi
    k = math.prod(math.sqrt(1 + 4.0 ** -i) for i in range(n))
    x, y = r_const(1 / k, fxy), 0
    for i in range(n):
        a = r_const(math.atan(2.0 ** -i), QFormat(8, fz.frac_bits))
        if z >= 0:
            x, y, z = x - (y >> i), y + (x >> i), z - a
        else:
            x, y, z = x + (y >> i), y - (x >> i), z + a
    if flip:
        x, y = -x, -y
    return r_requant(x, fxy, fout, rnd), r_requant(y, fxy, fout, rnd)


def r_atan2(y0, x0, fin, fang, n, g, cb, rnd, fmag=None):
    fxy, fz = QFormat(fin.int_bits + 2, fin.frac_bits + g), QFormat(3, fang.frac_bits + g)
    X, Y, z = x0 << g, y0 << g, 0
    if X < 0:
        X, Y, z = -X, -Y, (r_const(math.pi, fz) if y0 >= 0 else -r_const(math.pi, fz))
    for i in range(n):
        a = r_const(math.atan(2.0 ** -i), QFormat(8, fz.frac_bits))
        if Y >= 0:
            X, Y, z = X + (Y >> i), Y - (X >> i), z + a
        else:
            X, Y, z = X - (Y >> i), Y + (X >> i), z - a
    if x0 == 0 and y0 == 0:
        z = 0
    ang = r_requant(z, fz, fang, rnd)
    if fmag is None:
        return ang, None
    kf = QFormat(0, cb - 1)
    k = math.prod(math.sqrt(1 + 4.0 ** -i) for i in range(n))
    return ang, r_mul(X, fxy, r_const(1 / k, kf), kf, fmag, rnd)


def r_hyp_seq(n):
    seq, i = [], 1
    while len(seq) < n:
        seq.append(i)
        if i in (4, 13, 40):
            seq.append(i)
        i += 1
    return seq[:n]


def r_sqrt(v, fin, fout, n, g, cb, rnd):
    V = max(v, 0)
    if V == 0:
        return 0
    F = fout.frac_bits + g
    fi = QFormat(2, F)
    b = V.bit_length()
    e = F - b - ((fin.frac_bits - b) % 2)
    Vn = V << e if e >= 0 else V >> -e
    X, Y = Vn + (1 << (F - 2)), Vn - (1 << (F - 2))
    seq = r_hyp_seq(n)
    for i in seq:
        if Y >= 0:
            X, Y = X - (Y >> i), Y - (X >> i)
        else:
            X, Y = X + (Y >> i), Y + (X >> i)
    kh = math.prod(math.sqrt(1 - 4.0 ** -i) for i in seq)
    kf = QFormat(1, cb - 2)
    root = r_mul(X, fi, r_const(1 / kh, kf), kf, fi, rnd)
    k = (F - e - fin.frac_bits) // 2
    return r_sat(r_rshift(root, F - fout.frac_bits - k, rnd), fout)


class Ref:
    """The four modules on Python ints, mirroring the documented dataflow."""

    def __init__(self, cfg, coef):
        self.c, self.k = cfg, {f: int(getattr(coef, f)) for f in coef.__dataclass_fields__}
        self.cs = (cfg.cordic_iterations, cfg.cordic_guard_bits, cfg.coef_bits, cfg.rounding)

    def cf(self, name):
        return coef_format(name, self.c)

    def accel_to_angle(self, ax, ay, az):
        c = self.c
        roll, r = r_atan2(ay, az, c.accel, c.angle, *self.cs, fmag=c.accel)
        pitch, _ = r_atan2(-ax, r, c.accel, c.angle, *self.cs)
        return pitch, roll

    def kalman(self, phi, p, rate, ang):
        c, k, rnd = self.c, self.k, self.c.rounding
        phi = r_sat(phi + r_mul(rate, c.rate, k["dt"], self.cf("dt"), c.state, rnd), c.state)
        p = r_sat(p + k["kalman_q"], c.cov)
        gain = r_div(p, r_sat(p + k["kalman_r"], c.cov), c.unit, rnd)
        innov = r_sat(r_requant(ang, c.angle, c.state, rnd) - phi, c.state)
        phi = r_sat(phi + r_mul(gain, c.unit, innov, c.state, c.state, rnd), c.state)
        p = r_mul(r_sat((1 << c.unit.frac_bits) - gain, c.unit), c.unit, p, c.cov, c.cov, rnd)
        return phi, p

    def step_length(self, theta):
        c, k, rnd = self.c, self.k, self.c.rounding
        fine = QFormat(c.angle.int_bits, c.angle.frac_bits + 1)
        cos_t, sin_t = r_sincos(theta << 1, fine, c.unit, *self.cs)
        _, sin_h = r_sincos(theta, fine, c.unit, *self.cs)
        phidot = r_mul(k["two_sqrt_gl"], self.cf("two_sqrt_gl"), sin_h, c.unit, c.rate, rnd)
        a = r_mul(phidot, c.rate, k["sqrt_hg"], self.cf("sqrt_hg"), c.unit, rnd)
        x_com = r_mul(k["leg_length"], c.length, sin_t, c.unit, c.length, rnd)
        l_cos = r_mul(k["leg_length"], c.length, cos_t, c.unit, c.length, rnd)
        cp = r_sat(x_com + r_mul(l_cos, c.length, a, c.unit, c.length, rnd), c.length)
        return r_mul(k["cp_gain"], self.cf("cp_gain"), cp, c.length, c.length, rnd)

    def cpg(self, n, x_sup, y_sup):
        c, k, rnd, fl = self.c, self.k, self.c.rounding, self.c.length
        ft = self.cf("t_lift")
        n = max(-(1 << ft.int_bits) + 1, min((1 << ft.int_bits) - 1, n))
        t = n << ft.frac_bits
        in_swing, landed = k["t_lift"] <= t < k["t_land"], t >= k["t_land"]
        s = r_sat(t - k["t_lift"], ft)
        sx = r_sincos(r_mul(s, ft, k["dphase_x"], self.cf("dphase_x"), c.angle, rnd),
                      c.angle, c.unit, *self.cs)[1]
        sz = r_sincos(r_mul(s, ft, k["dphase_z"], self.cf("dphase_z"), c.angle, rnd),
                      c.angle, c.unit, *self.cs)[1]
        ux = sx if in_swing else ((1 << c.unit.frac_bits) if landed else 0)
        uz = sz if in_swing else 0
        half = QFormat(fl.int_bits - 1, fl.frac_bits + 1)
        hx, hy = (r_mul(v, half, ux, c.unit, fl, rnd) for v in (x_sup, y_sup))
        lift = r_mul(k["lift"], fl, uz, c.unit, fl, rnd)
        left = y_sup >= 0
        sx, sy = (hx, hy) if left else (r_sat(-hx, fl), r_sat(-hy, fl))
        z0 = -k["hip_to_ankle_z"]
        p_l = (sx, r_sat(k["hip_offset_y"] + sy, fl), r_sat(z0 + (lift if left else 0), fl))
        p_r = (r_sat(-sx, fl), r_sat(-k["hip_offset_y"] - sy, fl),
               r_sat(z0 + (0 if left else lift), fl))
        return p_r, p_l

    def solve_leg(self, p, hip_y):
        c, k, rnd = self.c, self.k, self.c.rounding
        fl, fu, fa = c.length, c.unit, c.angle
        # The IK's internal lengths: ik_guard_bits more fraction bits, the word <= 26 bits.
        fk = QFormat(fl.int_bits, fl.frac_bits + max(0, min(c.ik_guard_bits, 26 - fl.word_bits)))
        li = 2 * fl.int_bits + 1
        fq = QFormat(li, min(fk.frac_bits + 4, 30 - li))
        cl, sl = r_sincos(k["standing_lean"], fa, fu, *self.cs)
        x, y, z = p[0], r_sat(p[1] - hip_y, fl), p[2]
        m = lambda a, b: r_mul(a, fl, b, fu, fk, rnd)  # noqa: E731
        px, py, pz = (r_sat(m(x, cl) - m(z, sl), fk), r_requant(y, fl, fk, rnd),
                      r_sat(m(x, sl) + m(z, cl), fk))
        roll, lp = r_atan2(py, r_sat(-pz, fk), fk, fa, *self.cs, fmag=fk)
        target, dist = r_atan2(r_sat(-px, fk), lp, fk, fa, *self.cs, fmag=fk)
        th, ca = (r_requant(k[n], fl, fk, rnd) for n in ("thigh", "calf"))
        lo, hi = abs(r_sat(th - ca, fk)), r_sat(th + ca, fk)
        ok = lo <= dist <= hi
        d = max(lo, min(hi, dist))
        sq = lambda v: r_mul(v, fk, v, fk, fq, rnd)  # noqa: E731
        num = r_sat(r_sat(sq(d) - sq(th), fq) - sq(ca), fq)
        one = 1 << fu.frac_bits
        cos_k = max(-one, min(one, r_mul(num, fq, k["inv_2ltlc"], self.cf("inv_2ltlc"), fu, rnd)))
        sin_k = r_sqrt(r_mul(one - cos_k, fu, one + cos_k, fu, fu, rnd), fu, fu, *self.cs)
        knee, _ = r_atan2(sin_k, cos_k, fu, fa, *self.cs)
        off_y = r_mul(k["calf"], fl, sin_k, fu, fk, rnd)
        off_x = r_sat(th + r_mul(k["calf"], fl, cos_k, fu, fk, rnd), fk)
        offset, _ = r_atan2(off_y, off_x, fk, fa, *self.cs)
        pitch = r_sat(target - offset, fa)
        cr, sr = r_sincos(roll, fa, fu, *self.cs)
        m22, m12 = r_mul(cr, fu, cl, fu, fu, rnd), r_mul(sr, fu, cl, fu, fu, rnd)
        sole, hyp = r_atan2(r_sat(-sl, fu), m22, fu, fa, *self.cs, fmag=fu)
        aroll, _ = r_atan2(r_sat(-m12, fu), hyp, fu, fa, *self.cs)
        apitch = r_sat(r_sat(sole - pitch, fa) - knee, fa)
        return [0, roll, pitch, knee, apitch, aroll], ok


# ------------------------------------------------------------------ configurations

PARAMS = ControllerParams.paper()
DEFAULT = FixedPointConfig(straight_through=False)
ODD = FixedPointConfig(angle=QFormat(3, 12), rate=QFormat(4, 10), length=QFormat(1, 14),
                       accel=QFormat(2, 11), unit=QFormat(1, 13), state=QFormat(2, 16),
                       cov=QFormat(-4, 17), coef_bits=14, cordic_iterations=9,
                       cordic_guard_bits=0, rounding="truncate", straight_through=False)
CONFIGS = [pytest.param(DEFAULT, id="default"), pytest.param(ODD, id="odd-truncate")]
N = 48


def rand_words(rng, fmt, n, scale=1.0):
    lim = int(scale * fmt.max_raw)
    return rng.integers(-lim, lim + 1, size=n).astype(np.int32)


def ints(a):
    return [int(v) for v in np.asarray(a).ravel()]


# ------------------------------------------------------------------ (a) bit-exact


@pytest.mark.parametrize("rnd", ["nearest", "truncate"])
def test_word_arithmetic_bit_exact(rnd):
    rng = np.random.default_rng(1)
    fa, fb = QFormat(3, 20), QFormat(-2, 27)
    a, b = rand_words(rng, fa, 400), rand_words(rng, fb, 400)
    a[:4] = [fa.max_raw, fa.min_raw, 0, -1]
    b[:4] = [fb.min_raw, fb.min_raw, fb.max_raw, 1]
    for fo in (QFormat(2, 10), QFormat(0, 29), QFormat(5, 25), QFormat(10, 18)):
        got = ints(jax.jit(lambda a, b, fo=fo: qformat.mul(a, fa, b, fb, fo, rnd))(a, b))
        assert got == [r_mul(int(x), fa, int(y), fb, fo, rnd) for x, y in zip(a, b)], fo
        got = ints(qformat.requant(jnp.asarray(a), fa, fo, rnd))
        assert got == [r_requant(int(x), fa, fo, rnd) for x in a], fo
    den = np.abs(a) + 1
    num = (rng.random(400) * den).astype(np.int32)
    num[:2] = den[:2]
    got = ints(qformat.div_fraction(jnp.asarray(num), jnp.asarray(den), QFormat(1, 22), rnd))
    assert got == [r_div(int(x), int(y), QFormat(1, 22), rnd) for x, y in zip(num, den)]
    x = np.float32(rng.normal(size=400) * 3.0)
    got = ints(quantize(jnp.asarray(x), QFormat(2, 20), rnd))
    assert got == [r_quantize(v, QFormat(2, 20), rnd) for v in x]


@pytest.mark.parametrize("cfg", CONFIGS)
def test_cordic_primitives_bit_exact(cfg):
    rng = np.random.default_rng(2)
    spec = cordic.spec_of(cfg)
    cs = (cfg.cordic_iterations, cfg.cordic_guard_bits, cfg.coef_bits, cfg.rounding)
    fa, fu, fl = cfg.angle, cfg.unit, cfg.length
    th = rand_words(rng, fa, N)
    c, s = jax.jit(lambda t: cordic.sincos(t, fa, fu, spec))(th)
    assert list(zip(ints(c), ints(s))) == [r_sincos(int(t), fa, fu, *cs) for t in th]
    x, y = rand_words(rng, fl, N, 0.3), rand_words(rng, fl, N, 0.3)
    x[:3], y[:3] = [0, -5, -5], [0, 0, -7]
    ang, mag = jax.jit(lambda y, x: cordic.atan2(y, x, fl, fa, spec, fmt_mag=fl))(y, x)
    ref = [r_atan2(int(b), int(a), fl, fa, *cs, fmag=fl) for a, b in zip(x, y)]
    assert list(zip(ints(ang), ints(mag))) == ref
    v = np.abs(rand_words(rng, fl, N)) >> rng.integers(0, 12, N).astype(np.int32)
    v[:2] = [0, 1]
    got = ints(jax.jit(lambda v: cordic.sqrt(v, fl, fu, spec))(v))
    assert got == [r_sqrt(int(w), fl, fu, *cs) for w in v]
    cw = rand_words(rng, fu, N, 0.5)
    got = ints(jax.jit(lambda c: cordic.acos(c, fu, fa, spec))(cw))
    one = 1 << fu.frac_bits
    ref = []
    for w in cw:
        w = max(-one, min(one, int(w)))
        s = r_sqrt(r_mul(one - w, fu, one + w, fu, fu, cfg.rounding), fu, fu, *cs)
        ref.append(r_atan2(s, w, fu, fa, *cs)[0])
    assert got == ref


@pytest.mark.parametrize("lateral", [0.0, 1.0])
@pytest.mark.parametrize("cfg", CONFIGS)
def test_modules_bit_exact(cfg, lateral):
    import dataclasses
    params = dataclasses.replace(PARAMS, lateral_steps=lateral)
    coef = coefficients(params, cfg)
    ref = Ref(cfg, coef)
    rng = np.random.default_rng(3 + int(lateral))
    # Kalman: accelerometer inclination and one update.
    acc = np.stack([rand_words(rng, cfg.accel, N, 0.3) for _ in range(3)], -1)
    angles = ints(jax.jit(lambda a: accel_to_angle_fx(a, cfg))(acc))
    assert angles == [v for a in acc for v in ref.accel_to_angle(*map(int, a))]
    phi, rate = rand_words(rng, cfg.state, N, 0.2), rand_words(rng, cfg.rate, N, 0.2)
    p = np.abs(rand_words(rng, cfg.cov, N, 0.5))
    ang = rand_words(rng, cfg.angle, N, 0.2)
    got = jax.jit(lambda *a: kalman_step_fx(*a, coef, cfg))(phi, p, rate, ang)
    assert list(zip(*map(ints, got))) == [ref.kalman(*map(int, t)) for t in zip(phi, p, rate, ang)]
    # Capture point.
    theta = rand_words(rng, cfg.angle, N, 0.15)
    got = ints(jax.jit(lambda t: step_length_fx(t, coef, cfg))(theta))
    assert got == [ref.step_length(int(t)) for t in theta]
    # CPG, including before, during and after the step.
    n = rng.integers(-3, 14, N).astype(np.int32)
    xs, ys = rand_words(rng, cfg.length, N, 0.15), rand_words(rng, cfg.length, N, 0.1 * lateral)
    pr, pl = jax.jit(lambda *a: cpg_feet_fx(*a, coef, cfg))(n, xs, ys)
    refs = [ref.cpg(*map(int, t)) for t in zip(n, xs, ys)]
    assert [tuple(ints(a)) for a in np.asarray(pr)] == [r[0] for r in refs]
    assert [tuple(ints(a)) for a in np.asarray(pl)] == [r[1] for r in refs]
    # IK of both legs on feet around the stand pose, a few out of reach.
    base = np.asarray(pr)
    jitter = lambda s: np.stack([rand_words(rng, cfg.length, N, s) for _ in range(3)], -1)  # noqa
    p_r = (base + jitter(0.04)).astype(np.int32)
    p_l = (np.asarray(pl) + jitter(0.04)).astype(np.int32)
    p_r[:3, 2] = -int(0.3 * 2 ** cfg.length.frac_bits)      # beyond the 0.22 m leg
    legs, ok = jax.jit(lambda a, b: solve_legs_fx(a, b, coef, cfg))(p_r, p_l)
    hy = int(coef.hip_offset_y)
    for i in range(N):
        r_r, ok_r = ref.solve_leg(ints(p_r[i]), -hy)
        r_l, ok_l = ref.solve_leg(ints(p_l[i]), hy)
        assert ints(legs[i]) == r_r + r_l, i
        assert bool(ok[i]) == (ok_r and ok_l)
    assert not bool(ok[0])


def test_coefficients_are_rounded_parameters():
    coef = coefficients(PARAMS, DEFAULT)
    for name, v in [("dt", PARAMS.control_period), ("leg_length", PARAMS.leg_length),
                    ("kalman_r", PARAMS.kalman_r), ("eps_forward", PARAMS.eps_forward),
                    ("two_sqrt_gl", 2 * math.sqrt(PARAMS.gravity / PARAMS.leg_length))]:
        f = coef_format(name, DEFAULT)
        assert (abs(int(getattr(coef, name)) - v * 2 ** f.frac_bits)
                <= 0.5 + 1e-6 * abs(v) * 2 ** f.frac_bits)


# ------------------------------------------------------------------ (b) CORDIC error bounds
#
# Rotation (sin/cos of an angle word theta):   |err| <= atan(2^-(n-1))            residual angle
#     + (n + 2) / 2 * lsb_z         atan ROM and pi, pi/2 constants rounded to nearest
#     + (2.33 n + 0.83) * lsb_xy    one truncated LSB per shift and component, times the gain
#     + lsb_out / 2                 final rounding.
# Vectoring (atan2 of a vector of length r):  |err| <= atan(2^-(n-1)) + (n + 1) / 2 * lsb_z
#     + 2.33 (n + 1) * lsb_xy / r + lsb_out / 2.
# Hyperbolic sqrt: |err| <= sqrt(v) * (cosh(res) - 1 + 6 (n + 2) lsb_F) + lsb_out, with res
#     the worst residual hyperbolic angle of the exact-arithmetic iteration (interval bound
#     below; close to, but not always within, atanh(2^-s_last) of the last shift): x_n^2 -
#     y_n^2 is invariant up to the gain, so x_n = K_h sqrt(v) cosh(res).


HYPERBOLIC_THETA_MAX = math.atanh(0.6)


def hyperbolic_residual_bound(seq, theta_max=HYPERBOLIC_THETA_MAX):
    """Bound on |theta_n| over theta_0 in [0, theta_max] (v' in [1/4, 1) gives y/x < 0.6) for
    theta <- |theta - atanh 2^-s| (sign-symmetric), by interval propagation."""
    lo, hi = 0.0, theta_max
    for s in seq:
        a = math.atanh(2.0 ** -s)
        if lo <= a <= hi:
            lo, hi = 0.0, max(a - lo, hi - a)
        else:
            lo, hi = sorted((abs(lo - a), abs(hi - a)))
    return hi

BOUND_CFG = dict(guard_bits=3, coef_bits=28, rounding="nearest")


@pytest.mark.parametrize("n", [3, 5, 8, 12, 16, 20, 24])
def test_cordic_error_within_theoretical_bound(n):
    spec = cordic.CordicSpec(n, **BOUND_CFG)
    fa, fo = QFormat(2, 23), QFormat(1, 24)
    g = spec.guard_bits
    rng = np.random.default_rng(10 + n)
    th = rng.integers(-int(3.1 * 2 ** 23), int(3.1 * 2 ** 23), 400).astype(np.int32)
    c, s = jax.jit(lambda t: cordic.sincos(t, fa, fo, spec))(th)
    t = th / 2.0 ** 23
    err = max(np.max(np.abs(np.asarray(c) / 2.0 ** 24 - np.cos(t))),
              np.max(np.abs(np.asarray(s) / 2.0 ** 24 - np.sin(t))))
    resid = math.atan(2.0 ** -(n - 1))
    lsb_z, lsb_xy = 2.0 ** -(23 + g), 2.0 ** -(24 + g)
    bound = resid + (n + 2) / 2 * lsb_z + (2.33 * n + 0.83) * lsb_xy + 2.0 ** -25
    assert err <= bound, (err, bound)
    assert err >= 0.05 * resid                            # the bound is not vacuous
    # Vectoring on vectors of length r in [0.25, 1.5].
    fin = QFormat(1, 24)
    r = rng.uniform(0.25, 1.5, 400)
    ang = rng.uniform(-math.pi, math.pi, 400)
    x, y = (np.round(r * np.cos(ang) * 2 ** 24).astype(np.int32),
            np.round(r * np.sin(ang) * 2 ** 24).astype(np.int32))
    z, _ = jax.jit(lambda y, x: cordic.atan2(y, x, fin, fa, spec))(y, x)
    exact = np.arctan2(y.astype(float), x.astype(float))
    dz = np.abs(np.asarray(z) / 2.0 ** 23 - exact)
    dz = np.minimum(dz, 2 * np.pi - dz)                   # +-pi are the same direction
    bound = resid + (n + 1) / 2 * lsb_z + 2.33 * (n + 1) * 2.0 ** -(24 + g) / 0.25 + 2.0 ** -24
    assert dz.max() <= bound, (dz.max(), bound)
    # Hyperbolic sqrt over many octaves.
    fv = QFormat(4, 20)
    v = np.exp(rng.uniform(np.log(1e-5), np.log(15.0), 400))
    vw = np.round(v * 2 ** 20).astype(np.int32)
    q = jax.jit(lambda v: cordic.sqrt(v, fv, fv, spec))(vw)
    sv = np.sqrt(vw / 2.0 ** 20)
    res = hyperbolic_residual_bound(cordic.hyperbolic_sequence(n))
    rel = math.cosh(res) - 1 + 6 * (n + 2) * 2.0 ** -(20 + g)
    err = np.abs(np.asarray(q) / 2.0 ** 20 - sv)
    assert np.all(err <= sv * rel + 2.0 ** -20), (err / sv).max()
    if n <= 8:
        assert np.max(err / sv) >= 0.05 * (math.cosh(res) - 1)


# ------------------------------------------------------------------ (c) against the float twin


def push_trace(n_ticks=40, dt=0.03, amp=0.25):
    """Sensor readings of a robot tipping forward by ~amp rad and back (a push from behind)."""
    t = np.arange(n_ticks) * dt
    bump = np.exp(-((t - 0.3) / 0.15) ** 2)
    pitch, roll = 0.122 + amp * bump, 0.05 * bump
    g = 9.81
    accel = np.stack([-g * np.sin(pitch), g * np.cos(pitch) * np.sin(roll),
                      g * np.cos(pitch) * np.cos(roll)], -1)
    gyro = np.stack([0.05 * bump * (-2 * (t - 0.3) / 0.15 ** 2),
                     amp * bump * (-2 * (t - 0.3) / 0.15 ** 2), 0.02 * np.ones_like(t)], -1)
    return gyro.astype(np.float32), accel.astype(np.float32)


def scan_fx(params, gyro, accel, cfg):
    def body(s, x):
        s, o = controller_step_fx(s, Sensors(*x), params, 1.0, cfg)
        return s, (o.leg_targets, o.phi, s.x_sup_m, o.gate, o.leg_targets_prev)
    return jax.lax.scan(body, controller_init_fx(params, cfg), (gyro, accel))[1]


def scan_float(params, gyro, accel):
    def body(s, x):
        s, o = controller_step(s, Sensors(*x), params, 1.0)
        return s, (o.leg_targets, o.phi, s.x_sup_m, o.gate)
    return jax.lax.scan(body, controller_init(params), (gyro, accel))[1]


@functools.cache
def float_run():
    return jax.jit(scan_float)(PARAMS, *push_trace())


def test_wide_words_match_float_controller():
    fx = jax.jit(functools.partial(scan_fx, cfg=FixedPointConfig.wide(straight_through=False)))(
        PARAMS, *push_trace())
    fl = float_run()
    assert np.array_equal(np.asarray(fx[3]), np.asarray(fl[3]))          # same gate every tick
    assert np.asarray(fl[3]).any()                                        # the push is detected
    assert np.max(np.abs(fx[1] - fl[1])) < 2e-6                           # filtered pitch, rad
    assert np.max(np.abs(fx[2] - fl[2])) < 2e-6                           # x_Sup, m
    assert np.max(np.abs(fl[2])) > 0.02
    assert np.max(np.abs(fx[0] - fl[0])) < 1e-5                           # leg targets, rad


@pytest.mark.parametrize("changes", [dict(cp_excess=1.0), dict(cp_update_window=0.03),
                                     dict(cp_update_window=0.09, cp_excess=1.0)])
def test_wide_words_match_float_controller_with_cp_options(changes):
    """cp_excess and cp_update_window (implemented in the twin): near-float words
    follow the float controller's x_Sup tick by tick, and the option changes x_Sup."""
    import dataclasses
    params = dataclasses.replace(PARAMS, **changes)
    cfg = FixedPointConfig.wide(straight_through=False)
    trace = push_trace()
    fx = jax.jit(functools.partial(scan_fx, cfg=cfg))(params, *trace)
    fl = jax.jit(scan_float)(params, *trace)
    assert np.array_equal(np.asarray(fx[3]), np.asarray(fl[3]))
    assert np.max(np.abs(fx[2] - fl[2])) < 2e-6                           # x_Sup, m
    assert np.max(np.abs(fx[0] - fl[0])) < 1e-5                           # leg targets, rad
    base = np.asarray(float_run()[2])
    assert np.max(np.abs(np.asarray(fl[2]) - base)) > 1e-3                # the option acts


def test_default_words_with_latency_track_float_controller():
    """Default words, a 1.4-tick latency; the batch also checks vmap (second trace unused)."""
    cfg = FixedPointConfig(straight_through=False, latency_ticks=1, latency_frac=0.4)
    traces = [push_trace(), push_trace(amp=-0.2)]
    gyro, accel = (np.stack(a) for a in zip(*traces))
    fx = jax.jit(jax.vmap(functools.partial(scan_fx, cfg=cfg), in_axes=(None, 0, 0)))(
        PARAMS, gyro, accel)
    fx = jax.tree_util.tree_map(lambda a: np.asarray(a[0]), fx)
    fl = float_run()
    assert np.array_equal(fx[3], np.asarray(fl[3]))
    # 18-bit words, 16 iterations: a fraction of the 1.5e-3 rad servo resolution.
    assert np.max(np.abs(fx[0][1:] - fl[0][:-1])) < 1e-3               # delayed by one tick
    assert np.max(np.abs(fx[4][2:] - fl[0][:-2])) < 1e-3               # previous command
    assert np.array_equal(fx[4][1:], fx[0][:-1])
    assert np.max(np.abs(fx[2] - fl[2])) < 1e-4
    assert servo_switch_substep(cfg, 15) == 6
    assert servo_switch_substep(FixedPointConfig(), 15) == 0


def test_straight_through_gradient():
    import dataclasses
    cfg = FixedPointConfig(cordic_iterations=12)          # straight_through=True by default
    gyro, accel = push_trace(n_ticks=16)

    def loss(gain, fixed):
        p = dataclasses.replace(PARAMS, cp_gain=gain)
        out = scan_fx(p, gyro, accel, cfg) if fixed else scan_float(p, gyro, accel)
        return jnp.sum(out[2]) + jnp.sum(out[0][:, 2])    # x_Sup and the right hip pitch

    (v_fx, g_fx), (v_fl, g_fl) = (jax.jit(jax.value_and_grad(loss), static_argnums=1)(1.0, f)
                                  for f in (True, False))
    assert np.isfinite(g_fx) and g_fx != 0.0
    assert abs(g_fx - g_fl) < 1e-2 * abs(g_fl)            # the float controller's gradient
    assert abs(v_fx - v_fl) < 1e-2 and v_fx != v_fl       # the fixed-point controller's value


@pytest.mark.parametrize("changes, field", [
    (dict(angle=QFormat(1, 15)), "angle.int_bits"),
    (dict(length=QFormat(0, 26)), "length.frac_bits"),
    (dict(cordic_iterations=0), "cordic_iterations"),
    (dict(cordic_guard_bits=4), "cordic_guard_bits"),
    (dict(rounding="up"), "rounding"),
    (dict(latency_frac=1.0), "latency_frac"),
    (dict(latency_ticks=-1), "latency_ticks"),
    (dict(coef_bits=40), "coef_bits"),
])
def test_config_validation_names_field(changes, field):
    with pytest.raises(ValueError, match=rf"FixedPointConfig\.{field} must be"):
        FixedPointConfig(**changes)


def test_words_identical_with_x64_enabled():
    rng = np.random.default_rng(7)
    fa, fo = QFormat(2, 20), QFormat(1, 22)
    a, b = rand_words(rng, fa, 64), rand_words(rng, fa, 64)
    f = lambda a, b: (qformat.mul(a, fa, b, fa, fo, "nearest"),  # noqa: E731
                      cordic.atan2(a, b, fa, fa, cordic.CordicSpec(), fmt_mag=fo))
    off = jax.tree_util.tree_map(np.asarray, jax.jit(f)(a, b))
    with jax.enable_x64(True):
        on = jax.tree_util.tree_map(np.asarray, jax.jit(f)(a, b))
    assert all(np.array_equal(x, y) and y.dtype == np.int32
               for x, y in zip(jax.tree_util.tree_leaves(off), jax.tree_util.tree_leaves(on)))


# ------------------------------------------------------------------ (d) refusal


def test_supported_fields_are_fields_and_paper_params_pass():
    """The implemented list names real fields; ControllerParams() and .paper() (geometry and
    Kalman noises, both variants) are accepted."""
    import dataclasses
    from tkujax.control.fixed import IMPLEMENTED_FIELDS, check_supported, unsupported
    names = {f.name for f in dataclasses.fields(ControllerParams)}
    assert IMPLEMENTED_FIELDS <= names
    for p in (ControllerParams(), ControllerParams.paper(),
              ControllerParams.paper(variant="estimated")):
        assert unsupported(p) == [] and check_supported(p) is p
    # Every field outside the list is refused when moved off its default: the rule iterates
    # over all fields (nothing hard-coded), so each one is named in turn.
    for f in dataclasses.fields(ControllerParams):
        if f.name in IMPLEMENTED_FIELDS:
            continue
        bumped = dataclasses.replace(ControllerParams(), **{f.name: f.default + 0.5})
        assert [u[0] for u in unsupported(bumped)] == [f.name]


def test_a_new_controller_option_is_refused_without_code_changes():
    """A field added later (here on a subclass) is refused once set away from its default, and
    accepted at its default: no list of unsupported options to maintain."""
    import dataclasses
    from tkujax.control.fixed import check_supported

    @dataclasses.dataclass(frozen=True)
    class Future(ControllerParams):
        multi_step: float = 0.0

    check_supported(Future())
    with pytest.raises(ValueError, match=r'^ControllerParams\.multi_step = 2\.0 is not '
                                         r'implemented by arithmetic = "fixed"'):
        check_supported(Future(multi_step=2.0))


def test_check_supported_refuses_traced_values():
    import dataclasses
    from tkujax.control.fixed import check_supported
    with pytest.raises(TypeError, match="outside jit"):
        jax.jit(lambda g: check_supported(dataclasses.replace(PARAMS, accel_gate=g)) and 0)(1.0)


# ------------------------------------------------------------------ (e) step lengths

SERVO_STEP = 2 * math.pi / 4096          # rad, Dynamixel MX (tkujax.sim.tick)


def _ankle_x(q6, params):
    """Level-frame x of an ankle relative to its hip from one leg's 6 commands (forward
    kinematics of tkujax.control.ik's convention, the pelvis leaning by standing_lean)."""
    _, r, hp, k = (float(v) for v in q6[:4])
    lt, lc, lean = params.thigh_length, params.calf_length, params.standing_lean
    # R_y(hp) [(0, 0, -l_t) + R_y(k) (0, 0, -l_c)], then R_x(r) (leaves x), then R_y(lean).
    x = -lt * math.sin(hp) - lc * math.sin(hp + k)
    z0 = -lt * math.cos(hp) - lc * math.cos(hp + k)
    z = math.cos(r) * z0
    return math.cos(lean) * x + math.sin(lean) * z


def _step_cmd(q12, params):
    """Commanded step length: left ankle x minus right ankle x (the hips share x = 0)."""
    return _ankle_x(q12[6:], params) - _ankle_x(q12[:6], params)


def test_forward_kinematics_inverts_the_float_ik():
    """_ankle_x is an independent check: FK(float IK(p)) = p for a stepped pose."""
    from tkujax.control.cpg import cpg_feet
    from tkujax.control.solve import solve_legs
    pr, pl = cpg_feet(jnp.asarray(0.3), jnp.asarray(0.06), PARAMS)   # landed, x_Sup = 6 cm
    q = np.asarray(solve_legs(pr, pl, PARAMS)[0], np.float64)
    assert abs(_ankle_x(q[6:], PARAMS) - float(pl[0])) < 1e-6
    assert abs(_step_cmd(q, PARAMS) - 0.06) < 1e-6


def test_ik_guard_bits_remove_the_stand_pose_bias():
    """The cause of the float-fixed step gap: the knee moves 22 rad/m of the ankle distance D,
    so D rounded to the 7.6 um `length` LSB biased the stand knee by 0.21 mrad (0.14 servo
    step; commands near a servo rounding boundary then flip by one step). ik_guard_bits = 4
    (default) carries the IK's lengths with 4 more fraction bits."""
    import dataclasses
    from tkujax.control.controller import stand_leg_targets
    from tkujax.control.fixed import stand_leg_targets_fx
    ref = np.asarray(stand_leg_targets(PARAMS), np.float64)
    err = {}
    for bits in (0, 4):
        cfg = dataclasses.replace(DEFAULT, ik_guard_bits=bits)
        q = np.asarray(stand_leg_targets_fx(PARAMS, cfg), np.float64) * cfg.angle.lsb
        err[bits] = np.abs(q - ref).max()
    # Closed form of the D term alone: dknee/dD * LSB/2 with dknee/dD = D / (l_t l_c sin knee).
    lt, lc, d = PARAMS.thigh_length, PARAMS.calf_length, PARAMS.hip_to_ankle_z
    cos_k = (d * d - lt * lt - lc * lc) / (2 * lt * lc)
    slope = d / (lt * lc * math.sqrt(1 - cos_k ** 2))
    assert 21.0 < slope < 23.0                                        # rad/m
    d_term = slope * DEFAULT.length.lsb / 2          # D rounded to the length LSB: 0.083 mrad
    assert err[0] > 0.15e-3                          # measured 0.207 mrad (D and p' rounded)
    assert err[4] < 0.5 * d_term                     # measured 0.037 mrad


def test_commanded_step_length_within_its_bound():
    """Same sensors, both controllers, default words (18 bits): before the servos' rounding the
    commands differ by eps << one servo step s; after it by at most one step per joint. Moving
    joint j by dq moves the ankle by exactly 2 r_j sin(dq / 2) <= r_j dq, r_j its distance to
    the ankle (<= l_t + l_c for the two hip axes, l_c for the knee, 0 for the ankle axes), so the
    commanded step (left ankle x - right ankle x) differs by <= 2 dq (2 l_t + 3 l_c): 1.69 mm
    with dq = s, 2 eps (2 l_t + 3 l_c) before rounding."""
    from tkujax.sim.tick import quantise_targets
    fx = jax.jit(functools.partial(scan_fx, cfg=DEFAULT))(PARAMS, *push_trace())
    fl = float_run()
    assert np.array_equal(np.asarray(fx[3]), np.asarray(fl[3])) and np.asarray(fl[3]).any()
    qx, qf = np.asarray(fx[0], np.float64), np.asarray(fl[0], np.float64)
    eps = np.abs(qx - qf).max()
    assert eps < 0.25 * SERVO_STEP                                   # measured 0.1 mrad
    sx, sf = (np.asarray(quantise_targets(jnp.asarray(q, jnp.float32)), np.float64)
              for q in (qx, qf))
    assert np.abs(sx - sf).max() <= SERVO_STEP * 1.001               # at most one step
    lever = 2 * PARAMS.thigh_length + 3 * PARAMS.calf_length
    step_fx = np.array([_step_cmd(q, PARAMS) for q in qx])
    step_fl = np.array([_step_cmd(q, PARAMS) for q in qf])
    assert np.abs(step_fl).max() > 0.03                              # the trace steps
    assert np.abs(step_fx - step_fl).max() <= 2 * eps * lever
    served = np.array([_step_cmd(a, PARAMS) - _step_cmd(b, PARAMS) for a, b in zip(sx, sf)])
    assert np.abs(served).max() <= 2 * SERVO_STEP * lever            # 1.69 mm
    assert np.abs(step_fx - step_fl).max() < 1e-4                    # 0.1 mm before rounding


# ------------------------------------------------------------------ (f) EP3C120 resources


def test_multiplier_block_rule():
    from tkujax.control.fixed.resources import mul_blocks
    assert [mul_blocks(a, b) for a, b in [(18, 18), (19, 18), (24, 24), (36, 36), (37, 18)]] \
        == [1, 2, 4, 4, 3]


def test_resource_count_of_one_kalman_update_by_hand():
    """kalman_step_fx on [pitch, roll] (kalman_fx.py, read by hand): per axis 3 products
    (rate dt, k innovation, (1 - k) p), 6 adders (phi + rate dt, p + q, p + r, innovation,
    phi + k innovation, 1 - k) and one divide. Default words: rate 18, dt 18, unit 18,
    state 24, cov 18 bits."""
    from tkujax.control.fixed import kalman_fx, qformat
    from tkujax.control.fixed.resources import count_ops, module_resources, op_cycles
    coef = coefficients(PARAMS, DEFAULT)
    z = jnp.zeros(2, jnp.int32)
    ops = count_ops(DEFAULT, fn=lambda: kalman_step_fx(z, z, z, z, coef, DEFAULT))
    assert sorted((o.kind, o.count, o.widths) for o in ops) == sorted([
        ("mul", 2, (18, 18, 24)), ("mul", 2, (18, 24, 24)), ("mul", 2, (18, 18, 18)),
        ("add", 2, (24,)), ("add", 2, (18,)), ("add", 2, (18,)), ("add", 2, (24,)),
        ("add", 2, (24,)), ("add", 2, (18,)), ("div", 2, (18, 15))])
    m = module_resources(ops, "fn")
    assert (m["multiplies"], m["adds"], m["divides"]) == (6, 12, 2)
    assert m["multipliers_18x18"] == 2                   # the 18 x 24 product: 1 x 2 blocks
    assert m["multipliers_18x18_parallel"] == 2 * 1 + 2 * 2 + 2 * 1
    # cycles: 2 x (3 + 4 + 3) products, 12 adds, 2 x (15 + 2) divides
    assert m["latency_cycles"] == 20 + 12 + 34 == sum(o.count * op_cycles(o) for o in ops)
    # registers: results 2 x (24 + 24 + 18) + 2 x (24 + 18 + 18 + 24 + 24 + 18) + 2 x 17,
    # the divider 18 + 15 + 1
    assert m["register_bits"] == 132 + 252 + 34 + 34
    assert m["cordic_runs"] == 0 and m["rom_words"] == 0
    # The primitives are restored after counting.
    assert kalman_fx.mul is qformat.mul and kalman_fx.div_fraction is qformat.div_fraction


def test_resource_count_of_cordic_runs_by_hand():
    """Three rotations of 16 iterations: 3 runs x (16 + 2) cycles, 48 unrolled stages, one atan
    ROM of 16 words of the z register (Q3.(15 + 2): 21 bits)."""
    from tkujax.control.fixed.resources import count_ops, module_resources
    spec = cordic.spec_of(DEFAULT)
    ops = count_ops(DEFAULT, fn=lambda: cordic.sincos(jnp.zeros(3, jnp.int32), DEFAULT.angle,
                                                      DEFAULT.unit, spec))
    m = module_resources(ops, "fn")
    assert (m["cordic_runs"], m["latency_cycles"], m["cordic_stages_unrolled"]) == (3, 54, 48)
    assert (m["rom_words"], m["rom_bits"], m["m9k_blocks"]) == (16, 16 * 21, 1)
    assert (m["cordic_xy_bits"], m["cordic_z_bits"]) == (1 + 1 + 17, 21)


def test_state_registers_cover_every_state_word():
    from tkujax.control.fixed.resources import state_register_bits
    bits = state_register_bits(FixedPointConfig(latency_ticks=2))
    assert bits["delay"] == 3 * 12 * 18 and bits["phi"] == 2 * 24 and bits["p"] == 2 * 18
