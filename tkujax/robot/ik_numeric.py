"""Leg IK for any joint axes and offsets, through MuJoCo's Jacobians (MuJoCo C, numpy).

The foot pose is the ankle centre (the `tkujax_*_ankle` site, where the ankle axes meet) and the
foot body's orientation, both relative to the floating base's frame. `solve_leg_ik` runs damped
least squares on the leg's six joints with `mj_jacSite`, inside the joint ranges.
`analytic_ik_applies` says whether the closed form of `tkujax.control.ik` / `solve.py` holds
for a robot: TKU-X's axes, signs and offsets.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from tkujax.robot.geometry import hip_and_ankle_centres
from tkujax.robot.loader import LEG_ORDER, ROLE_AXES, RobotModel, zero_pose_data

LEG_ROLE_NAMES = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")


@dataclasses.dataclass(frozen=True)
class LegIK:
    """A leg IK solution: joint angles (rad, role order) and its remaining errors."""

    q_rad: np.ndarray
    position_error_m: float
    rotation_error_rad: float
    iterations: int

    @property
    def converged(self) -> bool:
        return self.position_error_m < 1e-6 and self.rotation_error_rad < 1e-5


def _side(side: str) -> int:
    if side not in LEG_ORDER:
        raise ValueError(f"side must be one of {LEG_ORDER}, got {side!r}")
    return LEG_ORDER.index(side)


def base_data(robot: RobotModel, qpos: np.ndarray | None = None) -> mujoco.MjData:
    """MjData at `qpos` (default qpos0) with the floating base at the origin, unrotated: the
    world frame is then the base frame."""
    data = zero_pose_data(robot.model, robot.root_body)
    if qpos is not None:
        adr = int(robot.model.jnt_qposadr[robot.model.body_jntadr[robot.root_body]])
        data.qpos[:] = qpos
        data.qpos[adr:adr + 7] = (0, 0, 0, 1, 0, 0, 0)
    mujoco.mj_kinematics(robot.model, data)
    return data


def foot_pose(robot: RobotModel, data: mujoco.MjData, side: str) -> tuple[np.ndarray, np.ndarray]:
    """(ankle centre (3,), foot rotation (3, 3)) of a leg in `data`'s world frame."""
    i = _side(side)
    return (data.site_xpos[robot.ankle_sites[i]].copy(),
            data.xmat[robot.foot_bodies[i]].reshape(3, 3).copy())


def _rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """The rotation vector (world frame) turning `current` into `target`."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (target @ current.T).reshape(-1))
    vel = np.zeros(3)
    mujoco.mju_quat2Vel(vel, quat, 1.0)
    return vel


def set_leg(robot: RobotModel, data: mujoco.MjData, side: str, q: np.ndarray) -> None:
    data.qpos[robot.leg_qpos[_side(side)]] = q
    mujoco.mj_kinematics(robot.model, data)


def leg_jacobian(robot: RobotModel, data: mujoco.MjData, i: int, jacp: np.ndarray | None = None,
                 jacr: np.ndarray | None = None) -> np.ndarray:
    """(6, n): the ankle centre's velocity and the foot's angular velocity per leg joint rate
    of leg i (LEG_ORDER), in `data`'s world frame (after kinematics; jacp, jacr: 3 x nv
    scratch arrays, reused by a loop)."""
    model = robot.model
    jacp = np.zeros((3, model.nv)) if jacp is None else jacp
    jacr = np.zeros((3, model.nv)) if jacr is None else jacr
    mujoco.mj_comPos(model, data)
    mujoco.mj_jacSite(model, data, jacp, jacr, robot.ankle_sites[i])
    dofs = robot.leg_dofs[i]
    return np.concatenate([jacp[:, dofs], jacr[:, dofs]])


def solve_leg_ik(robot: RobotModel, side: str, target_pos: np.ndarray, target_rot: np.ndarray,
                 q_init: np.ndarray | None = None, data: mujoco.MjData | None = None,
                 max_iterations: int = 200, damping: float = 1e-4) -> LegIK:
    """The leg's joint angles (role order) putting its ankle centre at `target_pos` with the
    foot at `target_rot`, both in the base frame (`base_data`). Damped least squares from `q_init`
    (default: the leg's angles in `data`, or zero), clipped to the joint ranges."""
    model, i = robot.model, _side(side)
    data = data if data is not None else base_data(robot)
    qadr = robot.leg_qpos[i]
    q = np.array(q_init if q_init is not None else data.qpos[qadr], float)
    joints = robot.leg_joints[i]
    limited = model.jnt_limited[joints].astype(bool)
    lo = np.where(limited, model.jnt_range[joints, 0], -np.inf)
    hi = np.where(limited, model.jnt_range[joints, 1], np.inf)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    err_p = err_r = np.inf
    iterations = 0
    for iterations in range(1, max_iterations + 1):  # noqa: B007 (the count is returned)
        set_leg(robot, data, side, q)
        pos, rot = foot_pose(robot, data, side)
        e = np.concatenate([target_pos - pos, _rotation_error(target_rot, rot)])
        err_p, err_r = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
        if err_p < 1e-9 and err_r < 1e-8:
            break
        jac = leg_jacobian(robot, data, i, jacp, jacr)
        step = jac.T @ np.linalg.solve(jac @ jac.T + damping ** 2 * np.eye(6), e)   # 6 x 6
        q = np.clip(q + step, lo, hi)
    return LegIK(q_rad=q, position_error_m=err_p, rotation_error_rad=err_r, iterations=iterations)


def analytic_ik_applies(robot: RobotModel, tol: float = 1e-6) -> tuple[bool, str]:
    """Whether the closed-form IK of tkujax.control.ik/solve.py holds for `robot`, and why not:
    joint axes exactly along z, x, y, y, y, x of the base with TKU-X's signs; hip axes meeting
    at a hip centre level with the base origin and straight above the ankle centre at the zero
    pose, where the two ankle axes meet."""
    if not robot.tkux_chain:
        orders = {side: list(order) for side, order in zip(LEG_ORDER, robot.chain_order)}
        return False, f"the legs' chains from the base are {orders}, not TKU-X's six joints"
    model, data = robot.model, zero_pose_data(robot.model, robot.root_body)
    hips, ankles = hip_and_ankle_centres(robot, data)
    for i, side in enumerate(LEG_ORDER):
        row = robot.leg_joints[i]
        for k, j in enumerate(row):
            axis = data.xaxis[j]
            name = model.joint(int(j)).name
            if np.linalg.norm(axis - ROLE_AXES[k]) > tol:
                how = "reversed" if np.linalg.norm(axis + ROLE_AXES[k]) < tol else "tilted"
                return False, (f"legs.{side}.{LEG_ROLE_NAMES[k]}: joint {name!r} axis "
                               f"{np.round(axis, 4).tolist()} is {how} against "
                               f"{ROLE_AXES[k].tolist()}")
        for k, j in enumerate(row):
            centre = hips[i] if k < 3 else ankles[i] if k > 3 else None
            if centre is None:
                continue
            gap = np.cross(centre - data.xanchor[j], data.xaxis[j])
            if np.linalg.norm(gap) > tol:
                return False, (f"legs.{side}: joint {model.joint(int(j)).name!r} misses the "
                               f"{'hip' if k < 3 else 'ankle'} centre by "
                               f"{1e3 * np.linalg.norm(gap):.3f} mm")
        if abs(hips[i][0]) > tol or abs(hips[i][2]) > tol:
            return False, f"legs.{side}: the hip centre is not level with the base origin"
        if np.linalg.norm(hips[i][:2] - ankles[i][:2]) > tol:
            return False, f"legs.{side}: the ankle centre is not below the hip at the zero pose"
    return True, "TKU-X's chain: the closed form of tkujax.control.ik applies"
