"""A bounded capture-point margin of one rollout, whose gradient is taken before the fall.

Per control tick k of the `Series` (tkujax.sim.records):

  DCM         xi_k = c_k + v_k / omega_k (horizontal, m), c the whole-body CoM, v its backward
              difference between ticks (0 at the first tick), omega_k = sqrt(g / c_z,k).
  support     the convex hull of the two sole rectangles: each ankle site plus the sole's
              extent (toe `foot_front_m` ahead, heel `foot_back_m` behind, `foot_half_width_m`
              to each side; world-axis aligned: the feet do not yaw). With drop_airborne_foot,
              a foot more than `lift_m` above its first-tick height is left out, unless both
              are; by default both always count (a swing foot on its way is where the support
              is going).
  distance    d_k, the signed distance of xi_k outside the hull (m; negative inside), through
              the hull's support function: d = max_u (u . xi - max_corners u . corner) over
              `n_directions` unit directions u, which is the exact signed distance of a convex
              polygon up to the direction grid (error <= |d| (1 - cos(pi / n_directions))).

The push's margin is a soft maximum (temperature `softmax_m`) of d_k over its window: the ticks
after the push onset, up to and including the first tick at which the clearance of the fall
test (tkujax.sim.metrics: lowest non-foot point - 5 mm, pelvis height - 0.12 m) is below
`stop_clearance_m`, and at most `window_s` after the onset. Over a long window the margin is
bimodal (held-out pushes, recommended controller: survivors below ~3 cm, falls above ~20 cm,
the DCM of a body about to touch the floor), so a squash centred between the two modes gives
falls almost no gradient; a window of ~0.3-0.45 s after the onset keeps the margin continuous
across the fall boundary and still predicts the fall (scripts/gradient_margin_auc.py).
Ticks after the window are masked out of the value and the gradient (a body lying on the
floor says nothing about the controller), as are non-finite ticks (numerical blow-up), which
also close the window.

The loss is the squashed margin sigmoid((margin - offset_m) / scale_m) in (0, 1): about 1 for
a push that falls (its gradient vanishes), about 0 for one that stays well inside, and steep
near the boundary. Pure jnp; jit, vmap and grad go through (inputs are NaN-guarded with the
double `where` of tkujax.control.safe_math).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from tkujax.control.safe_math import safe_sqrt
from tkujax.sim.metrics import FALL_BODY_CLEARANCE_M, FALL_PELVIS_HEIGHT_M
from tkujax.sim.records import Series


@dataclasses.dataclass(frozen=True)
class MarginConfig:
    """Static settings of the margin (the defaults: the default TKU-X model's soles)."""

    gravity_m_s2: float = 9.81
    foot_front_m: float = 0.048        # toe ahead of the ankle site (foot_forward_offset + L/2)
    foot_back_m: float = 0.103         # heel behind the ankle site
    foot_half_width_m: float = 0.0425  # half the sole's width
    lift_m: float = 0.01               # a foot this far above its first-tick height is airborne
    # True: an airborne foot leaves the support; False (default, the better AUC on the dev
    # pushes of scripts/gradient_margin_auc.py): both feet always count (the feet's hull).
    drop_airborne_foot: bool = False
    n_directions: int = 32             # directions of the support-function distance
    softmax_m: float = 0.005           # temperature of the soft maximum over ticks
    stop_clearance_m: float = 0.01     # the window ends at the first tick below this clearance
    window_s: float = math.inf         # ... or this long after the onset, whichever comes first
    min_com_z_m: float = 0.05          # omega's CoM height floor
    offset_m: float = 0.0              # the loss's centre: sigmoid((margin - offset) / scale)
    scale_m: float = 0.02              # the loss's width


def _finite(x):
    """x with non-finite entries replaced by 0 (the harmless input of the double `where`)."""
    return jnp.where(jnp.isfinite(x), x, 0.0)


def com_velocity(series: Series) -> jax.Array:
    """(n_ticks, 3) backward difference of the CoM between ticks (m/s; 0 at the first tick)."""
    com = _finite(series.com)
    dt = jnp.maximum(jnp.diff(_finite(series.t)), 1e-6)
    v = jnp.diff(com, axis=0) / dt[:, None]
    return jnp.concatenate([jnp.zeros_like(com[:1]), v], axis=0)


def dcm_xy(series: Series, cfg: MarginConfig = MarginConfig()) -> jax.Array:
    """(n_ticks, 2) horizontal divergent component of motion xi = c + v / omega (m)."""
    com = _finite(series.com)
    omega = safe_sqrt(cfg.gravity_m_s2 / jnp.maximum(com[:, 2], cfg.min_com_z_m))
    return com[:, :2] + com_velocity(series)[:, :2] / omega[:, None]


def _sole_corners(ankle_xy: jax.Array, cfg: MarginConfig) -> jax.Array:
    """(..., 4, 2) sole corners around ankle sites (..., 2)."""
    dx = jnp.array([cfg.foot_front_m, cfg.foot_front_m, -cfg.foot_back_m, -cfg.foot_back_m])
    dy = jnp.array([cfg.foot_half_width_m, -cfg.foot_half_width_m] * 2)
    return ankle_xy[..., None, :] + jnp.stack([dx, dy], -1)


def support_corners(series: Series, cfg: MarginConfig = MarginConfig()) -> jax.Array:
    """(n_ticks, 8, 2) corners whose hull is the support (right sole, then left sole). An
    airborne foot's corners are replaced by the other foot's (see the module docstring)."""
    r, l_ = _finite(series.r_ankle), _finite(series.l_ankle)
    r_c, l_c = _sole_corners(r[:, :2], cfg), _sole_corners(l_[:, :2], cfg)
    r_air = r[:, 2] - r[0, 2] > cfg.lift_m
    l_air = l_[:, 2] - l_[0, 2] > cfg.lift_m
    drop = cfg.drop_airborne_foot
    r_use = jnp.where((drop & r_air & ~l_air)[:, None, None], l_c, r_c)
    l_use = jnp.where((drop & l_air & ~r_air)[:, None, None], r_c, l_c)
    return jnp.concatenate([r_use, l_use], axis=1)


def hull_signed_distance(point: jax.Array, corners: jax.Array, n_directions: int = 32
                         ) -> jax.Array:
    """Signed distance (m, > 0 outside) of point (..., 2) from the convex hull of corners
    (..., C, 2), by the support function over n_directions directions (module docstring)."""
    theta = 2.0 * math.pi * jnp.arange(n_directions) / n_directions
    u = jnp.stack([jnp.cos(theta), jnp.sin(theta)], -1)                 # (D, 2)
    h = jnp.max(jnp.einsum("...ck,dk->...dc", corners, u), axis=-1)      # (..., D)
    return jnp.max(jnp.einsum("...k,dk->...d", point, u) - h, axis=-1)


def clearance_m(series: Series) -> jax.Array:
    """(n_ticks,) the fall test's clearance: min(lowest non-foot point - 5 mm, pelvis height -
    0.12 m) (tkujax.sim.metrics), non-finite entries as -1 m (fallen)."""
    c = jnp.minimum(series.lowest_body_z - FALL_BODY_CLEARANCE_M,
                    series.pelvis_z - FALL_PELVIS_HEIGHT_M)
    return jnp.where(jnp.isfinite(c), c, -1.0)


def window_mask(series: Series, onset_s, cfg: MarginConfig = MarginConfig()) -> jax.Array:
    """(n_ticks,) bool: after the onset, up to and including the first tick whose clearance is
    below stop_clearance_m (or whose CoM / ankles are not finite), and within window_s."""
    finite = (jnp.all(jnp.isfinite(series.com), -1) & jnp.all(jnp.isfinite(series.r_ankle), -1)
              & jnp.all(jnp.isfinite(series.l_ankle), -1))
    low = (clearance_m(series) < cfg.stop_clearance_m) | ~finite
    # Ticks strictly after the first low tick: a low tick earlier than this one exists.
    after_fall = (jnp.cumsum(low) - low) > 0
    t = _finite(series.t)
    return (t > onset_s) & (t <= onset_s + cfg.window_s) & ~after_fall


def dcm_distance(series: Series, cfg: MarginConfig = MarginConfig()) -> jax.Array:
    """(n_ticks,) signed distance of the DCM outside the support (m)."""
    return hull_signed_distance(dcm_xy(series, cfg), support_corners(series, cfg),
                                cfg.n_directions)


def push_margin(series: Series, onset_s, cfg: MarginConfig = MarginConfig()) -> jax.Array:
    """() the soft maximum of the DCM distance over the window (m); see the module docstring.
    An empty window (onset after the last tick) gives -1 m (with a zero gradient)."""
    d = dcm_distance(series, cfg)
    mask = window_mask(series, onset_s, cfg)
    s = cfg.softmax_m
    z = jnp.where(mask, d / s, -1e9)
    # Masked ticks: exp(-1e9 - lse) = 0, so neither their value nor their gradient counts.
    m = s * jax.nn.logsumexp(z)
    return jnp.where(jnp.any(mask), m, -1.0)


def margin_loss(series: Series, onset_s, cfg: MarginConfig = MarginConfig()) -> dict:
    """Per-push terms: total (the squashed margin, in (0, 1)), margin_m, fell_window (the
    window was closed by a low clearance: a hard, gradient-free indicator)."""
    m = push_margin(series, onset_s, cfg)
    mask = window_mask(series, onset_s, cfg)
    closed = jnp.any((clearance_m(series) < cfg.stop_clearance_m) & mask)
    total = jax.nn.sigmoid((m - cfg.offset_m) / cfg.scale_m)
    return dict(total=total, margin_m=m, fell_window=closed)


def batched_margin(series: Series, onset_s, cfg: MarginConfig = MarginConfig()) -> jax.Array:
    """(n,) push_margin over a batch of series (leading axis n) and onsets (n,)."""
    return jax.vmap(lambda s, o: push_margin(s, o, cfg))(series, onset_s)
