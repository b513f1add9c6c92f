"""A robot file's model, checked and completed: `load_robot(path_or_description)` -> RobotModel.

Checks (each a RobotFileError naming the key): the model compiles and has a floating base (a
free joint on a child of the world); every named joint and body exists (close matches listed);
each leg's joints are hinges forming the chain from the floating base to the foot: the three
hip joints first, in any order, then the knee, then the ankle joints in any order; joints above
the hips that are no leg's (a waist) are held at their stand angle by their servos; the left
foot lies to the left of the right one; each leg joint is driven by a position actuator (or
`[servo]` makes one: tkujax.robot.servos).

Completes (added through mujoco.MjSpec, never written back to the file): a floor when the model
has no plane in its world body; an IMU site at the named body's origin (unless `imu` names a
site) with a gyro and an accelerometer on it; a site at each ankle centre (where the ankle axes
meet); four touch sensors per sole, one per quadrant of the foot's collision geoms' footprint.
In the "primitives" collision mode (the default; tkujax.robot.collision) the robot's
collision meshes become fitted boxes and its self-collisions are off, before the completion.
Leg arrays are in tkujax's order: right then left, roles in LEG_ROLES order (`RobotModel.roles`:
the roles the legs have; a five-joint leg has no ankle_roll).
"""

from __future__ import annotations

import dataclasses
import difflib
from pathlib import Path

import mujoco
import numpy as np

from tkujax.robot.collision import approximate_collisions, feet_only
from tkujax.robot.description import (ANKLE_ROLES, HIP_ROLES, LEG_ROLES, RobotDescription,
                                      RobotFileError, load_description)
from tkujax.robot.servos import apply_servo, is_position_servo

LEG_ORDER = ("right", "left")
# The axis of each role in the base frame at the zero pose, up to sign (x forward, z up).
ROLE_AXES = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0], [1, 0, 0]], float)
AXIS_ALIGNED_TOL = 1e-6        # 1 - |cos| of an axis along its role's (0.08 deg)
GYRO, ACCEL, IMU_SITE = "tkujax_gyro", "tkujax_accel", "tkujax_imu"
HELD_JOINT_TYPES = (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE))
TOUCH_MARGIN_M = 0.01          # the touch sites reach this far below and above the sole


@dataclasses.dataclass(frozen=True, eq=False)
class RobotModel:
    """The compiled, completed model of a robot file and its indices (legs: right, left)."""

    description: RobotDescription
    model: mujoco.MjModel
    root_body: int                 # the floating base's body
    leg_joints: np.ndarray         # (2, n) joint ids, n = len(roles)
    leg_qpos: np.ndarray           # (2, n) qpos addresses
    leg_dofs: np.ndarray           # (2, n) dof addresses
    leg_actuators: np.ndarray      # (2, n) actuator ids
    axis_signs: np.ndarray         # (2, n) +1/-1: the joint axis against ROLE_AXES at zero
    axis_alignment: np.ndarray     # (2, n) |cos| of the angle between them (1: along it)
    foot_bodies: np.ndarray        # (2,)
    foot_geoms: tuple[frozenset, frozenset]   # collision geoms of each foot body
    floor_geom: int
    imu_site: int
    ankle_sites: tuple[int, int]
    fsr_sites: np.ndarray          # (8,) right 1-4, left 1-4
    fsr_sensors: tuple[str, ...]
    waist_joints: tuple[int, ...] = ()        # joints above the hips on a leg's chain
    chain_order: tuple[tuple[str, ...], tuple[str, ...]] = (LEG_ROLES, LEG_ROLES)  # base first
    # (box geom, its mesh's hull vertices in the box's frame) for each mesh the "primitives"
    # collision mode boxed (tkujax.robot.collision): what the fall test reads in its place.
    box_mesh_points: tuple[tuple[int, np.ndarray], ...] = ()

    @property
    def name(self) -> str:
        return self.description.name

    @property
    def roles(self) -> tuple[str, ...]:
        """The roles each leg has, in LEG_ROLES order (the columns of the leg arrays)."""
        return self.description.roles

    def column(self, role: str) -> int:
        """The column of `role` in the leg arrays."""
        return self.roles.index(role)

    def columns(self, roles) -> list[int]:
        """The columns of those of `roles` the legs have."""
        return [self.roles.index(r) for r in roles if r in self.roles]

    @property
    def tkux_chain(self) -> bool:
        """Whether both legs are TKU-X's chain: six joints, hip yaw, roll, pitch, knee, ankle
        pitch, roll from the base (the controller's own joint conventions)."""
        return all(order == LEG_ROLES for order in self.chain_order)

    @property
    def joint_for_joint(self) -> bool:
        """Whether the controller's joint angles map onto the robot's one for one (sign and
        offset, `tkujax.robot.leg_map.sign_map`): TKU-X's chain with every axis along its
        role's, either way. The Berkeley Humanoid's order is TKU-X's, but its hip joints turn
        about axes tilted 45 degrees (tests/test_robot_chains.py)."""
        return self.tkux_chain and bool(np.all(self.axis_alignment > 1.0 - AXIS_ALIGNED_TOL))


def _compile(spec: mujoco.MjSpec, where: str) -> mujoco.MjModel:
    try:
        return spec.compile()
    except ValueError as err:
        raise RobotFileError(f"mjcf: {where} does not compile: {err}") from err


def _names(model: mujoco.MjModel, obj: mujoco.mjtObj, count: int) -> list[str]:
    return [mujoco.mj_id2name(model, obj, i) or "" for i in range(count)]


def _find(model, obj, count: int, name: str, key: str, kind: str) -> int:
    i = mujoco.mj_name2id(model, obj, name)
    if i < 0:
        close = difflib.get_close_matches(name, _names(model, obj, count), n=4, cutoff=0.5)
        hint = f"; close matches: {close}" if close else ""
        raise RobotFileError(f"{key}: no {kind} named {name!r} in the model{hint}")
    return i


def _root_body(model: mujoco.MjModel) -> int:
    for j in range(model.njnt):
        body = int(model.jnt_bodyid[j])
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE and model.body_parentid[body] == 0:
            return body
    raise RobotFileError("mjcf: the model has no floating base (a free joint on a body whose "
                         "parent is the world); tkujax simulates a free-standing robot")


def _path_joints(model: mujoco.MjModel, root: int, foot: int) -> list[int] | None:
    """Joints on the body path from `root` (excluded) down to `foot`, base first; None when
    `foot` is not below `root`."""
    bodies = []
    b = foot
    while b != root:
        if b == 0:
            return None
        bodies.append(b)
        b = int(model.body_parentid[b])
    joints = []
    for b in reversed(bodies):
        adr, n = int(model.body_jntadr[b]), int(model.body_jntnum[b])
        joints.extend(range(adr, adr + n))
    return joints


def _check_chain(model, root: int, side: str, roles: tuple[str, ...], joints: list[int],
                 foot: int) -> tuple[list[int], tuple[str, ...]]:
    """(the joints above the hips on the chain, the roles in chain order); raises when the leg
    is not hips (any order), knee, ankles (any order) from the base to the foot."""
    desc = lambda j: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)  # noqa: E731
    for role, j in zip(roles, joints):
        if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE:
            raise RobotFileError(f"legs.{side}.{role}: joint {desc(j)!r} is not a hinge")
    path = _path_joints(model, root, foot)
    if path is None:
        raise RobotFileError(f"legs.{side}.foot: body {model.body(foot).name!r} is not below the "
                             "floating base")
    n = len(joints)
    above, tail = path[:-n] if len(path) > n else [], path[-n:]
    role_of = dict(zip(joints, roles))
    order = tuple(role_of.get(j, "?") for j in tail)
    groups = [set(order[:3]), set(order[3:4]), set(order[4:])]
    wanted = [set(HIP_ROLES), {"knee"}, set(ANKLE_ROLES) & set(roles)]
    if set(tail) != set(joints) or groups != wanted or any(j in role_of for j in above):
        raise RobotFileError(
            f"legs.{side}: the joints are not the chain from the floating base to the foot "
            f"{model.body(foot).name!r}: that chain is {[desc(j) for j in path]}, the file gives "
            f"{[desc(j) for j in joints]} (roles {list(roles)}; a leg is the three hip joints "
            "in any order, the knee, then the ankle joints; joints above the hips, such as a "
            "waist, are allowed)")
    return list(above), order


def _position_actuator(model, joint: int, key: str) -> int:
    for a in range(model.nu):
        if model.actuator_trnid[a, 0] == joint and is_position_servo(model, a):
            return a
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
    raise RobotFileError(f"{key}: joint {name!r} has no position actuator (a <position> with "
                         "gear 1 on that joint); give a [servo] table (kp, kv) to drive the "
                         "legs as PD position servos")


def axis_point(anchors: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """The point nearest, in least squares, to the lines through `anchors` along `axes`."""
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for p, u in zip(anchors, axes):
        u = u / np.linalg.norm(u)
        proj = np.eye(3) - np.outer(u, u)
        a += proj
        b += proj @ p
    return np.linalg.lstsq(a, b, rcond=None)[0]


def zero_pose_data(model: mujoco.MjModel, root: int) -> mujoco.MjData:
    """Kinematics at qpos0 with the floating base at the origin, unrotated."""
    data = mujoco.MjData(model)
    adr = int(model.jnt_qposadr[model.body_jntadr[root]])
    data.qpos[adr:adr + 7] = (0, 0, 0, 1, 0, 0, 0)
    mujoco.mj_kinematics(model, data)
    return data


def _foot_geoms(model: mujoco.MjModel, foot: int) -> list[int]:
    paired = set(model.pair_geom1.tolist()) | set(model.pair_geom2.tolist())
    return [g for g in range(model.ngeom) if model.geom_bodyid[g] == foot
            and (model.geom_contype[g] or model.geom_conaffinity[g] or g in paired)]


def geom_points(model: mujoco.MjModel, g: int) -> np.ndarray:
    """Points bounding geom g in its body's frame (box corners, sphere/capsule extremes, mesh
    vertices): a footprint and a lowest point good to the geom's shape."""
    t, size = model.geom_type[g], model.geom_size[g]
    if t == mujoco.mjtGeom.mjGEOM_MESH:
        m = model.geom_dataid[g]
        adr, n = model.mesh_vertadr[m], model.mesh_vertnum[m]
        local = model.mesh_vert[adr:adr + n]
    else:
        if t == mujoco.mjtGeom.mjGEOM_BOX:
            half = size
        elif t == mujoco.mjtGeom.mjGEOM_SPHERE:
            half = np.full(3, size[0])
        elif t == mujoco.mjtGeom.mjGEOM_CAPSULE or t == mujoco.mjtGeom.mjGEOM_CYLINDER:
            half = np.array([size[0], size[0], size[1] + size[0]])
        else:
            half = size
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        local = signs * half
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[g])
    return local @ rot.reshape(3, 3).T + model.geom_pos[g]


def _sole_quadrants(model, foot: int, side: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """(centre, half size) of the four touch sites of a foot, in its body frame; numbered 1
    front-right, 2 front-left, 3 back-left, 4 back-right (seen from above), as TKU-X's."""
    geoms = _foot_geoms(model, foot)
    if not geoms:
        raise RobotFileError(f"legs.{side}.foot: body {model.body(foot).name!r} has no collision "
                             "geom (the sole)")
    pts = np.concatenate([geom_points(model, g) for g in geoms])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    mid = 0.5 * (lo + hi)
    # Each quadrant reaches TOUCH_MARGIN_M beyond the sole's outer edges, so that a contact at
    # a sole corner (a box foot's contacts all are) lies inside it, not on its boundary.
    quarter = np.array([0.25 * (hi[0] - lo[0]), 0.25 * (hi[1] - lo[1])])
    half = np.array([*(quarter + 0.5 * TOUCH_MARGIN_M), TOUCH_MARGIN_M])
    quads = [(1, -1), (1, 1), (-1, 1), (-1, -1)]
    return [(np.array([mid[0] + sx * half[0], mid[1] + sy * half[1], lo[2]]), half)
            for sx, sy in quads]


def _has_floor(model: mujoco.MjModel) -> int:
    for g in range(model.ngeom):
        if model.geom_bodyid[g] == 0 and model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            return g
    return -1


def _leg_indices(model, root: int, desc: RobotDescription, side: str):
    """(joint ids in role order, foot body, joints above the hips, roles in chain order)."""
    leg = desc.leg(side)
    joints = [_find(model, mujoco.mjtObj.mjOBJ_JOINT, model.njnt, name, f"legs.{side}.{role}",
                    "joint") for role, name in zip(leg.roles, leg.joints)]
    foot = _find(model, mujoco.mjtObj.mjOBJ_BODY, model.nbody, leg.foot, f"legs.{side}.foot",
                 "body")
    above, order = _check_chain(model, root, side, leg.roles, joints, foot)
    if desc.servo is None:
        for role, j in zip(leg.roles, joints):
            _position_actuator(model, j, f"legs.{side}.{role}")
    return joints, foot, above, order


def _check_sides(model, root: int, feet: dict) -> None:
    """The left foot lies to the left (+y in the base frame) of the right one at the zero pose."""
    data = zero_pose_data(model, root)
    rot = data.xmat[root].reshape(3, 3)
    y = {side: float((data.xpos[foot] - data.xpos[root]) @ rot[:, 1])
         for side, foot in feet.items()}
    if y["left"] <= y["right"]:
        raise RobotFileError(
            f"legs: legs.left's foot {model.body(feet['left']).name!r} lies {1e3 * y['left']:.1f} "
            f"mm to the left of the base and legs.right's {model.body(feet['right']).name!r} "
            f"{1e3 * y['right']:.1f} mm: the left leg must be on the +y side (left and right "
            "swapped?)")


def _apply_servos(spec, raw, desc: RobotDescription, legs: dict, waist: set[int]) -> None:
    """[servo]: the leg joints as PD servos; [servo.other]: every other actuated joint and the
    waist joints too."""
    table = desc.servo
    if table is None:
        return
    leg_ids = set()
    for side in LEG_ORDER:
        for role, j in zip(desc.roles, legs[side][0]):
            apply_servo(spec, raw, j, table.legs.of(role))
            leg_ids.add(j)
    if table.other is None:
        return
    others = {int(raw.actuator_trnid[a, 0]) for a in range(raw.nu)
              if raw.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT} | waist
    for j in sorted(others - leg_ids):
        if int(raw.jnt_type[j]) in HELD_JOINT_TYPES:
            apply_servo(spec, raw, j, table.other.of("*"))


def _check_waist(model, waist: set[int]) -> None:
    """Each joint above the hips is held by a position servo."""
    for j in sorted(waist):
        if not any(model.actuator_trnid[a, 0] == j and is_position_servo(model, a)
                   for a in range(model.nu)):
            name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j)
            raise RobotFileError(
                f"legs: joint {name!r} sits between the floating base and the legs and has no "
                "position servo to hold it at the stand; give [servo.other] (kp, kv)")


def _imu_body(model, name: str) -> int | None:
    """None when `imu` names a site; the body id when it names a body."""
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name) >= 0:
        return None
    if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name) >= 0:
        return model.body(name).id
    names = _names(model, mujoco.mjtObj.mjOBJ_BODY, model.nbody) + _names(
        model, mujoco.mjtObj.mjOBJ_SITE, model.nsite)
    close = difflib.get_close_matches(name, names, n=4, cutoff=0.5)
    hint = f"; close matches: {close}" if close else ""
    raise RobotFileError(f"imu: no body or site named {name!r} in the model{hint}")


def ankle_point(data: mujoco.MjData, knee: int, ankles: list[int]) -> np.ndarray:
    """The ankle centre: where the ankle axes meet; with one ankle axis, its point nearest
    the knee's anchor (the leg's own plane)."""
    if len(ankles) >= 2:
        return axis_point(data.xanchor[ankles], data.xaxis[ankles])
    u = data.xaxis[ankles[0]] / np.linalg.norm(data.xaxis[ankles[0]])
    a = data.xanchor[ankles[0]]
    return a + np.dot(data.xanchor[knee] - a, u) * u


def _ankle_centre_in_foot(model, data, joints: list[int], foot: int,
                          roles: tuple[str, ...]) -> np.ndarray:
    ankles = [joints[roles.index(r)] for r in ANKLE_ROLES if r in roles]
    centre = ankle_point(data, joints[roles.index("knee")], ankles)
    rot = data.xmat[foot].reshape(3, 3)
    return rot.T @ (centre - data.xpos[foot])


def _complete(spec: mujoco.MjSpec, raw: mujoco.MjModel, desc: RobotDescription, root: int,
              legs: dict) -> tuple[str, list[str], list[str]]:
    """Add the floor, the IMU site and sensors, the ankle sites and the touch sensors to
    `spec`; returns (imu site name, ankle site names, touch sensor names), right leg first."""
    if _has_floor(raw) < 0:
        spec.worldbody.add_geom(name="tkujax_floor", type=mujoco.mjtGeom.mjGEOM_PLANE,
                                size=[0, 0, 0.05])
    imu = desc.imu
    body = _imu_body(raw, imu)
    if body is not None:
        imu = IMU_SITE
        spec.body(desc.imu).add_site(name=imu, pos=[0, 0, 0])
    for name, kind in ((GYRO, mujoco.mjtSensor.mjSENS_GYRO),
                       (ACCEL, mujoco.mjtSensor.mjSENS_ACCELEROMETER)):
        spec.add_sensor(name=name, type=kind, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=imu)
    data = zero_pose_data(raw, root)
    ankles, touch = [], []
    for side in LEG_ORDER:
        joints, foot = legs[side][:2]
        fbody = spec.body(raw.body(foot).name)
        ankles.append(f"tkujax_{side[0]}_ankle")
        fbody.add_site(name=ankles[-1],
                       pos=_ankle_centre_in_foot(raw, data, joints, foot, desc.roles))
        for i, (centre, half) in enumerate(_sole_quadrants(raw, foot, side), start=1):
            touch.append(f"tkujax_{side[0]}_fsr_{i}")
            fbody.add_site(name=touch[-1], type=mujoco.mjtGeom.mjGEOM_BOX, pos=centre, size=half)
            spec.add_sensor(name=touch[-1], type=mujoco.mjtSensor.mjSENS_TOUCH,
                            objtype=mujoco.mjtObj.mjOBJ_SITE, objname=touch[-1])
    return imu, ankles, touch


def _axis_dots(model, root: int, joints: np.ndarray, roles: tuple[str, ...]) -> np.ndarray:
    """(2, n) each leg joint's unit axis dotted with its role's axis (ROLE_AXES), in the base
    frame at the zero pose."""
    data = zero_pose_data(model, root)
    rot = data.xmat[root].reshape(3, 3)
    axes = data.xaxis[joints] @ rot                     # (2, n, 3) in the base frame
    return np.einsum("sjk,jk->sj", axes, ROLE_AXES[[LEG_ROLES.index(r) for r in roles]])


def _use_tkujax_integrator(model: mujoco.MjModel) -> None:
    """Semi-implicit Euler without eulerdamp, whatever the model asks: the MuJoCo C rollout
    chains the solver's warm start through qvel' = qvel + dt qacc, which holds only then
    (tkujax.sim.rollout_mujoco), and MJX then steps the same integrator. The stand check runs
    it too, so a robot that stands here stands in the sweeps."""
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
    model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)


def _cap_solver(model: mujoco.MjModel, desc: RobotDescription) -> None:
    """The robot file's [solver] caps, where it gives them. MJX's batched solver runs every lane
    to its line-search cap, which then sets a step's cost (docs/robots.md, "The solver's caps")."""
    if desc.solver_iterations is not None:
        model.opt.iterations = desc.solver_iterations
    if desc.ls_iterations is not None:
        model.opt.ls_iterations = desc.ls_iterations


def load_robot(robot: RobotDescription | str | Path) -> RobotModel:
    """The checked and completed model of a robot file (or a parsed description)."""
    desc = robot if isinstance(robot, RobotDescription) else load_description(robot)
    try:
        spec = mujoco.MjSpec.from_file(str(desc.mjcf_path))
    except ValueError as err:
        raise RobotFileError(f"mjcf: {desc.mjcf_path} could not be read: {err}") from err
    raw = _compile(spec, str(desc.mjcf_path))
    root = _root_body(raw)
    legs = {side: _leg_indices(raw, root, desc, side) for side in LEG_ORDER}
    _check_sides(raw, root, {side: legs[side][1] for side in LEG_ORDER})
    waist = set(legs["right"][2]) | set(legs["left"][2])
    _apply_servos(spec, raw, desc, legs, waist)
    boxed = ()
    if desc.collision_mode == "primitives":
        boxed = approximate_collisions(spec, raw, {legs[s][1] for s in LEG_ORDER}).box_mesh_points
    if desc.floor_contacts == "feet":
        feet_only(spec, {raw.body(legs[s][1]).name for s in LEG_ORDER})
    raw = _compile(spec, f"{desc.mjcf_path} with tkujax's servos and collisions")
    imu, ankles, touch = _complete(spec, raw, desc, root, legs)
    model = _compile(spec, f"{desc.mjcf_path} with tkujax's sensors")
    _check_waist(model, waist)
    _use_tkujax_integrator(model)
    _cap_solver(model, desc)
    joints = np.array([legs[s][0] for s in LEG_ORDER])
    dots = _axis_dots(model, root, joints, desc.roles)
    feet = np.array([legs[s][1] for s in LEG_ORDER])
    geoms = tuple(frozenset(_foot_geoms(model, int(f))) for f in feet)
    actuators = np.array([[_position_actuator(model, int(j), f"legs.{side}.{role}")
                           for j, role in zip(row, desc.roles)]
                          for row, side in zip(joints, LEG_ORDER)])
    return RobotModel(
        description=desc, model=model, root_body=root, leg_joints=joints,
        leg_qpos=model.jnt_qposadr[joints], leg_dofs=model.jnt_dofadr[joints],
        leg_actuators=actuators, axis_signs=np.where(dots >= 0, 1, -1).astype(int),
        axis_alignment=np.abs(dots),
        foot_bodies=feet, foot_geoms=geoms, floor_geom=_has_floor(model),
        imu_site=model.site(imu).id,
        ankle_sites=(model.site(ankles[0]).id, model.site(ankles[1]).id),
        fsr_sites=np.array([model.site(n).id for n in touch]), fsr_sensors=tuple(touch),
        waist_joints=tuple(sorted(waist)),
        chain_order=(legs["right"][3], legs["left"][3]),
        box_mesh_points=tuple((model.geom(name).id, pts) for name, pts in boxed))
