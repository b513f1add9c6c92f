"""Feet positions in the level waist frame -> the 12 leg joint targets of the TKU-X model.

The paper's IK (Eq. 19-28) works in a frame attached to the waist. On TKU-X the pelvis (and
the IMU on it) leans forward by the standing lean, while the CPG's frame is level. So, per leg:
  1. the target relative to the hip joint centre is rotated from the level frame into the
     leaning pelvis frame (the hip sits at (0, +-d_y, 0) in both: the lean is about y);
  2. hip roll, hip pitch and knee come from `leg_ik` in that frame (they alone set the ankle
     position, the ankle axes passing through the ankle centre);
  3. the ankle pitch and roll make the sole level in the world, not parallel to the pelvis:
     R_x(roll_h) R_y(pitch_h + knee + pitch_a) R_x(roll_a) must carry the sole normal to the
     world vertical, i.e. match the third column of R_x(-roll_h) R_y(-lean). That is always
     solvable, so the sole is exactly level; with no hip roll (every pose of the paper's
     sagittal step) the whole orientation is exact (pitch_a = -lean - pitch_h - knee, roll_a =
     0); with a hip roll r the foot keeps a small yaw (about sin r sin lean, 0.6 deg at r = 5
     deg) that a pitch-roll ankle cannot undo.
Model joint signs: see tkujax.model.mjcf (right-hand rule, zero = straight leg, no offsets).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.control.ik import leg_ik
from tkujax.control.controller_params import ControllerParams


def _rot_y(a: jax.Array) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    z, o = jnp.zeros_like(a), jnp.ones_like(a)
    return jnp.stack([jnp.stack([c, z, s], -1), jnp.stack([z, o, z], -1),
                      jnp.stack([-s, z, c], -1)], -2)


def _rot_x(a: jax.Array) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    z, o = jnp.zeros_like(a), jnp.ones_like(a)
    return jnp.stack([jnp.stack([o, z, z], -1), jnp.stack([z, c, -s], -1),
                      jnp.stack([z, s, c], -1)], -2)


def solve_leg(p_ankle_level: jax.Array, hip_y: jax.Array, params: ControllerParams):
    """One leg: ankle target (..., 3) relative to the waist P_W, level frame -> 6 joint angles.

    Returns ((..., 6) [hip_yaw, hip_roll, hip_pitch, knee, ankle_pitch, ankle_roll] rad,
    reachable (...) bool).
    """
    lean = params.standing_lean
    hip = jnp.stack([jnp.zeros_like(hip_y), hip_y, jnp.zeros_like(hip_y)], -1)
    p_rel = p_ankle_level - hip
    # Level -> pelvis frame: the pelvis is the level frame rotated by R_y(lean).
    p_pelvis = jnp.einsum("...ji,...j->...i", _rot_y(jnp.broadcast_to(lean, p_rel.shape[:-1])),
                          p_rel)
    a = leg_ik(p_pelvis, params.thigh_length, params.calf_length)
    # Desired sole orientation in the hip-roll frame: M = R_x(-roll_h) R_y(-lean) = R_y(b) R_x(c).
    m = _rot_x(-a.hip_roll) @ _rot_y(jnp.broadcast_to(-lean, a.hip_roll.shape))
    # Match M's third column (the sole normal): R_y(b) R_x(c) e_z = (sin b cos c, -sin c,
    # cos b cos c). The sole is then exactly level; only its yaw can differ from M's.
    sole_pitch = jnp.arctan2(m[..., 0, 2], m[..., 2, 2])
    ankle_roll = jnp.arctan2(-m[..., 1, 2], jnp.hypot(m[..., 0, 2], m[..., 2, 2]))
    ankle_pitch = sole_pitch - a.hip_pitch - a.knee
    angles = jnp.stack([jnp.zeros_like(a.knee), a.hip_roll, a.hip_pitch, a.knee, ankle_pitch,
                        ankle_roll], -1)
    return angles, a.reachable


def solve_legs(p_right: jax.Array, p_left: jax.Array, params: ControllerParams):
    """Both legs -> (joint targets (..., 12) in `tkujax.model.LEG_ACTUATORS` order, reachable).

    p_right, p_left: (..., 3) ankle positions relative to P_W (the `waist` site) in the level
    frame of the `stand` keyframe (x forward, y left, z up), m.
    """
    d_y = jnp.asarray(params.hip_offset_y)
    right, ok_r = solve_leg(p_right, jnp.broadcast_to(-d_y, p_right.shape[:-1]), params)
    left, ok_l = solve_leg(p_left, jnp.broadcast_to(d_y, p_left.shape[:-1]), params)
    return jnp.concatenate([right, left], -1), ok_r & ok_l


def _rot_z(a: jax.Array) -> jax.Array:
    c, s = jnp.cos(a), jnp.sin(a)
    z, o = jnp.zeros_like(a), jnp.ones_like(a)
    return jnp.stack([jnp.stack([c, -s, z], -1), jnp.stack([s, c, z], -1),
                      jnp.stack([z, z, o], -1)], -2)


def solve_leg_yaw(p_ankle_level: jax.Array, hip_y: jax.Array, yaw: jax.Array,
                  params: ControllerParams):
    """`solve_leg` with the hip yaw at `yaw` (rad, about the pelvis's z axis: the foot turned
    by about `yaw` relative to the waist). The target is taken into the yawed leg's frame
    (R_z(yaw)^T after the lean), the sole kept level: M = R_x(-roll_h) R_z(-yaw) R_y(-lean).
    With yaw = 0 it is `solve_leg`'s solution."""
    lean = params.standing_lean
    hip = jnp.stack([jnp.zeros_like(hip_y), hip_y, jnp.zeros_like(hip_y)], -1)
    p_rel = p_ankle_level - hip
    p_pelvis = jnp.einsum("...ji,...j->...i", _rot_y(jnp.broadcast_to(lean, p_rel.shape[:-1])),
                          p_rel)
    yaw = jnp.broadcast_to(jnp.asarray(yaw, p_rel.dtype), p_rel.shape[:-1])
    p_leg = jnp.einsum("...ji,...j->...i", _rot_z(yaw), p_pelvis)
    a = leg_ik(p_leg, params.thigh_length, params.calf_length)
    m = _rot_x(-a.hip_roll) @ _rot_z(-yaw) @ _rot_y(jnp.broadcast_to(-lean, a.hip_roll.shape))
    sole_pitch = jnp.arctan2(m[..., 0, 2], m[..., 2, 2])
    ankle_roll = jnp.arctan2(-m[..., 1, 2], jnp.hypot(m[..., 0, 2], m[..., 2, 2]))
    ankle_pitch = sole_pitch - a.hip_pitch - a.knee
    angles = jnp.stack([yaw, a.hip_roll, a.hip_pitch, a.knee, ankle_pitch, ankle_roll], -1)
    return angles, a.reachable


def solve_legs_yaw(p_right: jax.Array, p_left: jax.Array, yaw_right, yaw_left,
                   params: ControllerParams):
    """`solve_legs` with each leg's hip yaw (rad) given (`solve_leg_yaw`)."""
    d_y = jnp.asarray(params.hip_offset_y)
    right, ok_r = solve_leg_yaw(p_right, jnp.broadcast_to(-d_y, p_right.shape[:-1]), yaw_right,
                                params)
    left, ok_l = solve_leg_yaw(p_left, jnp.broadcast_to(d_y, p_left.shape[:-1]), yaw_left, params)
    return jnp.concatenate([right, left], -1), ok_r & ok_l
