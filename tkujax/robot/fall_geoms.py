"""The geoms a robot file's fall test reads, and the points it reads them by.

The fall test (tkujax.sim.metrics) calls a push a fall when the pelvis drops below
FALL_PELVIS_HEIGHT_M or a non-foot collision geom comes within FALL_BODY_CLEARANCE_M (5 mm) of
the floor. For a robot file's model:

- the geoms are its collision geoms off the feet that can touch the floor (`floor_geoms`);
- a mesh is read by the vertices of its convex hull, and so is a mesh that the "primitives"
  collision mode replaced by a box (tkujax.robot.collision): the box collides, the mesh decides
  the fall. A box around a shin reaches well below the shin: Unitree G1's shank box is 13.5 mm
  above the floor at the stand where its mesh is 28.3 mm, and an ankle pitched in a step took
  the box within 5 mm with the robot upright (tests/test_fall_geom_choice.py);
- a geom already within STAND_CLEARANCE_MIN_M of the floor at the stand is left out: there it
  is (nearly) a fall before any push, so it cannot tell one. `tkujax stand` names it.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from tkujax.robot.collision import hull_points
from tkujax.robot.loader import RobotModel
from tkujax.sim.metrics import FALL_BODY_CLEARANCE_M
from tkujax.sim.recording import axial_lows

# A geom whose lowest point is closer than this to the floor at the stand is not read by the
# fall test: twice its 5 mm clearance, so that a sole's tilt of a few mm in a step does not
# make a fall of a stand (tests/test_fall_geom_choice.py).
STAND_CLEARANCE_MIN_M = 2 * FALL_BODY_CLEARANCE_M
# The rule as a robot file's sweep records it (tkujax.sweeps.sweep_hash): a sweep whose fall
# test read boxed meshes by their boxes is another sweep, never resumed into this one.
FALL_TEST_RULE = ("fall test: meshes and boxed meshes read by their hull vertices; geoms "
                  f"within {STAND_CLEARANCE_MIN_M:g} m of the floor at the stand left out")


@dataclasses.dataclass(frozen=True)
class FallGeoms:
    """What the fall test reads: primitive geoms by their shapes, meshes by points."""

    primitives: tuple[int, ...]            # spheres, boxes, capsules, cylinders
    point_geoms: tuple[int, ...]           # meshes, and the boxes that stand in for meshes
    points: tuple[np.ndarray, ...]         # (n_i, 3) per point geom, in its geom's frame
    left_out: tuple[tuple[str, float], ...] = ()   # (geom, its clearance at the stand, m)


def floor_geoms(robot: RobotModel) -> list[int]:
    """Collision geoms not on a foot that can touch the floor (a pair, or contype/conaffinity)."""
    model, floor = robot.model, robot.floor_geom
    feet = set(robot.foot_bodies.tolist())
    paired = {int(b) for a, b in zip(model.pair_geom1, model.pair_geom2) if a == floor} | {
        int(a) for a, b in zip(model.pair_geom1, model.pair_geom2) if b == floor}
    out = []
    for g in range(model.ngeom):
        if g == floor or model.geom_bodyid[g] in feet or model.geom_bodyid[g] == 0:
            continue
        collides = (model.geom_contype[g] & model.geom_conaffinity[floor]
                    or model.geom_conaffinity[g] & model.geom_contype[floor])
        if collides or g in paired:
            out.append(g)
    return out


def _mesh_points(model: mujoco.MjModel, g: int) -> np.ndarray:
    """Mesh geom g's hull vertices in its geom frame."""
    m = model.geom_dataid[g]
    adr, n = model.mesh_vertadr[m], model.mesh_vertnum[m]
    return hull_points(np.array(model.mesh_vert[adr:adr + n], np.float64))


def primitive_low(model: mujoco.MjModel, data: mujoco.MjData, g: int) -> float:
    """The lowest point's height of a sphere, box, capsule or cylinder, as the fall test reads
    it (tkujax.sim.recording); +inf for another type, which the fall test does not read."""
    kind, size = model.geom_type[g], model.geom_size[g]
    z, rot = data.geom_xpos[g][2], data.geom_xmat[g].reshape(3, 3)
    if kind == mujoco.mjtGeom.mjGEOM_SPHERE:
        return float(z - size[0])
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return float(z - np.abs(rot[2]) @ size)
    if kind in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
        return float(axial_lows(np, np.array([z]), np.array([rot[2, 2]]), size[None, :2],
                                kind == mujoco.mjtGeom.mjGEOM_CAPSULE)[0])
    return float("inf")


def _geom_name(model: mujoco.MjModel, g: int) -> str:
    return model.geom(g).name or f"geom {g} of body {model.body(model.geom_bodyid[g]).name!r}"


def fall_geoms(robot: RobotModel, stand_qpos: np.ndarray) -> FallGeoms:
    """The fall test's geoms of `robot` standing at `stand_qpos` (see the module doc)."""
    model = robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = stand_qpos
    mujoco.mj_kinematics(model, data)
    boxed = {int(g): pts for g, pts in robot.box_mesh_points}
    primitives, point_geoms, points, left_out = [], [], [], []
    for g in floor_geoms(robot):
        if g in boxed:
            local = boxed[g]
        elif model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH:
            local = _mesh_points(model, g)
        else:
            local = None
        if local is None:
            low = primitive_low(model, data, g)
        else:
            low = data.geom_xpos[g][2] + local @ data.geom_xmat[g].reshape(3, 3)[2]
        clearance = float(np.min(low))   # a height, as the fall test reads it (metrics)
        if clearance < STAND_CLEARANCE_MIN_M:
            left_out.append((_geom_name(model, g), round(clearance, 4)))
        elif local is None:
            primitives.append(g)
        else:
            point_geoms.append(g)
            points.append(local)
    return FallGeoms(tuple(primitives), tuple(point_geoms), tuple(points), tuple(left_out))
