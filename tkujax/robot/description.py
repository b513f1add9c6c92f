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
    [collision]                   # optional: mode = "primitives" (default) or "model"
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from pathlib import Path

from tkujax.robot.collision import COLLISION_MODES, DEFAULT_COLLISION_MODE
from tkujax.studies.validation import SpecError, read_toml

LEG_ROLES = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")
SIDES = ("left", "right")
TOP_KEYS = ("mjcf", "imu", "legs", "stand", "name", "collision")
REQUIRED_TOP = ("mjcf", "imu", "legs")
STAND_KEYS = ("keyframe", "joints", "hip_height_frac")
COLLISION_KEYS = ("mode",)
HIP_HEIGHT_FRAC = 0.93        # computed stand: hip-to-ankle = this x (thigh + calf)
_VAR = re.compile(r"\$\{([A-Za-z_][A-Za-z0-9_]*)(?::-([^}]*))?\}")


class RobotFileError(SpecError):
    """A problem with a robot file or its model; the message names the key."""


@dataclasses.dataclass(frozen=True)
class LegDescription:
    """One leg: a joint name per role (LEG_ROLES order) and the foot's body."""

    joints: tuple[str, ...]
    foot: str

    def joint(self, role: str) -> str:
        return self.joints[LEG_ROLES.index(role)]


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
    if not path.is_file():
        raise RobotFileError(f"robot file not found: {path}")
    try:
        data = read_toml(path)
    except SpecError as err:
        raise RobotFileError(str(err)) from err
    return parse_description(data, path.parent.resolve(), str(path))


def _string(data: dict, key: str, where: str) -> str:
    value = data.get(key)
    if not isinstance(value, str) or not value:
        raise RobotFileError(f"{where}{key}: expected a non-empty string, got {value!r}")
    return value


def _check_keys(data: dict, allowed, required, where: str) -> None:
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        raise RobotFileError(f"{where or 'top level'}: unknown key(s) {unknown}; allowed: "
                             f"{list(allowed)}")
    missing = [k for k in required if k not in data]
    if missing:
        raise RobotFileError(f"{where or 'top level'}: missing required key(s) "
                             f"{[f'{where}{k}' for k in missing]}")


def _leg(data, side: str) -> LegDescription:
    where = f"legs.{side}."
    if not isinstance(data, dict):
        raise RobotFileError(f"legs.{side}: expected a table of joint names, got {data!r}")
    _check_keys(data, LEG_ROLES + ("foot",), LEG_ROLES + ("foot",), where)
    joints = tuple(_string(data, role, where) for role in LEG_ROLES)
    for i, name in enumerate(joints):
        if name in joints[:i]:
            first = LEG_ROLES[joints.index(name)]
            raise RobotFileError(f"{where}{LEG_ROLES[i]}: joint {name!r} is already given as "
                                 f"{where}{first} (a role given twice)")
    return LegDescription(joints=joints, foot=_string(data, "foot", where))


def _stand(data) -> StandDescription:
    if data is None:
        return StandDescription()
    if not isinstance(data, dict):
        raise RobotFileError(f"stand: expected a table, got {data!r}")
    _check_keys(data, STAND_KEYS, (), "stand.")
    if "keyframe" in data and "joints" in data:
        raise RobotFileError("stand: give stand.keyframe or stand.joints, not both")
    keyframe = _string(data, "keyframe", "stand.") if "keyframe" in data else None
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


def _collision_mode(data) -> str:
    if data is None:
        return DEFAULT_COLLISION_MODE
    if not isinstance(data, dict):
        raise RobotFileError(f"collision: expected a table, got {data!r}")
    _check_keys(data, COLLISION_KEYS, (), "collision.")
    mode = data.get("mode", DEFAULT_COLLISION_MODE)
    if mode not in COLLISION_MODES:
        raise RobotFileError(f"collision.mode: expected one of {list(COLLISION_MODES)}, got "
                             f"{mode!r}")
    return mode


def parse_description(data: dict, base: Path, source: str = "<robot file>") -> RobotDescription:
    """A RobotDescription from the TOML's dict; relative paths are relative to `base`."""
    _check_keys(data, TOP_KEYS, REQUIRED_TOP, "")
    mjcf = expand_path(_string(data, "mjcf", ""), base)
    if not mjcf.is_file():
        raise RobotFileError(f"mjcf: model file not found: {mjcf} (relative to {base})")
    legs = data["legs"]
    if not isinstance(legs, dict):
        raise RobotFileError(f"legs: expected [legs.left] and [legs.right] tables, got {legs!r}")
    _check_keys(legs, SIDES, SIDES, "legs.")
    left, right = _leg(legs["left"], "left"), _leg(legs["right"], "right")
    shared = sorted(set(left.joints) & set(right.joints))
    if shared:
        raise RobotFileError(f"legs.right: joint(s) {shared} also given in legs.left "
                             "(a role given twice)")
    name = data.get("name", mjcf.stem)
    if not isinstance(name, str):
        raise RobotFileError(f"name: expected a string, got {name!r}")
    return RobotDescription(name=name, mjcf_path=mjcf, imu=_string(data, "imu", ""),
                            left=left, right=right, stand=_stand(data.get("stand")),
                            source=source, collision_mode=_collision_mode(data.get("collision")))
