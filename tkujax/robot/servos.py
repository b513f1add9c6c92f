"""Servos from the robot file: `[servo]` makes each leg joint a PD position servo, replacing
whatever actuates it (a `<position>` for another pipeline, a `<motor>`, a `<general>`), and
`[servo.other]` does the same for the model's other actuated joints (arms, waist, head), which
then hold the stand pose.

    [servo]
    kp = 40.0            # N m/rad: one number, or one per role { hip_yaw = 40, knee = 60, ... }
    kv = 2.0             # N m s/rad: likewise
    force_limit = 30.0   # optional, N m; default: the joint's actuatorfrcrange, else the
                         # replaced motor's ctrlrange x gear, else none
    [servo.other]
    kp = 20.0
    kv = 1.0

The servo is MuJoCo's position actuator: force = kp (target - q) - kv qdot, clipped to the force
limit, its target limited to the joint's range (`configure_servo`). Applied through MjSpec at
load time; the model file is never written.
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from tkujax.robot.file_checks import RobotFileError, check_keys, number

SERVO_KEYS = ("kp", "kv", "force_limit", "other")
OTHER_KEYS = ("kp", "kv", "force_limit")
KP_RANGE = (0.0, 1e5)          # N m/rad, lower end open
KV_RANGE = (0.0, 1e4)          # N m s/rad
FORCE_RANGE = (0.0, 1e5)       # N m, lower end open


@dataclasses.dataclass(frozen=True)
class ServoGains:
    """Gains per role (roles in order; one role "*" for a single value), force limit or None."""

    roles: tuple[str, ...]
    kp: tuple[float, ...]
    kv: tuple[float, ...]
    force_limit: tuple[float | None, ...]

    def of(self, role: str) -> tuple[float, float, float | None]:
        """(kp, kv, force limit) of `role`."""
        i = self.roles.index(role) if role in self.roles else 0
        return self.kp[i], self.kv[i], self.force_limit[i]


@dataclasses.dataclass(frozen=True)
class ServoTable:
    """A parsed [servo]: the legs' gains, and the other joints' (None: left as the model has
    them)."""

    legs: ServoGains
    other: ServoGains | None = None


def _per_role(data: dict, key: str, roles: tuple[str, ...], table: str, rng, unit: str,
              lo_open: bool, default):
    """One value per role from a number or a { role = number } table covering every role."""
    value = data.get(key, default)
    where = f"{table}.{key}"
    if isinstance(value, dict):
        check_keys(value, roles, roles, where)
        return tuple(number(f"{where}.{r}", value[r], *rng, unit, lo_open) for r in roles)
    if value is None:
        return (None,) * len(roles)
    return (number(where, value, *rng, unit, lo_open),) * len(roles)


def _gains(data, roles: tuple[str, ...], table: str, allowed) -> ServoGains:
    if not isinstance(data, dict):
        raise RobotFileError(f"{table}: expected a table with kp and kv, got {data!r}")
    check_keys(data, allowed, ("kp", "kv"), table)
    return ServoGains(
        roles=roles,
        kp=_per_role(data, "kp", roles, table, KP_RANGE, "N m/rad", True, None),
        kv=_per_role(data, "kv", roles, table, KV_RANGE, "N m s/rad", False, None),
        force_limit=_per_role(data, "force_limit", roles, table, FORCE_RANGE, "N m", True, None))


def parse_servo_table(data, roles: tuple[str, ...]) -> ServoTable:
    """A ServoTable from the robot file's [servo] table; `roles`: the legs' roles."""
    legs = _gains(data, roles, "servo", SERVO_KEYS)
    other = None
    if "other" in data:
        other = _gains(data["other"], ("*",), "servo.other", OTHER_KEYS)
    return ServoTable(legs=legs, other=other)


def _joint_actuators(spec: mujoco.MjSpec, joint: str) -> list:
    return [a for a in spec.actuators
            if a.trntype == mujoco.mjtTrn.mjTRN_JOINT and a.target == joint]


def default_force_limit(model: mujoco.MjModel, joint: int, actuator: int | None) -> float | None:
    """The joint's actuatorfrcrange, else the (motor) actuator's ctrlrange x gear, else None."""
    if model.jnt_actfrclimited[joint]:
        return float(np.abs(model.jnt_actfrcrange[joint]).max())
    if actuator is not None and model.actuator_ctrllimited[actuator] \
            and model.actuator_gaintype[actuator] == mujoco.mjtGain.mjGAIN_FIXED \
            and model.actuator_biastype[actuator] == mujoco.mjtBias.mjBIAS_NONE:
        gain = abs(model.actuator_gainprm[actuator, 0] * model.actuator_gear[actuator, 0])
        return float(np.abs(model.actuator_ctrlrange[actuator]).max() * gain)
    return None


def configure_servo(act, kp: float, kv: float, force_limit: float | None,
                    joint_range: tuple[float, float] | None) -> None:
    """Make an MjSpec actuator a position servo: kp (target - q) - kv qdot, gear 1, its target
    within the joint's range (None: +-pi), its force within +-force_limit (None: unlimited)."""
    act.dyntype = mujoco.mjtDyn.mjDYN_NONE
    act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
    act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
    gain, bias = np.zeros(len(act.gainprm)), np.zeros(len(act.biasprm))
    gain[0], bias[1], bias[2] = kp, -kp, -kv
    act.gainprm, act.biasprm = gain, bias
    act.gear = np.array([1.0, 0, 0, 0, 0, 0])
    act.inheritrange = 0.0
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.ctrlrange = np.array(joint_range if joint_range is not None else (-math.pi, math.pi))
    limited = force_limit is not None
    act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE if limited else \
        mujoco.mjtLimited.mjLIMITED_FALSE
    act.forcerange = np.array([-force_limit, force_limit]) if limited else np.zeros(2)


def apply_servo(spec: mujoco.MjSpec, model: mujoco.MjModel, joint: int,
                gains: tuple[float, float, float | None]) -> None:
    """Joint `joint` (an id of the compiled `model` of `spec`) driven by one position servo:
    its first actuator reconfigured (any others removed), or a new one."""
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, joint)
    acts = _joint_actuators(spec, name)
    first_id = None
    if acts:
        first_id = int(acts[0].id)        # the compiled model's actuator of the same spec
        for extra in acts[1:]:
            spec.delete(extra)
        act = acts[0]
    else:
        act = spec.add_actuator(name=f"tkujax_servo_{name}", target=name,
                                trntype=mujoco.mjtTrn.mjTRN_JOINT)
    kp, kv, limit = gains
    if limit is None:
        limit = default_force_limit(model, joint, first_id)
    rng = (tuple(float(x) for x in model.jnt_range[joint]) if model.jnt_limited[joint]
           else None)
    configure_servo(act, kp, kv, limit, rng)


def is_position_servo(model: mujoco.MjModel, a: int) -> bool:
    """Whether actuator `a` is a position servo on a joint: fixed gain kp > 0, bias (0, -kp,
    any), gear 1."""
    kp, bias = model.actuator_gainprm[a, 0], model.actuator_biasprm[a, :3]
    return bool(model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT
                and model.actuator_gaintype[a] == mujoco.mjtGain.mjGAIN_FIXED
                and model.actuator_biastype[a] == mujoco.mjtBias.mjBIAS_AFFINE
                and kp > 0 and bias[0] == 0 and np.isclose(bias[1], -kp)
                and model.actuator_gear[a, 0] == 1.0)
