"""The robot file: a TOML naming a MuJoCo model's legs, IMU and stand (see docs/robots.md).

`load_description(path)` reads and checks the file's own structure (required and unknown keys,
roles given twice, the MJCF's existence); the names are checked against the compiled model by
`tkujax.robot.loader.load_robot`. Every problem is a `RobotFileError` (a `SpecError`, so a
`ValueError`) whose message names the key.

    mjcf = "op3/scene.xml"        # relative to this file; ${VAR:-default} is expanded
    imu = "body_link"             # the body (or site) carrying the gyro and accelerometer
    [legs.left]                   # one joint name per role, and the foot's body
    hip_yaw = "l_hip_yaw" ...  foot = "l_ank_roll_link"
    [legs.right]
    [stand]                       # optional: keyframe = "home", or joints = {name = rad, ...},
                                  # or hip_height_frac = 0.93 for the computed stand
    [collision]                   # optional: mode = "primitives" (default) or "model";
                                  # floor = "all" (default) or "feet" (tkujax.robot.collision)
    controller = "robot.json"     # optional: the robot's tuned controller, relative to this file
    walk_controller = "walk.json" # optional: the controller while walking (default: controller)
    [servo]                       # optional: PD servos on the leg joints (tkujax.robot.servos)
    [solver]                      # optional: iterations = 1, ls_iterations = 4 (the constraint
                                  # solver's caps; default: the model's own)
    [walk]                        # optional: the robot's gait (tkujax walk, [walk] sweeps):
                                  # lift_m, sway_m, step_period_s, double_support_ratio,
                                  # recovery_forward_gain, recovery_late_swing_gain,
                                  # recovery_hurry, com_shift_m

Each leg names hip_yaw, hip_roll, hip_pitch (in whatever order the chain has them), knee,
ankle_pitch and, optionally, ankle_roll (a five-joint leg has none).
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path

from tkujax.control.gait import WALK_LIMITS
from tkujax.model.files import SpecError, read_toml
from tkujax.robot.collision import (COLLISION_MODES, DEFAULT_COLLISION_MODE,
                                   DEFAULT_FLOOR_CONTACTS, FLOOR_CONTACTS)
from tkujax.robot.file_checks import RobotFileError, check_keys, string
from tkujax.robot.servos import ServoTable, parse_servo_table

LEG_ROLES = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")
OPTIONAL_ROLES = ("ankle_roll",)     # a five-joint leg (hip x 3, knee, ankle pitch) has none
HIP_ROLES = LEG_ROLES[:3]
ANKLE_ROLES = LEG_ROLES[4:]
SIDES = ("left", "right")
TOP_KEYS = ("mjcf", "imu", "legs", "stand", "name", "collision", "controller",
            "walk_controller", "servo", "solver", "walk")
REQUIRED_TOP = ("mjcf", "imu", "legs")
STAND_KEYS = ("keyframe", "joints", "hip_height_frac")
COLLISION_KEYS = ("mode", "floor")
# [solver]: each key's allowed range; MuJoCo's defaults are 100 and 50 (the caps MJX's batched
# solver runs to: tests/test_robot_solver.py)
SOLVER_RANGES = {"iterations": (1, 1000), "ls_iterations": (1, 1000)}
# [walk]: the gait's keys (tkujax.control.gait.WalkCommand fields), each with its allowed
# range, WalkCommand.validate's, and unit
WALK_RANGES = {k: (*WALK_LIMITS[k], unit) for k, unit in (
    ("lift_m", "m"), ("sway_m", "m"), ("step_period_s", "s"), ("double_support_ratio", ""),
    ("recovery_forward_gain", ""), ("recovery_late_swing_gain", ""), ("recovery_hurry", ""),
    ("com_shift_m", "m"))}
HIP_HEIGHT_FRAC = 0.93        # computed stand: hip-to-ankle = this x (thigh + calf)
_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


@dataclasses.dataclass(frozen=True)
class LegDescription:
    """One leg: a joint name per role it has (`roles`, in LEG_ROLES order) and the foot's body."""

    joints: tuple[str, ...]
    foot: str
    roles: tuple[str, ...] = LEG_ROLES

    def joint(self, role: str) -> str:
        return self.joints[self.roles.index(role)]


@dataclasses.dataclass(frozen=True)
class StandDescription:
    """How the stand is made: a keyframe, explicit joint angles (rad), or computed."""

    keyframe: str | None = None
    joints: tuple[tuple[str, float], ...] = ()
    hip_height_frac: float = HIP_HEIGHT_FRAC


@dataclasses.dataclass(frozen=True)
class RobotDescription:
    """A parsed robot file. `mjcf_path` is absolute; `source` is the file (for messages)."""

    name: str
    mjcf_path: Path
    imu: str
    left: LegDescription
    right: LegDescription
    stand: StandDescription
    source: str
    collision_mode: str = DEFAULT_COLLISION_MODE   # tkujax.robot.collision.COLLISION_MODES
    floor_contacts: str = DEFAULT_FLOOR_CONTACTS   # tkujax.robot.collision.FLOOR_CONTACTS
    controller_path: Path | None = None            # the robot's tuned controller (absolute)
    walk_controller_path: Path | None = None       # its controller while walking (absolute)
    servo: ServoTable | None = None                # [servo]: PD servos replacing the legs'
    solver_iterations: int | None = None           # [solver] iterations (None: the model's)
    ls_iterations: int | None = None               # [solver] ls_iterations (None: the model's)
    walk: tuple[tuple[str, float], ...] = ()       # [walk]: (WalkCommand field, value) pairs

    @property
    def roles(self) -> tuple[str, ...]:
        """The leg roles both legs have, in LEG_ROLES order."""
        return self.left.roles

    def leg(self, side: str) -> LegDescription:
        return self.left if side == "left" else self.right


def expand_path(text: str, base: Path) -> Path:
    """`text` with ${VAR} / ${VAR:-default} expanded from the environment, relative to `base`."""
    def repl(m: re.Match) -> str:
        value = os.environ.get(m.group(1))
        if value:
            return value
        if m.group(2) is None:
            raise RobotFileError(f"mjcf: environment variable {m.group(1)} is not set "
                                 f"(write ${{{m.group(1)}:-default}} to give a default)")
        return m.group(2)
    path = Path(os.path.expanduser(_VAR.sub(repl, text)))
    return path if path.is_absolute() else (base / path).resolve()


def load_description(path: str | Path) -> RobotDescription:
    """Read and check a robot file (its structure; names are checked by `load_robot`)."""
    path = Path(path)
    try:
        data = read_toml(path, "robot file")
    except SpecError as err:
        raise RobotFileError(str(err)) from err
    return parse_description(data, path.parent.resolve(), str(path))


def _leg(data, side: str) -> LegDescription:
    where = f"legs.{side}."
    if not isinstance(data, dict):
        raise RobotFileError(f"legs.{side}: expected a table of joint names, got {data!r}")
    required = tuple(r for r in LEG_ROLES if r not in OPTIONAL_ROLES) + ("foot",)
    check_keys(data, LEG_ROLES + ("foot",), required, f"legs.{side}")
    roles = tuple(r for r in LEG_ROLES if r in data)
    joints = tuple(string(data, role, f"legs.{side}") for role in roles)
    for i, name in enumerate(joints):
        if name in joints[:i]:
            first = roles[joints.index(name)]
            raise RobotFileError(f"{where}{roles[i]}: joint {name!r} is already given as "
                                 f"{where}{first} (a role given twice)")
    return LegDescription(joints=joints, foot=string(data, "foot", f"legs.{side}"), roles=roles)


def _stand(data) -> StandDescription:
    if data is None:
        return StandDescription()
    if not isinstance(data, dict):
        raise RobotFileError(f"stand: expected a table, got {data!r}")
    check_keys(data, STAND_KEYS, (), "stand")
    if "keyframe" in data and "joints" in data:
        raise RobotFileError("stand: give stand.keyframe or stand.joints, not both")
    keyframe = string(data, "keyframe", "stand") if "keyframe" in data else None
    joints = data.get("joints", {})
    if not isinstance(joints, dict):
        raise RobotFileError(f"stand.joints: expected a table of joint angles (rad), got "
                             f"{joints!r}")
    for name, angle in joints.items():
        if isinstance(angle, bool) or not isinstance(angle, (int, float)) \
                or not math.isfinite(angle) or abs(angle) > 2 * math.pi:
            raise RobotFileError(f"stand.joints.{name}: expected an angle in [-2 pi, 2 pi] rad, "
                                 f"got {angle!r}")
    frac = data.get("hip_height_frac", HIP_HEIGHT_FRAC)
    if isinstance(frac, bool) or not isinstance(frac, (int, float)) or not 0.7 <= frac <= 0.99:
        raise RobotFileError(f"stand.hip_height_frac: expected a number in [0.7, 0.99], got "
                             f"{frac!r}")
    return StandDescription(keyframe=keyframe,
                            joints=tuple((k, float(v)) for k, v in joints.items()),
                            hip_height_frac=float(frac))


def _collision(data) -> tuple[str, str]:
    """([collision] mode, floor), each checked against its allowed values."""
    if data is None:
        return DEFAULT_COLLISION_MODE, DEFAULT_FLOOR_CONTACTS
    if not isinstance(data, dict):
        raise RobotFileError(f"collision: expected a table, got {data!r}")
    check_keys(data, COLLISION_KEYS, (), "collision")
    out = []
    for key, allowed, default in (("mode", COLLISION_MODES, DEFAULT_COLLISION_MODE),
                                  ("floor", FLOOR_CONTACTS, DEFAULT_FLOOR_CONTACTS)):
        value = data.get(key, default)
        if value not in allowed:
            raise RobotFileError(f"collision.{key}: expected one of {list(allowed)}, got "
                                 f"{value!r}")
        out.append(value)
    return out[0], out[1]


def _solver(data) -> dict:
    """[solver]'s keys as RobotDescription fields, each an integer in its SOLVER_RANGES."""
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise RobotFileError(f"solver: expected a table, got {data!r}")
    check_keys(data, tuple(SOLVER_RANGES), (), "solver")
    out = {}
    for key, value in data.items():
        lo, hi = SOLVER_RANGES[key]
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise RobotFileError(f"solver.{key}: expected an integer in [{lo}, {hi}], got "
                                 f"{value!r}")
        out["solver_iterations" if key == "iterations" else key] = value
    return out


def _walk(data) -> tuple[tuple[str, float], ...]:
    """[walk]'s keys as (WalkCommand field, value) pairs, each a number in its WALK_RANGES."""
    if data is None:
        return ()
    if not isinstance(data, dict):
        raise RobotFileError(f"walk: expected a table, got {data!r}")
    check_keys(data, tuple(WALK_RANGES), (), "walk")
    out = []
    for key, value in data.items():
        lo, hi, unit = WALK_RANGES[key]
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not ok or not lo <= value <= hi:      # also refuses NaN
            raise RobotFileError(f"walk.{key}: expected a number in [{lo:g}, {hi:g}]"
                                 f"{' ' + unit if unit else ''}, got {value!r}")
        out.append((key, float(value)))
    return tuple(out)


def parse_description(data: dict, base: Path, source: str = "<robot file>") -> RobotDescription:
    """A RobotDescription from the TOML's dict; relative paths are relative to `base`."""
    check_keys(data, TOP_KEYS, REQUIRED_TOP, "")
    mjcf = expand_path(string(data, "mjcf", ""), base)
    if not mjcf.is_file():
        raise RobotFileError(f"mjcf: model file not found: {mjcf} (relative to {base})")
    legs = data["legs"]
    if not isinstance(legs, dict):
        raise RobotFileError(f"legs: expected [legs.left] and [legs.right] tables, got {legs!r}")
    check_keys(legs, SIDES, SIDES, "legs")
    left, right = _leg(legs["left"], "left"), _leg(legs["right"], "right")
    if left.roles != right.roles:
        raise RobotFileError(f"legs.right: roles {list(right.roles)} differ from legs.left's "
                             f"{list(left.roles)} (both legs need the same joints)")
    shared = sorted(set(left.joints) & set(right.joints))
    if shared:
        raise RobotFileError(f"legs.right: joint(s) {shared} also given in legs.left "
                             "(a role given twice)")
    name = data.get("name", mjcf.stem)
    if not isinstance(name, str):
        raise RobotFileError(f"name: expected a string, got {name!r}")
    servo = parse_servo_table(data["servo"], roles=left.roles) if "servo" in data else None
    mode, floor = _collision(data.get("collision"))
    return RobotDescription(name=name, mjcf_path=mjcf, imu=string(data, "imu", ""),
                            left=left, right=right, stand=_stand(data.get("stand")),
                            source=source, collision_mode=mode, floor_contacts=floor,
                            controller_path=_controller_path(data, base),
                            walk_controller_path=_controller_path(data, base, "walk_controller"),
                            servo=servo, walk=_walk(data.get("walk")),
                            **_solver(data.get("solver")))


def _controller_path(data: dict, base: Path, key: str = "controller") -> Path | None:
    if key not in data:
        return None
    path = expand_path(string(data, key, ""), base)
    if not path.is_file():
        raise RobotFileError(f"{key}: file not found: {path} (relative to {base})")
    return path
