"""Leg inverse kinematics (Sec. 3.4, Eq. 19-28), exact for the TKU-X leg chain.

Joint convention of `leg_ik` (the model's, see tkujax/model/mjcf.py):
  chain hip_yaw (z) -> hip_roll (x) -> hip_pitch (y) -> knee (y) -> ankle_pitch (y) ->
  ankle_roll (x);
  the three hip axes meet at the hip joint centre, the two ankle axes at the ankle centre;
  thigh = hip centre to knee, calf = knee to ankle centre; MuJoCo right-hand rule; all zero =
  straight leg pointing down (-z) with the sole flat. Consequences: R_y(a) (0, 0, -1) =
  (-sin a, 0, -cos a), so a positive hip pitch swings the leg backward (a thigh flexed forward
  has hip_pitch < 0) and a bent knee (shin swung backward relative to the thigh) is positive;
  R_x(r) (0, 0, -1) = (0, sin r, -cos r), so a positive hip roll moves the foot toward +y.

Relation to the paper: Eq. 23-28 solve the sagittal triangle with the vertical distance L^z,
which is exact only without lateral offset; after the hip roll the leg plane is tilted and the
distance in that plane is L' = sqrt(L_y^2 + L_z^2). `leg_ik` uses L' and is exact;
`paper_leg_ik` is the literal transcription, kept for comparison.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from tkujax.control.safe_math import safe_atan2, safe_norm, safe_sqrt


class LegAngles(NamedTuple):
    """Joint angles of one leg (rad), each (...); `reachable` is a (...) bool."""

    hip_roll: jax.Array
    hip_pitch: jax.Array
    knee: jax.Array
    ankle_pitch: jax.Array
    ankle_roll: jax.Array
    reachable: jax.Array


def leg_ik(p_ankle_from_hip: jax.Array, thigh, calf) -> LegAngles:
    """Exact IK: joint angles putting the ankle centre at p with the sole flat (hip_yaw = 0).

    Args:
      p_ankle_from_hip: (..., 3) ankle centre relative to the hip joint centre, m, in a level
        frame (x forward, y left, z up); the paper's L^x = p_x, L^y = p_y, L^z = -p_z.
      thigh, calf: link lengths l_t, l_c (m, > 0; scalars or broadcastable to (...)).
    Returns:
      LegAngles in the convention of the module docstring, with
        hip_roll    = atan2(p_y, -p_z)                     (Eq. 19 without the L^z approximation)
        knee        = acos((D^2 - l_t^2 - l_c^2) / (2 l_t l_c)) >= 0, D = |p| (law of cosines,
                      computed as an equivalent, better conditioned atan2)
        hip_pitch   = atan2(-p_x, L') - atan2(l_c sin knee, l_t + l_c cos knee),
                      L' = sqrt(p_y^2 + p_z^2)
        ankle_pitch = -(hip_pitch + knee)                  (sole parallel to the ground)
        ankle_roll  = -hip_roll                            (sole parallel to the ground)
      reachable is False when D is outside [|l_t - l_c|, l_t + l_c]; the angles are then those
      of the nearest reachable ankle position on the ray from the hip through p. D is clipped
      to a relative margin of 1e-6 inside that shell, so boundary targets land within ~2e-7 m
      and all gradients stay finite; the price is a knee of ~2.8 mrad (not 0) for a fully
      extended target with l_t = l_c (the angle goes like the square root of the margin).
    """
    p = jnp.asarray(p_ankle_from_hip)
    dtype = jnp.result_type(p, thigh, calf, float)
    p = p.astype(dtype)
    px, py, pz = p[..., 0], p[..., 1], p[..., 2]
    thigh = jnp.asarray(thigh, dtype)
    calf = jnp.asarray(calf, dtype)

    # The hip roll tilts the whole pitch plane; in that plane the leg hangs a distance L' down.
    hip_roll = safe_atan2(py, -pz)
    l_plane = safe_norm(py, pz)
    dist = safe_norm(px, l_plane)

    lo = jnp.abs(thigh - calf)
    hi = thigh + calf
    reachable = (dist >= lo) & (dist <= hi)
    # Clip the distance so the result is the nearest reachable pose and the knee never reaches
    # 0 or pi exactly, where its derivative with respect to the distance is infinite.
    margin = 1e-6 * hi
    d = jnp.clip(dist, lo + margin, hi - margin)
    # Law of cosines, 2 l_t l_c cos(knee) = d^2 - l_t^2 - l_c^2, written as an atan2 with
    # 2 l_t l_c sin(knee) = sqrt((hi^2 - d^2)(d^2 - lo^2)): same angle as the acos, but the
    # factored sine keeps float32 accuracy near full extension (acos(1 - x) is ill-conditioned).
    # The sqrt argument is > 0 thanks to the clip; the safe sqrt also guards rounding.
    two_lt_lc_sin = safe_sqrt((hi - d) * (hi + d) * (d - lo) * (d + lo))
    two_lt_lc_cos = d * d - thigh * thigh - calf * calf
    knee = jnp.arctan2(two_lt_lc_sin, two_lt_lc_cos)

    # Direction of the target from straight-down in the leg plane (positive = backward), minus
    # the angle between thigh and hip-ankle line: the thigh sits forward of that line.
    target = safe_atan2(-px, l_plane)
    offset = jnp.arctan2(calf * jnp.sin(knee), thigh + calf * jnp.cos(knee))
    hip_pitch = target - offset
    ankle_pitch = -(hip_pitch + knee)
    ankle_roll = -hip_roll
    return LegAngles(hip_roll, hip_pitch, knee, ankle_pitch, ankle_roll, reachable)


def paper_leg_ik(L_x, L_y, L_z, thigh, calf) -> LegAngles:
    """Literal transcription of the paper's Eq. 19-28, in the PAPER's joint convention.

    Args:
      L_x, L_y, L_z: (...) step length, step width and (positive, downward) hip-to-ankle height,
        m: L_x = p_x, L_y = p_y, L_z = -p_z of `leg_ik`.
      thigh, calf: l_t, l_c in m.
    Returns:
      LegAngles with the paper's angles: hip_roll = atan(L_y / L_z) (Eq. 19), ankle_roll =
      hip_roll (Eq. 20), hip_pitch = theta_H^pit (thigh angle forward of vertical, Eq. 23),
      knee = theta_K^pit (Eq. 24), ankle_pitch = theta_A^pit (shin angle backward of vertical,
      Eq. 25). Use `paper_to_model_angles` to convert to `leg_ik`'s convention. No guards:
      the divisions of Eq. 24-25 and the acos of Eq. 23 are taken literally (NaN/inf where the
      paper's formula is singular or the target out of reach); reachable is computed from the
      sagittal distance sqrt(L_x^2 + L_z^2) the paper uses.
    """
    L_x, L_y, L_z = (jnp.asarray(v) for v in (L_x, L_y, L_z))
    hip_roll = jnp.arctan(L_y / L_z)                                   # Eq. 19 / 21
    ankle_roll = hip_roll                                              # Eq. 20 / 22
    r = jnp.sqrt(L_x**2 + L_z**2)
    hip_pitch = (jnp.arccos((L_x**2 + L_z**2 + thigh**2 - calf**2) / (2.0 * thigh * r))
                 + jnp.arctan(L_x / L_z))                              # Eq. 23 / 26
    c, s = thigh * jnp.cos(hip_pitch), thigh * jnp.sin(hip_pitch)
    knee = jnp.pi - jnp.arctan(c / s) - jnp.arctan((L_z - c) / (s - L_x))  # Eq. 24 / 27
    ankle_pitch = jnp.arctan((s - L_x) / (L_z - c))                    # Eq. 25 / 28
    reachable = (r >= jnp.abs(thigh - calf)) & (r <= thigh + calf)
    return LegAngles(hip_roll, hip_pitch, knee, ankle_pitch, ankle_roll, reachable)


def paper_to_model_angles(a: LegAngles) -> LegAngles:
    """Map `paper_leg_ik`'s angles to `leg_ik`'s convention.

    The paper measures the thigh forward and the shin backward of vertical, and its ankle roll
    equals the hip roll when the sole is flat; with right-hand-rule axes the thigh forward is a
    negative hip pitch, the ankle pitch undoing a backward shin is negative, and the flat-sole
    ankle roll is minus the hip roll. The knee (relative flexion) agrees.
    """
    return LegAngles(hip_roll=a.hip_roll, hip_pitch=-a.hip_pitch, knee=a.knee,
                     ankle_pitch=-a.ankle_pitch, ankle_roll=-a.ankle_roll, reachable=a.reachable)
