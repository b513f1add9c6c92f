"""How far a standing robot's centre of mass is from tipping: its ground projection against
the support polygon, the convex hull of the feet's contact points with the floor (MuJoCo C).

`com_margins(robot, data)` gives, in the base's heading frame, how far the CoM's projection may
move forward, backward, left and right before it leaves the polygon, and its least distance to
any edge (negative: outside). A stand with a small backward margin tips backward at the
smallest push: the Berkeley Humanoid, standing 6.8 deg back, falls backward from pushes from
the front at 59 % below 4.3 N s (results/robots/berkeley_humanoid/README.md).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np
from scipy.spatial import ConvexHull, QhullError

from tkujax.robot.loader import RobotModel


def floor_contacts(robot: RobotModel, data: mujoco.MjData):
    """(body id, contact) of each contact between the floor and another geom."""
    for c in data.contact[:data.ncon]:
        if robot.floor_geom not in (c.geom1, c.geom2):
            continue
        other = c.geom2 if c.geom1 == robot.floor_geom else c.geom1
        yield int(robot.model.geom_bodyid[other]), c


def foot_contact_points(robot: RobotModel, data: mujoco.MjData) -> np.ndarray:
    """(k, 2) world (x, y) of the contacts between the floor and the feet's geoms."""
    feet = set(robot.foot_bodies.tolist())
    points = [np.array(c.pos[:2]) for body, c in floor_contacts(robot, data) if body in feet]
    return np.array(points).reshape(-1, 2)


def _exit_distance(equations: np.ndarray, p0: np.ndarray, u: np.ndarray) -> float:
    """How far p0 moves along the unit vector u before it leaves the hull n . p + d <= 0."""
    inside = -(equations[:, :2] @ p0 + equations[:, 2])      # >= 0 inside, per edge
    rate = equations[:, :2] @ u
    ahead = rate > 1e-12
    return float(np.min(inside[ahead] / rate[ahead])) if ahead.any() else math.inf


def com_margins(robot: RobotModel, data: mujoco.MjData) -> dict | None:
    """{front_m, back_m, left_m, right_m, least_m} of the CoM's ground projection in the
    support polygon (module doc), the directions in the base's heading; None when the feet's
    contacts span no polygon (fewer than three points, or all in a line)."""
    points = foot_contact_points(robot, data)
    if len(points) < 3:
        return None
    try:
        hull = ConvexHull(points)
    except QhullError:
        return None
    com = np.array(data.subtree_com[robot.root_body][:2])
    x_axis = data.xmat[robot.root_body].reshape(3, 3)[:2, 0]
    heading = x_axis / max(float(np.linalg.norm(x_axis)), 1e-12)
    left = np.array([-heading[1], heading[0]])
    eq = hull.equations
    least = float(np.min(-(eq[:, :2] @ com + eq[:, 2])))
    return dict(front_m=_exit_distance(eq, com, heading), back_m=_exit_distance(eq, com, -heading),
                left_m=_exit_distance(eq, com, left), right_m=_exit_distance(eq, com, -left),
                least_m=least)
