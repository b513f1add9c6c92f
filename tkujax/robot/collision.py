"""Collision geometry made practical for MJX, on the model as loaded (the file is unchanged).

`[collision] mode` in a robot file (tkujax.robot.description) chooses:

- "primitives" (the default): every collision mesh on the robot becomes a box bounding its
  vertices, in the mesh's principal frame or in its body's frame, whichever box is smaller (on a
  foot always the body's frame, so the sole stays flat); the mesh geom stays, for its mass and
  its looks, with its collisions off; the box is massless, in the mesh's group, with its
  contact parameters (friction, solref, solimp, condim, margin, gap, priority). Self-collisions
  are off: each robot collision geom gets contype 0 and conaffinity bit 1, the world's
  colliding geoms (the floor) contype bit 1 (`world_only_collisions`, the one place that rule
  is written), so a robot geom touches the world and never the robot;
  explicit <pair>s between two robot geoms are removed, those with a world geom kept (a pair
  naming a replaced mesh then names its box). Spheres, capsules, boxes and the other primitives
  keep their shapes.
- "model": the model's collisions as written.

`[collision] floor = "feet"` (default "all") keeps the floor's contacts with the foot bodies
only (`feet_only`: the world excluded from every other robot body). A push study decides a
fall by the fall test, which reads geometry (a non-foot geom within FALL_BODY_CLEARANCE_M =
5 mm of the floor), not contacts: such a geom touches the floor only after the fall is decided.
OP3's contacts per step fall from 116 to 16 (docs/robots.md gives the measured compile and step
times, and the fall outcomes against "all").

MJX pays for mesh collisions at compile time and per step (convex-convex tests over every
colliding pair); a push study needs the robot against the floor: the feet's contacts and, for a
fall, any other body's. docs/robots.md gives the measured figures.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
from scipy.spatial import ConvexHull, QhullError

COLLISION_MODES = ("primitives", "model")
DEFAULT_COLLISION_MODE = "primitives"
FLOOR_CONTACTS = ("all", "feet")
DEFAULT_FLOOR_CONTACTS = "all"
MIN_HALF_SIZE_M = 1e-3          # a flat mesh still gets a box this thick
BOX_SUFFIX = "_tkujax_box"


@dataclasses.dataclass(frozen=True)
class BoxFit:
    """A box in a body's frame: centre (3,), orientation quaternion (4,), half sizes (3,)."""

    pos: np.ndarray
    quat: np.ndarray
    half_m: np.ndarray


@dataclasses.dataclass(frozen=True)
class CollisionChanges:
    """What `approximate_collisions` did (names or compiled ids of the model before it)."""

    boxed_meshes: tuple[int, ...]       # mesh geoms replaced by boxes
    self_collision_geoms: int           # robot geoms whose dynamic collisions became floor-only
    removed_pairs: int                  # robot-robot <pair>s removed
    # Each box's mesh as the fall test reads it: (box name, the mesh's convex-hull vertices in
    # the box's frame), so a fall is decided on the mesh, not on the box around it.
    box_mesh_points: tuple[tuple[str, np.ndarray], ...] = ()


def _mat(quat: np.ndarray) -> np.ndarray:
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, np.asarray(quat, np.float64))
    return rot.reshape(3, 3)


def _quat(rot: np.ndarray) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.ascontiguousarray(rot, np.float64).reshape(-1))
    return quat


def _aabb(points: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(centre, half sizes) of `points` (body frame) in the frame whose axes are rot's columns;
    the centre in the body frame."""
    local = points @ rot
    lo, hi = local.min(axis=0), local.max(axis=0)
    return rot @ (0.5 * (lo + hi)), np.maximum(0.5 * (hi - lo), MIN_HALF_SIZE_M)


def mesh_vertices_in_body(model: mujoco.MjModel, g: int) -> np.ndarray:
    """The vertices of mesh geom g in its body's frame."""
    m = model.geom_dataid[g]
    adr, n = model.mesh_vertadr[m], model.mesh_vertnum[m]
    verts = np.asarray(model.mesh_vert[adr:adr + n], np.float64)
    return verts @ _mat(model.geom_quat[g]).T + model.geom_pos[g]


def fit_box(model: mujoco.MjModel, g: int, body_frame: bool = False) -> BoxFit:
    """The box bounding mesh geom g: in the mesh's principal frame (the compiled geom frame)
    or in the body's frame, the smaller of the two; only the body's with `body_frame`."""
    points = mesh_vertices_in_body(model, g)
    frames = [np.eye(3)] if body_frame else [np.eye(3), _mat(model.geom_quat[g])]
    fits = [(*_aabb(points, rot), rot) for rot in frames]
    centre, half, rot = min(fits, key=lambda f: float(np.prod(f[1])))
    return BoxFit(pos=centre, quat=_quat(rot), half_m=half)


def _collides(model: mujoco.MjModel, g: int) -> bool:
    return bool(model.geom_contype[g] or model.geom_conaffinity[g])


def _add_box(spec_geom, model: mujoco.MjModel, g: int, fit: BoxFit) -> str:
    """A massless box beside spec_geom (same body, group and contact parameters); its name."""
    name = spec_geom.name + BOX_SUFFIX if spec_geom.name else f"tkujax_box_{g}"
    spec_geom.parent.add_geom(
        name=name, type=mujoco.mjtGeom.mjGEOM_BOX, size=fit.half_m, pos=fit.pos, quat=fit.quat,
        mass=0.0, density=0.0, group=int(model.geom_group[g]),
        contype=int(model.geom_contype[g]), conaffinity=int(model.geom_conaffinity[g]),
        condim=int(model.geom_condim[g]), friction=model.geom_friction[g],
        solref=model.geom_solref[g], solimp=model.geom_solimp[g],
        solmix=float(model.geom_solmix[g]), priority=int(model.geom_priority[g]),
        margin=float(model.geom_margin[g]), gap=float(model.geom_gap[g]),
        rgba=model.geom_rgba[g])
    return name


def _retarget_pairs(spec: mujoco.MjSpec, renamed: dict[str, str]) -> None:
    for pair in spec.pairs:
        if pair.geomname1 in renamed:
            pair.geomname1 = renamed[pair.geomname1]
        if pair.geomname2 in renamed:
            pair.geomname2 = renamed[pair.geomname2]


def hull_points(points: np.ndarray) -> np.ndarray:
    """The vertices of the convex hull of `points` (n, 3): the same lowest point in any pose,
    from a few hundred points where a mesh has tens of thousands. `points` as given where
    they span no volume."""
    try:
        return points[ConvexHull(points).vertices]
    except QhullError:
        return points


def _in_box_frame(model: mujoco.MjModel, g: int, fit: BoxFit) -> np.ndarray:
    """Mesh geom g's hull vertices in the frame of its fitted box."""
    points = hull_points(mesh_vertices_in_body(model, g))
    return (points - fit.pos) @ _mat(fit.quat)


def _box_meshes(spec: mujoco.MjSpec, model: mujoco.MjModel,
                feet: set[int]) -> tuple[list[int], list[tuple[str, np.ndarray]]]:
    """Replace each colliding robot mesh by a fitted box; the replaced geom ids, and each box's
    name with its mesh's hull vertices in the box's frame."""
    geoms = {g.id: g for g in spec.geoms}
    paired = set(model.pair_geom1.tolist()) | set(model.pair_geom2.tolist())
    renamed, boxed, points = {}, [], []
    for g in range(model.ngeom):
        if (model.geom_bodyid[g] == 0 or model.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH
                or not (_collides(model, g) or g in paired)):
            continue
        spec_geom = geoms[g]
        fit = fit_box(model, g, body_frame=int(model.geom_bodyid[g]) in feet)
        box = _add_box(spec_geom, model, g, fit)
        points.append((box, _in_box_frame(model, g, fit)))
        if spec_geom.name:
            renamed[spec_geom.name] = box
        spec_geom.contype, spec_geom.conaffinity = 0, 0
        boxed.append(g)
    _retarget_pairs(spec, renamed)
    return boxed, points


def _colliding_robot_geoms(spec: mujoco.MjSpec) -> list:
    """The spec's geoms on robot bodies (not the world) with a dynamic collision."""
    return [g for g in spec.geoms if g.parent.name != "world" and (g.contype or g.conaffinity)]


def world_only_collisions(robot_geoms, world_geoms) -> None:
    """The floor-only collision rule: each of robot_geoms (spec geoms on robot bodies) gets
    contype 0 and conaffinity bit 1, each of world_geoms contype bit 1, so such a robot geom
    touches those world geoms, and another robot geom only through that geom's own contype
    (none once every colliding robot geom has had this rule: no self-collision)."""
    for g in robot_geoms:
        g.contype, g.conaffinity = 0, int(g.conaffinity) | 1
    for g in world_geoms:
        g.contype = int(g.contype) | 1


def _floor_only(spec: mujoco.MjSpec, model: mujoco.MjModel) -> tuple[int, int]:
    """Robot geoms collide with the world's geoms only; (geoms changed, pairs removed)."""
    robot = _colliding_robot_geoms(spec)
    if robot:
        world_only_collisions(robot, [g for g in spec.worldbody.geoms
                                      if g.contype or g.conaffinity])
    world = {model.geom(g).name for g in range(model.ngeom) if model.geom_bodyid[g] == 0}
    removed = [p for p in spec.pairs
               if p.geomname1 not in world and p.geomname2 not in world]
    for pair in removed:
        spec.delete(pair)
    return len(robot), len(removed)


def approximate_collisions(spec: mujoco.MjSpec, model: mujoco.MjModel,
                           feet: set[int]) -> CollisionChanges:
    """Edit `spec` (compiled as `model`, spec.geoms' ids valid) for the "primitives" mode:
    colliding meshes to boxes, robot self-collisions off. `feet`: the foot bodies' ids."""
    boxed, points = _box_meshes(spec, model, feet)
    changed, removed = _floor_only(spec, model)
    return CollisionChanges(boxed_meshes=tuple(boxed), self_collision_geoms=changed,
                            removed_pairs=removed, box_mesh_points=tuple(points))


def feet_only(spec: mujoco.MjSpec, foot_bodies: set[str]) -> int:
    """Exclude the floor's contacts with every robot body outside foot_bodies (`[collision]
    floor = "feet"`): one <exclude> between the world and each such body that has a colliding
    geom. A <pair> of such a geom with a world geom becomes that geom's floor-only collision
    (`world_only_collisions`: contype 0, conaffinity bit 1, the world geom's contype bit 1),
    which the exclusion then stops. The geoms keep colliding in the model's bookkeeping, so
    the fall test still reads them (`tkujax.robot.simsetup.floor_geoms`). The number of
    bodies excluded."""
    geoms = {g.name: g for g in spec.geoms if g.name}
    for pair in list(spec.pairs):
        a, b = geoms.get(pair.geomname1), geoms.get(pair.geomname2)
        if a is None or b is None or (a.parent.name == "world") == (b.parent.name == "world"):
            continue
        world, body = (a, b) if a.parent.name == "world" else (b, a)
        if body.parent.name in foot_bodies:
            continue
        world_only_collisions([body], [world])
        spec.delete(pair)
    bodies = sorted({g.parent.name for g in _colliding_robot_geoms(spec)
                     if g.parent.name not in foot_bodies})
    for name in bodies:
        spec.add_exclude(bodyname1="world", bodyname2=name)
    return len(bodies)
