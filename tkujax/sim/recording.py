"""The per-tick recording shared by both rollouts (MJX in jnp, MuJoCo C in numpy): the centre
of pressure of the sole sensors, the lowest point of the body, and the Series row of a tick.

The helpers take the array module `xp` (numpy or jax.numpy) so each backend computes the same
formula in its own arrays; the Series field names come from `records.Series` alone.
"""

from __future__ import annotations

from tkujax.sim.records import Series

NO_CONTACT_N = 1e-3   # below this total sole force there is no ZMP (the feet's centre instead)


def zmp(xp, fsr, site_xy):
    """Centre of pressure of the sole sensors and their total force.

    fsr (..., F) forces (N); site_xy (..., F, 2) their world (x, y). Returns (zmp (..., 2),
    total (...)). With no foot on the ground (total <= NO_CONTACT_N) the ZMP is the sensors'
    centre instead of 0/0."""
    total = xp.sum(fsr, -1)
    contact = total > NO_CONTACT_N
    safe = xp.where(contact, total, 1.0)
    weighted = xp.einsum("...f,...fk->...k", fsr, site_xy) / safe[..., None]
    return xp.where(contact[..., None], weighted, xp.mean(site_xy, -2)), total


def lowest_point(xp, sphere_z, sphere_radii, box_z=None, box_zrow=None, box_half_sizes=None,
                 point_z=None):
    """Height of the lowest point of the non-foot collision geoms (m).

    sphere_z (..., S) centre heights, sphere_radii (S,); box_z (..., B) centre heights,
    box_zrow (..., B, 3) the world z row of each box's rotation (its vertical half-extent is
    |zrow| . half sizes), box_half_sizes (B, 3); boxes None where the model has none.
    point_z (..., P): heights of further lowest points (a mesh's lowest vertex), or None."""
    lows = [sphere_z - sphere_radii]
    if box_z is not None:
        lows.append(box_z - xp.sum(xp.abs(box_zrow) * box_half_sizes, -1))
    if point_z is not None:
        lows.append(point_z)
    return xp.min(xp.concatenate(lows, -1), -1)


# sin^2 of a cylinder's tilt is floored here: its square root stays differentiable when the
# axis is vertical (the lowest point then moves by at most radius x 1e-6).
MIN_SIN2 = 1e-12


def axial_lows(xp, centre_z, axis_z, sizes, capsule: bool):
    """Heights of the lowest points of capsules (capsule=True) or cylinders (m).

    centre_z (..., C) the centre heights; axis_z (..., C) the world z component of each geom's
    axis (its frame's z); sizes (C, 2) (radius, half length). A capsule's lowest point is
    z - |a_z| h - r (the end sphere's bottom); a cylinder's is z - |a_z| h - r sqrt(1 - a_z^2)
    (the lower rim's lowest point; its flat face when the axis is vertical)."""
    radius, half = sizes[:, 0], sizes[:, 1]
    ends = centre_z - xp.abs(axis_z) * half
    if capsule:
        return ends - radius
    return ends - radius * xp.sqrt(xp.maximum(1.0 - axis_z * axis_z, MIN_SIN2))


def tick_series(*, t, pitch, roll, zmp_xy, fsr_total, com, r_ankle, l_ankle, pelvis_z,
                lowest_body_z, out, ctrl_state, qpos=None) -> Series:
    """The Series row of one control tick: the physics quantities given, the controller's from
    its tick output `out` (phi, roll, gate, reachable, touchdown_s) and its state (the latched
    step x_sup_m, y_sup_m and step_weight). qpos None: not recorded."""
    return Series(t=t, pitch=pitch, roll=roll, pitch_est=out.phi, roll_est=out.roll, zmp=zmp_xy,
                  fsr_total=fsr_total, com=com, r_ankle=r_ankle, l_ankle=l_ankle,
                  pelvis_z=pelvis_z, lowest_body_z=lowest_body_z, gate=out.gate,
                  x_sup=ctrl_state.x_sup_m, y_sup=ctrl_state.y_sup_m,
                  step_weight=ctrl_state.step_weight, reachable=out.reachable, qpos=qpos,
                  touchdown_s=out.touchdown_s)
