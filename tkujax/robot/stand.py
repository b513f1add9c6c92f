"""A robot's standing pose, and the check that it stands (MuJoCo C, the servos holding it).

`stand_pose(robot)`: the robot file's keyframe or joint angles, else a computed bent-knee stand:
the base upright, the soles flat under the hips as in the model's zero pose, the hip-to-ankle
height `hip_height_frac` x the zero pose's, both feet moved fore-aft until the CoM is over the
middle of the soles, and the base lowered until the soles touch the floor.
`check_stand(robot, pose, seconds)` holds the pose's targets and measures; `require_stand`
raises RobotStandError saying why a robot cannot stand (the body that touched the floor, the
CoM's drift).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from tkujax.robot.description import RobotFileError
from tkujax.robot.geometry import base_pitch_roll, floor_height_m, link_lengths
from tkujax.robot.ik_numeric import base_data, foot_pose, solve_leg_ik
from tkujax.robot.loader import LEG_ORDER, RobotModel, geom_points
from tkujax.robot.stand_torques import explain_failed_stand
from tkujax.robot.support import com_margins, floor_contacts

COM_DRIFT_LIMIT_FRAC = 0.25     # of thigh + calf: the CoM may wander this far and still stand
TILT_LIMIT_DEG = 20.0


class RobotStandError(ValueError):
    """The robot does not stand; the message says why, with the measurement."""


@dataclasses.dataclass(frozen=True)
class StandPose:
    """Where the stand starts: the full qpos, the actuator targets, and where it came from."""

    qpos: np.ndarray
    ctrl: np.ndarray
    source: str


@dataclasses.dataclass(frozen=True)
class StandResult:
    """What holding the stand for `seconds` measured (MuJoCo C)."""

    seconds: float
    stood: bool
    why: str
    base_height_start_m: float
    base_height_end_m: float
    pitch_end_deg: float
    roll_end_deg: float
    max_tilt_change_deg: float
    com_drift_m: float
    sole_force_fraction: float        # sole touch sensors / (m g) at the end
    floor_contact_body: str | None    # the first body other than a foot to touch the floor
    floor_contact_time_s: float | None
    servo_shortfalls: tuple[str, ...] = ()   # when it fell: the servos that fall short of it
    # The settled CoM's room in the support polygon (tkujax.robot.support.com_margins), m.
    com_margin_m: dict | None = None

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def _root_adr(robot: RobotModel) -> int:
    return int(robot.model.jnt_qposadr[robot.model.body_jntadr[robot.root_body]])


def hold_targets(robot: RobotModel, qpos: np.ndarray) -> np.ndarray:
    """Actuator targets holding `qpos`: each joint position actuator at its joint's angle
    (clipped to its control range); any other actuator at 0."""
    model = robot.model
    ctrl = np.zeros(model.nu)
    for a in range(model.nu):
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT:
            j = model.actuator_trnid[a, 0]
            kind = int(model.jnt_type[j])
            if kind in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                ctrl[a] = qpos[model.jnt_qposadr[j]]
    limited = model.actuator_ctrllimited.astype(bool)
    rng = model.actuator_ctrlrange
    return np.where(limited, np.clip(ctrl, rng[:, 0], rng[:, 1]), ctrl)


def _lowest_foot_point(robot: RobotModel, data: mujoco.MjData) -> float:
    lowest = np.inf
    for geoms in robot.foot_geoms:
        for g in geoms:
            b = robot.model.geom_bodyid[g]
            pts = geom_points(robot.model, g) @ data.xmat[b].reshape(3, 3).T + data.xpos[b]
            lowest = min(lowest, float(pts[:, 2].min()))
    return lowest


def _on_floor(robot: RobotModel, qpos: np.ndarray) -> np.ndarray:
    """`qpos` with the base raised or lowered so the lowest sole point is on the floor."""
    model, data = robot.model, mujoco.MjData(robot.model)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(model, data)
    out = qpos.copy()
    out[_root_adr(robot) + 2] += floor_height_m(robot) - _lowest_foot_point(robot, data)
    return out


def _bent_legs(robot: RobotModel, frac: float, forward_m: float, data) -> np.ndarray:
    """Leg angles (2, n) for soles flat under the hips, `frac` of the straight height,
    moved `forward_m` forward; raises when the IK does not converge."""
    straight = base_data(robot)
    out = []
    for i, side in enumerate(LEG_ORDER):
        pos, rot = foot_pose(robot, straight, side)
        hip_z = straight.xanchor[robot.leg_joints[i][robot.column("hip_pitch")]][2]
        target = np.array([pos[0] + forward_m, pos[1], hip_z - frac * (hip_z - pos[2])])
        sol = solve_leg_ik(robot, side, target, rot, q_init=_knee_bend(robot, i), data=data)
        if not sol.converged:
            raise RobotFileError(f"stand: no leg pose puts the {side} sole flat at "
                                 f"{frac:.2f} of the leg's height (IK error "
                                 f"{1e3 * sol.position_error_m:.2f} mm)")
        out.append(sol.q_rad)
    return np.array(out)


def _knee_bend(robot: RobotModel, i: int) -> np.ndarray:
    """A start for the IK with the knee bent 0.5 rad forward (the shin swung backward), the
    thigh forward and the ankle back by half that, in each joint's own sign."""
    bend = {"hip_pitch": -0.25, "knee": 0.5, "ankle_pitch": -0.25}
    q = np.array([bend.get(role, 0.0) for role in robot.roles])
    return q * robot.axis_signs[i]


def computed_stand(robot: RobotModel, frac: float) -> np.ndarray:
    """The bent-knee stand's qpos (see the module doc)."""
    model = robot.model
    data = base_data(robot)
    forward = 0.0
    for _ in range(30):
        legs = _bent_legs(robot, frac, forward, data)
        for i in range(2):
            data.qpos[robot.leg_qpos[i]] = legs[i]
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        sole_x = data.site_xpos[robot.fsr_sites][:, 0].mean()
        err = data.subtree_com[robot.root_body][0] - sole_x
        if abs(err) < 1e-5:
            break
        forward += err
    return _on_floor(robot, data.qpos.copy())


def stand_pose(robot: RobotModel) -> StandPose:
    """The robot file's stand: its keyframe, its joint angles, or the computed stand."""
    model, stand = robot.model, robot.description.stand
    if stand.keyframe is not None:
        k = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_KEY, stand.keyframe)
        if k < 0:
            names = [model.key(i).name for i in range(model.nkey)]
            raise RobotFileError(f"stand.keyframe: no keyframe named {stand.keyframe!r} in the "
                                 f"model (keyframes: {names})")
        qpos = model.key_qpos[k].copy()
        ctrl = model.key_ctrl[k].copy() if model.nu else np.zeros(0)
        return StandPose(qpos, ctrl, f"keyframe {stand.keyframe!r}")
    if stand.joints:
        qpos = model.qpos0.copy()
        for name, angle in stand.joints:
            j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            if j < 0:
                raise RobotFileError(f"stand.joints.{name}: no joint named {name!r} in the model")
            qpos[model.jnt_qposadr[j]] = angle
        qpos = _on_floor(robot, qpos)
        return StandPose(qpos, hold_targets(robot, qpos), "stand.joints")
    qpos = computed_stand(robot, stand.hip_height_frac)
    return StandPose(qpos, hold_targets(robot, qpos),
                     f"computed (hip height {stand.hip_height_frac:g} of the straight leg)")


def _floor_contact(robot: RobotModel, data: mujoco.MjData) -> str | None:
    """The first body other than a foot touching the floor, or None."""
    feet = set(robot.foot_bodies.tolist())
    for body, _ in floor_contacts(robot, data):
        if body not in feet:
            return robot.model.body(body).name
    return None


def check_stand(robot: RobotModel, pose: StandPose, seconds: float = 5.0) -> StandResult:
    """Hold `pose`'s targets for `seconds` in MuJoCo C and measure what happened."""
    model = robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = pose.qpos
    data.ctrl[:] = pose.ctrl
    mujoco.mj_forward(model, data)
    adr, root = _root_adr(robot), robot.root_body
    z0, com0 = float(data.qpos[adr + 2]), data.subtree_com[root][:2].copy()
    tilt0 = np.array(base_pitch_roll(data.qpos[adr + 3:adr + 7]))
    max_tilt, touched, touched_at = 0.0, None, None
    for _ in range(int(round(seconds / model.opt.timestep))):
        mujoco.mj_step(model, data)
        tilt = np.array(base_pitch_roll(data.qpos[adr + 3:adr + 7]))
        max_tilt = max(max_tilt, float(np.abs(np.rad2deg(tilt - tilt0)).max()))
        if touched is None:
            touched = _floor_contact(robot, data)
            touched_at = round(float(data.time), 3) if touched else None
    mujoco.mj_forward(model, data)
    drift = float(np.linalg.norm(data.subtree_com[root][:2] - com0))
    weight = float(model.body_subtreemass[root] * -model.opt.gravity[2])
    sole = sum(float(data.sensor(n).data[0]) for n in robot.fsr_sensors)
    pitch, roll = np.rad2deg(base_pitch_roll(data.qpos[adr + 3:adr + 7]))
    drift_limit = COM_DRIFT_LIMIT_FRAC * _reach(robot)
    why = ""
    if touched:
        why = f"body {touched!r} touched the floor at t = {touched_at} s"
    elif max_tilt > TILT_LIMIT_DEG:
        why = f"the base tilted {max_tilt:.1f} deg (limit {TILT_LIMIT_DEG:g})"
    elif drift > drift_limit:
        why = f"the CoM drifted {1e3 * drift:.1f} mm (limit {1e3 * drift_limit:.1f} mm)"
    short = explain_failed_stand(robot, pose.qpos, pose.ctrl, seconds) if why else ()
    if short:
        why += "; " + "; ".join(short)
    return StandResult(
        seconds=seconds, stood=not why, why=why or "stood", base_height_start_m=z0,
        base_height_end_m=float(data.qpos[adr + 2]), pitch_end_deg=float(pitch),
        roll_end_deg=float(roll), max_tilt_change_deg=max_tilt, com_drift_m=drift,
        sole_force_fraction=sole / weight if weight > 0 else 0.0,
        floor_contact_body=touched, floor_contact_time_s=touched_at, servo_shortfalls=short,
        com_margin_m=None if why else com_margins(robot, data))


def _reach(robot: RobotModel) -> float:
    return sum(link_lengths(robot))


def require_stand(robot: RobotModel, pose: StandPose | None = None,
                  seconds: float = 5.0) -> StandResult:
    """`check_stand`, raising RobotStandError (with the measurement) when the robot falls."""
    pose = pose or stand_pose(robot)
    result = check_stand(robot, pose, seconds)
    if not result.stood:
        raise RobotStandError(f"{robot.name} cannot stand {seconds:g} s from its stand "
                              f"({pose.source}): {result.why}")
    return result
