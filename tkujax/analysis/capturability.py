"""Analytic capturability bounds for TKU-X (Koolen et al. 2012; ../shared/notes/anchors.md).

Linear inverted pendulum at the stand pose: mass m, CoM height z0, omega = sqrt(g / z0). An
impulse J at rest shifts the instantaneous capture point by J / (m omega). The robot can stop
  with 0 steps if that shift stays inside the support polygon:  d_0 = r_max(azimuth)
  with N steps of max length l_max and min step time dt_s:
                                        d_N = r_max + l_max sum_k e^{-k omega dt_s}
so the largest recoverable impulse is J_N = m omega d_N. r_max is measured from the stand
pose's CoM ground projection to the edge of the two feet's convex hull along the push
direction; l_max is the CPG/IK reach (both ankles move by half the step relative to the waist,
so a leg of reach l_t + l_c allows 2 sqrt((l_t + l_c)^2 - d_z^2)); dt_s is the time from the
trigger to touchdown, T (1 - gamma / 2).

Caveat (said where sim and theory are compared): the LIP treats the push as acting at the CoM;
TKU-X is pushed at the chest, above the CoM, which also spins the body, and the 3D robot has
ankle torque and foot rotation the point-foot LIP ignores.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from tkujax.sim import physics
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams

G = 9.81


@dataclasses.dataclass(frozen=True)
class LipModel:
    mass_kg: float
    com_height_m: float
    com_xy_m: np.ndarray          # CoM ground projection in the stand pose
    support_polygon: np.ndarray   # (k, 2) convex hull of the soles, counter-clockwise

    @property
    def omega(self) -> float:
        return math.sqrt(G / self.com_height_m)


def _cross2(a, b) -> float:
    """z of the 2-D cross product (numpy 2 deprecates np.cross on 2-vectors)."""
    return float(a[0] * b[1] - a[1] * b[0])


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Andrew's monotone chain; counter-clockwise, no repeated end point."""
    pts = sorted(map(tuple, points))

    def half(seq):
        h = []
        for p in seq:
            while len(h) >= 2 and _cross2(np.subtract(h[-1], h[-2]), np.subtract(p, h[-2])) <= 0:
                h.pop()
            h.append(p)
        return h

    lower, upper = half(pts), half(reversed(pts))
    return np.array(lower[:-1] + upper[:-1])


def lip_model(model_params: ModelParams | None = None) -> LipModel:
    p = model_params or ModelParams()
    model = physics.host_model(model_params)
    data = physics.stand_data(model)
    corners = []
    for side in ("r", "l"):
        foot = model.body(f"{side}_foot").id
        centre = data.xpos[foot] + data.xmat[foot].reshape(3, 3) @ np.array(
            [p.foot_forward_offset_m, 0.0, 0.0])
        for sx in (-1, 1):
            for sy in (-1, 1):
                corners.append(centre[:2] + [sx * p.foot_length_m / 2, sy * p.foot_width_m / 2])
    com = data.subtree_com[model.body("pelvis").id]
    return LipModel(mass_kg=float(mujoco.mj_getTotalmass(model)), com_height_m=float(com[2]),
                    com_xy_m=com[:2].copy(), support_polygon=convex_hull(np.array(corners)))


def r_max(lip: LipModel, azimuth_rad) -> np.ndarray:
    """Distance (m) from the CoM projection to the support polygon edge along each azimuth."""
    az = np.atleast_1d(np.asarray(azimuth_rad, float))
    u = np.stack([np.cos(az), np.sin(az)], -1)                       # (n, 2)
    poly = lip.support_polygon
    edges = np.roll(poly, -1, axis=0) - poly
    normals = np.stack([edges[:, 1], -edges[:, 0]], -1)               # outward for CCW
    c = np.sum(normals * poly, -1)
    num = c[None] - normals @ lip.com_xy_m                            # (1, k), > 0 inside
    den = u @ normals.T                                               # (n, k)
    t = np.where(den > 1e-12, num / np.where(den > 1e-12, den, 1.0), np.inf)
    return t.min(-1)


def step_reach_m(params: ControllerParams) -> float:
    """l_max: the longest step the CPG's symmetric +-x/2 ankle motion can reach."""
    reach = params.thigh_length + params.calf_length
    return 2.0 * math.sqrt(max(reach**2 - params.hip_to_ankle_z**2, 0.0))


def step_time_s(params: ControllerParams) -> float:
    """dt_s: trigger to touchdown, T (1 - gamma / 2)."""
    return params.step_period * (1.0 - params.double_support_ratio / 2.0)


def capture_distance(lip: LipModel, azimuth_rad, n_steps: int | float,
                     params: ControllerParams) -> np.ndarray:
    """d_N (m); n_steps may be math.inf."""
    r = r_max(lip, azimuth_rad)
    if n_steps == 0:
        return r
    q = math.exp(-lip.omega * step_time_s(params))
    series = q / (1.0 - q) if math.isinf(n_steps) else sum(q**k for k in range(1, int(n_steps) + 1))
    return r + step_reach_m(params) * series


def max_impulse_ns(lip: LipModel, azimuth_rad, n_steps: int | float,
                   params: ControllerParams) -> np.ndarray:
    """J_N = m omega d_N (N s)."""
    return lip.mass_kg * lip.omega * capture_distance(lip, azimuth_rad, n_steps, params)


def capture_point_shift_m(lip: LipModel, impulse_ns) -> np.ndarray:
    """|Delta xi| = J / (m omega) for an impulse on the robot at rest."""
    return np.asarray(impulse_ns) / (lip.mass_kg * lip.omega)
