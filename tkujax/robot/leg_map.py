"""The controller's leg targets as a robot's joint targets.

The controller (tkujax.control) writes TKU-X's leg: hip yaw, roll, pitch, knee, ankle pitch,
roll about z, x, y, y, y, x of the pelvis, zero = the straight leg, with the robot's measured
thigh and calf (`tkux_leg_jacobian`). A robot's leg may differ:

- **TKU-X's chain** (`RobotModel.tkux_chain`: six joints in that order, OP3 among them): each
  actuator takes sign x q + offset, the sign its axis against TKU-X's, the offset making the
  controller's stand the robot's (`sign_map`). Joint for joint, so it holds away from the stand
  as far as the robot's links are the controller's.
- **Any other chain** (hips pitch-roll-yaw as Booster T1's and Unitree G1's, a five-joint leg
  without ankle roll): the robot's own IK of the foot pose the controller's angles ask for
  (`leg_chain`, solved in the loop by tkujax.sim.leg_chain), started from a linear map about
  the stand, q_robot = q_stand + A (q - q_c), with
  A taking the controller leg's joint rates to the robot leg's that move the ankle centre and
  the foot alike: A = (W J_robot)^+ (W J_controller), J the 6 x n Jacobians of the ankle
  centre's velocity and the foot's angular velocity in the base frame at the stand, W weighting
  rotation by the leg's reach (m/rad) so a five-joint leg matches the ankle's position first
  (`jacobian_map`). The linear map alone is exact at the stand and first order around it:
  on T1 a 17.5 cm backward step with a 7 cm lift lands 7.8 mm off; the IK is exact
  (`tests/test_robot_chains.py` measures both round trips).
"""

from __future__ import annotations

import numpy as np

from tkujax.robot.ik_numeric import base_data, leg_jacobian
from tkujax.robot.loader import LEG_ORDER, RobotModel
from tkujax.sim.leg_chain import LegChain, tkux_fk

UNLIMITED_RAD = 1e3      # the range of a joint without limits (finite in float32)


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def tkux_leg_jacobian(q: np.ndarray, thigh_m: float, calf_m: float) -> np.ndarray:
    """(6, 6): d(ankle centre velocity, foot angular velocity) / d(joint rates) of TKU-X's leg
    at angles `q` (tkujax.control.ik's convention), in the pelvis frame."""
    r01 = _rz(q[0]) @ _rx(q[1])
    r2 = r01 @ _ry(q[2])
    knee = r2 @ np.array([0.0, 0.0, -thigh_m])
    ankle = knee + r2 @ _ry(q[3]) @ np.array([0.0, 0.0, -calf_m])
    y = r01[:, 1]
    axes = [np.array([0.0, 0.0, 1.0]), _rz(q[0])[:, 0], y, y, y,
            (r01 @ _ry(q[2] + q[3] + q[4]))[:, 0]]
    points = [np.zeros(3), np.zeros(3), np.zeros(3), knee, ankle, ankle]
    cols = [np.concatenate([np.cross(w, ankle - p), w]) for w, p in zip(axes, points)]
    return np.array(cols).T


def robot_leg_jacobian(robot: RobotModel, qpos: np.ndarray, side: str) -> np.ndarray:
    """(6, n): the same of the robot's leg at `qpos`, in its base frame (MuJoCo's Jacobians)."""
    return leg_jacobian(robot, base_data(robot, qpos), LEG_ORDER.index(side))


def sign_map(robot: RobotModel, stand_ctrl: np.ndarray,
             q_controller_stand: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(signs (12,), offsets (12,)) for TKU-X's chain (module doc)."""
    signs = robot.axis_signs.reshape(-1).astype(float)
    stand = stand_ctrl[robot.leg_actuators.reshape(-1)]
    return signs, stand - signs * q_controller_stand


def jacobian_map(robot: RobotModel, stand_qpos: np.ndarray, stand_ctrl: np.ndarray,
                 q_controller_stand: np.ndarray, thigh_m: float,
                 calf_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(matrix (2n, 12), offsets (2n,)): the robot's leg targets = matrix @ q + offsets, for
    any chain (module doc); rows right leg then left, roles in order."""
    n = len(robot.roles)
    weight = np.diag([1.0, 1.0, 1.0] + [thigh_m + calf_m] * 3)
    matrix = np.zeros((2 * n, 12))
    for i, side in enumerate(LEG_ORDER):
        qc = q_controller_stand[6 * i:6 * i + 6]
        j_c = weight @ tkux_leg_jacobian(qc, thigh_m, calf_m)
        j_r = weight @ robot_leg_jacobian(robot, stand_qpos, side)
        matrix[n * i:n * i + n, 6 * i:6 * i + 6] = np.linalg.lstsq(j_r, j_c, rcond=None)[0]
    stand = stand_ctrl[robot.leg_actuators.reshape(-1)]
    return matrix, stand - matrix @ q_controller_stand


def leg_chain(robot: RobotModel, stand_qpos: np.ndarray, stand_ctrl: np.ndarray,
              q_controller_stand: np.ndarray, thigh_m: float, calf_m: float) -> LegChain:
    """The LegChain of `robot` (module doc): its joint axes and anchors with the legs straight
    and everything above them (a waist) at the stand, its stand, the controller's stand, and
    the linear map as the IK's start."""
    import jax.numpy as jnp

    model = robot.model
    straight = stand_qpos.copy()
    straight[robot.leg_qpos.reshape(-1)] = 0.0
    zero, stand = base_data(robot, straight), base_data(robot, stand_qpos)
    sides = range(len(LEG_ORDER))
    ctrl = [tkux_fk(jnp.asarray(q_controller_stand[6 * i:6 * i + 6], jnp.float32),
                    thigh_m, calf_m) for i in sides]
    joints = robot.leg_joints
    limited = model.jnt_limited[joints].astype(bool)
    matrix, offsets = jacobian_map(robot, stand_qpos, stand_ctrl, q_controller_stand, thigh_m,
                                   calf_m)
    return LegChain(
        axes=zero.xaxis[joints].copy(), anchors=zero.xanchor[joints].copy(),
        chain=tuple(tuple(robot.roles.index(r) for r in order) for order in robot.chain_order),
        ankle0=np.array([zero.site_xpos[robot.ankle_sites[i]] for i in sides]),
        foot0=np.array([zero.xmat[robot.foot_bodies[i]].reshape(3, 3) for i in sides]),
        stand_q=stand_qpos[robot.leg_qpos].copy(),
        stand_p=np.array([stand.site_xpos[robot.ankle_sites[i]] for i in sides]),
        stand_r=np.array([stand.xmat[robot.foot_bodies[i]].reshape(3, 3) for i in sides]),
        ctrl_stand_p=np.array([np.asarray(c[0], np.float64) for c in ctrl]),
        ctrl_stand_r=np.array([np.asarray(c[1], np.float64) for c in ctrl]),
        thigh_m=float(thigh_m), calf_m=float(calf_m), weight_m=float(thigh_m + calf_m),
        matrix=matrix, offsets=offsets,
        lo=np.where(limited, model.jnt_range[joints, 0], -UNLIMITED_RAD),
        hi=np.where(limited, model.jnt_range[joints, 1], UNLIMITED_RAD))
