"""Why a robot's servos cannot hold its stand: the torque the stand needs at each leg joint
against what the servos give.

`stand_torques(robot, pose)` holds the stand with stiff, unlimited servos (MuJoCo C, a copy of
the model) and reads the torque each leg joint's servo supplies once it has settled: what the
stand needs. `servo_shortfalls` sets that against the robot's own servos: kp x
`HOLD_ERROR_RAD`, and the force limit; the message also says how far the joint sagged under
them. A joint falls short
when its servo gives less than the stand needs; the message says which way to go, e.g. "knee:
the stand needs 0.6 N m; kp 1 gives 0.05 N m at 0.05 rad of error (the joint sagged 0.61 rad);
raise [servo] kp to at least 12". A robot on position servos is
also an inverted pendulum on its ankles: it creeps and falls when the two ankle-pitch servos
together are softer than gravity's toppling stiffness m g h (h: the CoM above the ankles), the
way Menagerie's Booster T1 (kp 75) falls from its own keyframe (`toppling_check`).
"""

from __future__ import annotations

import copy
import dataclasses
import math

import mujoco
import numpy as np

from tkujax.robot.loader import LEG_ORDER, RobotModel

STIFF_KP_PER_MGL = 5.0       # the stiff servo's kp, m g l per rad: stiffer oscillates on T1
STIFF_DAMPING_S = 0.02       # its kv / kp
SETTLE_S = 0.5               # held this long; the torque is the mean of the last AVERAGE_S
AVERAGE_S = 0.1
HOLD_ERROR_RAD = 0.05        # a servo should hold the stand within this error (2.9 deg)
TOPPLE_MARGIN = 1.5          # the ankles' kp should exceed the toppling stiffness by this


@dataclasses.dataclass(frozen=True)
class JointTorque:
    """One leg joint: what the stand needs against what its servo gives."""

    key: str                  # e.g. "legs.left.knee"
    needed_nm: float          # |torque| the stiff stand needs
    kp_nm_per_rad: float
    force_limit_nm: float | None
    error_rad: float          # the largest error the robot's own servo reached
    short: bool
    message: str


def _stiff_copy(robot: RobotModel, mgl: float) -> mujoco.MjModel:
    model = copy.deepcopy(robot.model)
    # The stiff servos' damping integrated implicitly: with the semi-implicit Euler step, a
    # joint without armature diverges under them (OP3 with its armature removed read 15.8 kN m
    # at a hip that needs none; tests/test_robot_chains.py), and the needs were noise.
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    kp = STIFF_KP_PER_MGL * mgl
    for a in robot.leg_actuators.reshape(-1):
        model.actuator_gainprm[a, 0] = kp
        model.actuator_biasprm[a, 1:3] = (-kp, -STIFF_DAMPING_S * kp)
        model.actuator_forcelimited[a] = 0
    return model


def stand_torques(robot: RobotModel, qpos: np.ndarray, ctrl: np.ndarray) -> np.ndarray:
    """(2, n) |torque| (N m) each leg joint needs to hold the stand at `qpos` / `ctrl`."""
    mass = float(robot.model.body_subtreemass[robot.root_body])
    g = float(-robot.model.opt.gravity[2])
    height = float(qpos[int(robot.model.jnt_qposadr[robot.model.body_jntadr[robot.root_body]])
                        + 2])
    model = _stiff_copy(robot, mass * g * max(height, 0.05))
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    data.ctrl[:] = ctrl
    mujoco.mj_forward(model, data)
    steps = int(round(SETTLE_S / model.opt.timestep))
    tail = max(1, int(round(AVERAGE_S / model.opt.timestep)))
    total = np.zeros(robot.leg_actuators.shape)
    for k in range(steps):
        mujoco.mj_step(model, data)
        if k >= steps - tail:
            total += data.actuator_force[robot.leg_actuators]
    return np.abs(total / tail)


def held_errors(robot: RobotModel, qpos: np.ndarray, ctrl: np.ndarray,
                seconds: float) -> np.ndarray:
    """(2, n) the largest |target - angle| (rad) of each leg joint under the robot's own servos,
    until `seconds` or until the base falls below half its height."""
    model = robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    data.ctrl[:] = ctrl
    mujoco.mj_forward(model, data)
    adr = int(model.jnt_qposadr[model.body_jntadr[robot.root_body]]) + 2
    z0 = float(data.qpos[adr])
    targets = ctrl[robot.leg_actuators]
    worst = np.zeros(robot.leg_actuators.shape)
    for _ in range(int(round(seconds / model.opt.timestep))):
        mujoco.mj_step(model, data)
        worst = np.maximum(worst, np.abs(targets - data.qpos[robot.leg_qpos]))
        if data.qpos[adr] < 0.5 * z0:
            break
    return worst


def _joint_message(key: str, need: float, kp: float, limit: float | None,
                   err: float) -> tuple[bool, str]:
    """(short, message): the servo falls short when kp x HOLD_ERROR_RAD is below the need (a
    servo that needs a larger error has let the stand sag by then) or the force limit is."""
    gives = kp * HOLD_ERROR_RAD
    if limit is not None and need > limit:
        return True, (f"{key}: the stand needs {need:.1f} N m; the force limit is "
                      f"{limit:.1f} N m; raise [servo] force_limit or choose a stand nearer "
                      "the straight leg")
    if gives < need:
        # Rounded up, and above kp: a need just over what kp gives asks for more than kp.
        least = max(math.ceil(need / HOLD_ERROR_RAD), math.floor(kp) + 1)
        return True, (f"{key}: the stand needs {need:.1f} N m; kp {kp:g} gives {gives:.2f} N m "
                      f"at {HOLD_ERROR_RAD:g} rad of error (the joint sagged {err:.2f} rad); "
                      f"raise [servo] kp to at least {least}")
    return False, f"{key}: the stand needs {need:.1f} N m; kp {kp:g} gives {gives:.2f} N m"


def servo_shortfalls(robot: RobotModel, qpos: np.ndarray, ctrl: np.ndarray,
                     seconds: float) -> list[JointTorque]:
    """Each leg joint's need against its servo (see the module doc), right leg first."""
    need = stand_torques(robot, qpos, ctrl)
    err = held_errors(robot, qpos, ctrl, seconds)
    model = robot.model
    out = []
    for i, side in enumerate(LEG_ORDER):
        for k, role in enumerate(robot.roles):
            a = int(robot.leg_actuators[i, k])
            limit = (float(np.abs(model.actuator_forcerange[a]).max())
                     if model.actuator_forcelimited[a] else None)
            kp = float(model.actuator_gainprm[a, 0])
            key = f"legs.{side}.{role}"
            short, msg = _joint_message(key, float(need[i, k]), kp, limit, float(err[i, k]))
            out.append(JointTorque(key, float(need[i, k]), kp, limit, float(err[i, k]), short,
                                   msg))
    return out


def toppling_check(robot: RobotModel, qpos: np.ndarray) -> JointTorque:
    """The two ankle-pitch servos' kp against m g h (h: the CoM's height above the ankles)."""
    model = robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    ankle_z = float(np.mean([data.site_xpos[s][2] for s in robot.ankle_sites]))
    mass = float(model.body_subtreemass[robot.root_body])
    stiffness = mass * float(-model.opt.gravity[2]) * (data.subtree_com[robot.root_body][2]
                                                         - ankle_z)
    col = robot.column("ankle_pitch")
    kps = [float(model.actuator_gainprm[int(a), 0]) for a in robot.leg_actuators[:, col]]
    short = sum(kps) < TOPPLE_MARGIN * stiffness
    msg = (f"ankle_pitch: the two ankles' kp {kps[0]:g} + {kps[1]:g} = {sum(kps):g} N m/rad "
           f"against the stand's toppling stiffness m g h = {stiffness:.0f} N m/rad")
    if short:
        msg += (f"; the robot creeps over its toes or heels: raise [servo] kp of ankle_pitch "
                f"to at least {TOPPLE_MARGIN * stiffness / 2:.0f}")
    return JointTorque("legs.ankle_pitch", stiffness, sum(kps), None, 0.0, short, msg)


def explain_failed_stand(robot: RobotModel, qpos: np.ndarray, ctrl: np.ndarray,
                         seconds: float) -> tuple[str, ...]:
    """The messages of the leg joints whose servos fall short of the stand, the toppling
    check's first; empty when the servos are not the reason."""
    checks = [toppling_check(robot, qpos), *servo_shortfalls(robot, qpos, ctrl, seconds)]
    return tuple(c.message for c in checks if c.short)
