"""LIP capturability for capture-region studies: Koolen et al.'s one-step capture region with
the step time, and the J_1 it implies (notation: ../shared/notes/anchors.md).

Linear inverted pendulum, omega = sqrt(g / z0). An impulse J at azimuth a on the robot at rest
puts the instantaneous capture point at xi_0 = c + J / (m omega) u(a). While the swing foot is in
the air the CoP r stays in the stance foot's sole S and xi diverges from it:
xi(dt) = r + (xi_0 - r) e^{omega dt}. The step captures (0-step capturable after touchdown) iff
xi(dt) lies in the new sole, p + F (p the swing ankle, F the sole relative to its ankle). So the
one-step region for the swing ankle is
    R_1 = { e xi_0 - (e - 1) r : r in S }  (+)  (-F),      e = e^{omega dt},
a Minkowski sum of convex polygons, intersected with the step reach |p - p_stand| <= l_max.
dt is from the push to touchdown (the step time included). Swing foot: the left one for
targets with y >= 0 (as tkujax.control.StepOverride), so R_1 is drawn per half-plane.
Caveats as tkujax.analysis.capturability: the push acts at the chest, not the CoM; the double
support before lift-off (CoP anywhere under both feet) is ignored, which makes R_1 conservative.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim import physics
from tkujax.analysis import capturability
from tkujax.analysis.capturability import G, convex_hull


@dataclasses.dataclass(frozen=True)
class Feet:
    """Stand-pose geometry, world (x, y) m: ankles, and each sole as a polygon around its ankle."""

    lip: capturability.LipModel
    ankle: dict                  # "l"/"r" -> (2,) stand ankle position
    sole: np.ndarray             # (4, 2) sole corners relative to the ankle (CCW)
    reach_m: float               # l_max


def stand_feet(model_params: ModelParams | None = None,
               params: ControllerParams | None = None) -> Feet:
    p = model_params or ModelParams()
    model = physics.host_model(model_params)
    data = physics.stand_data(model)
    ankle = {s: data.site_xpos[model.site(f"{s}_ankle").id][:2].copy() for s in ("l", "r")}
    hx, hy, fx = p.foot_length_m / 2, p.foot_width_m / 2, p.foot_forward_offset_m
    sole = np.array([[fx - hx, -hy], [fx + hx, -hy], [fx + hx, hy], [fx - hx, hy]])
    reach = capturability.step_reach_m(params or ControllerParams.paper(model_params))
    return Feet(lip=capturability.lip_model(model_params), ankle=ankle, sole=sole, reach_m=reach)


def icp_after_push(feet: Feet, impulse_ns, azimuth_rad) -> np.ndarray:
    """(..., 2) world capture point right after an impulse on the standing robot."""
    lip = feet.lip
    shift = np.asarray(impulse_ns, float) / (lip.mass_kg * lip.omega)
    az = np.asarray(azimuth_rad, float)
    return lip.com_xy_m + shift[..., None] * np.stack([np.cos(az), np.sin(az)], -1)


def minkowski(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return convex_hull((a[:, None, :] + b[None, :, :]).reshape(-1, 2))


def one_step_region(feet: Feet, impulse_ns: float, azimuth_rad: float, dt_s: float,
                    swing: str) -> np.ndarray:
    """R_1 for the `swing` ("l"/"r") ankle, in target coordinates (relative to its stand
    ankle), as a CCW polygon (not yet clipped to the reach or the half-plane)."""
    e = math.exp(feet.lip.omega * dt_s)
    stance = "r" if swing == "l" else "l"
    xi0 = icp_after_push(feet, impulse_ns, azimuth_rad)
    v = e * xi0 - (e - 1.0) * (feet.ankle[stance] + feet.sole)
    return minkowski(v, -feet.sole) - feet.ankle[swing]


def clip_half_plane(poly: np.ndarray, normal, offset: float) -> np.ndarray:
    """Sutherland-Hodgman: the part of a convex polygon with normal . p >= offset."""
    out = []
    n = len(poly)
    for i in range(n):
        a, b = poly[i], poly[(i + 1) % n]
        da, db = np.dot(normal, a) - offset, np.dot(normal, b) - offset
        if da >= 0:
            out.append(a)
        if da * db < 0:
            out.append(a + (b - a) * (da / (da - db)))
    return np.array(out).reshape(-1, 2)


def region_halves(feet: Feet, impulse_ns: float, azimuth_rad: float, dt_s: float) -> list:
    """R_1 in target coordinates as up to two polygons: left swing (y >= 0), right (y < 0)."""
    left = clip_half_plane(one_step_region(feet, impulse_ns, azimuth_rad, dt_s, "l"), (0, 1), 0)
    right = clip_half_plane(one_step_region(feet, impulse_ns, azimuth_rad, dt_s, "r"), (0, -1), 0)
    return [p for p in (left, right) if len(p) >= 3]


def point_polygon_distance(point, poly: np.ndarray) -> float:
    """Distance from a point to a convex CCW polygon (0 inside)."""
    point = np.asarray(point, float)
    edges = np.roll(poly, -1, 0) - poly
    inside = all(e[0] * (point[1] - a[1]) - e[1] * (point[0] - a[0]) >= 0
                 for a, e in zip(poly, edges))
    if inside:
        return 0.0
    t = np.clip(np.sum((point - poly) * edges, -1) / np.maximum(np.sum(edges**2, -1), 1e-18), 0, 1)
    return float(np.min(np.linalg.norm(poly + t[:, None] * edges - point, axis=-1)))


def region_reachable(feet: Feet, impulse_ns: float, azimuth_rad: float, dt_s: float) -> bool:
    """R_1 intersects the reach disc |target| <= l_max (on either swing side)."""
    return any(point_polygon_distance((0.0, 0.0), p) <= feet.reach_m
               for p in region_halves(feet, impulse_ns, azimuth_rad, dt_s))


def j1_theory(feet: Feet, azimuth_rad: float, dt_s: float, j_max: float = 20.0) -> float:
    """Theory's J_1: the largest impulse whose one-step region (with the step time dt_s) meets
    the reach; bisection (R_1 moves away monotonically as J grows)."""
    if not region_reachable(feet, 0.0, azimuth_rad, dt_s):
        return 0.0
    lo, hi = 0.0, j_max
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if region_reachable(feet, mid, azimuth_rad, dt_s) else (lo, mid)
    return lo


def lip_omega(z_m: float) -> float:
    return math.sqrt(G / z_m)
