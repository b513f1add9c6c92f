"""Validation of spec values, shared by every spec dialect (sweep specs `dialects.sweep_spec`, tune
specs `studies.tune.tune_spec`, calibrate specs `studies.calibrate.calibrate_spec`, converge
specs `studies.converge`).

Each check takes the key as the user wrote it (e.g. "tune.batch", "push.impulse_ns[2]") and
the value, and returns the value in its canonical type, or raises SpecError with a message
that names the key, what is allowed (the range, with its unit) and the bad value.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np

from tkujax.model.files import SpecError, read_toml  # noqa: F401  (the dialects read with it)


def number(key: str, value, lo: float, hi: float, unit: str = "") -> float:
    """A finite number (not a boolean) in [lo, hi], as a float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SpecError(f"{key}: expected a number in [{lo}, {hi}] {unit}, got {value!r}")
    if not lo <= value <= hi:
        raise SpecError(f"{key}: {value!r} is out of range [{lo}, {hi}] {unit}".rstrip())
    return float(value)


def integer(key: str, value, lo: int, hi: int) -> int:
    """An integer (not a boolean) in [lo, hi]."""
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise SpecError(f"{key}: expected an integer in [{lo}, {hi}], got {value!r}")
    return value


def boolean(key: str, value) -> bool:
    """true or false."""
    if not isinstance(value, bool):
        raise SpecError(f"{key}: expected true or false, got {value!r}")
    return value


def string(key: str, value) -> str:
    """A string."""
    if not isinstance(value, str):
        raise SpecError(f"{key}: expected a string, got {value!r}")
    return value


def choice(key: str, value, choices: Iterable):
    """One of `choices`."""
    choices = list(choices)
    if value not in choices:
        raise SpecError(f"{key}: expected one of {choices}, got {value!r}")
    return value


def names(key: str, value, allowed: Iterable) -> tuple[str, ...]:
    """A non-empty list of distinct names from `allowed`, in `allowed`'s order."""
    allowed = list(allowed)
    if (not isinstance(value, list) or not value or len(set(value)) != len(value)
            or any(v not in allowed for v in value)):
        bad = [v for v in value if v not in allowed] if isinstance(value, list) else value
        raise SpecError(f"{key}: expected a non-empty list of distinct names from {allowed}, "
                        f"got {value!r} (not allowed: {bad!r})")
    return tuple(v for v in allowed if v in value)     # canonical order


def table(key: str, value, allowed: Iterable) -> dict:
    """A table whose keys are all in `allowed` (key: the table's name, e.g. "tune.loss")."""
    if not isinstance(value, dict):
        raise SpecError(f"[{key}]: expected a table, got {type(value).__name__}")
    unknown = sorted(set(value) - set(allowed))
    if unknown:
        raise SpecError(f"[{key}]: unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    return value


def values(key: str, value, lo: float, hi: float, unit: str = "") -> np.ndarray:
    """A list, a scalar, or a {start, stop, num, endpoint} range -> an array of numbers in
    [lo, hi]."""
    if isinstance(value, dict):
        unknown = set(value) - {"start", "stop", "num", "endpoint"}
        if unknown or not {"start", "stop", "num"} <= set(value):
            raise SpecError(f"{key}: a range needs start, stop, num (and optional endpoint); "
                            f"got keys {sorted(value)}")
        num = integer(f"{key}.num", value["num"], 1, 1_000_000)
        endpoint = boolean(f"{key}.endpoint", value.get("endpoint", True))
        start = number(f"{key}.start", value["start"], lo, hi, unit)
        stop = number(f"{key}.stop", value["stop"], lo, hi, unit)
        return np.linspace(start, stop, num, endpoint=endpoint)
    items = value if isinstance(value, list) else [value]
    if not items:
        raise SpecError(f"{key}: empty list")
    return np.array([number(f"{key}[{i}]", v, lo, hi, unit) for i, v in enumerate(items)])


def uniform(key: str, value, lo: float, hi: float, unit: str = "") -> tuple[float, float]:
    """{uniform = [a, b]} with lo <= a <= b <= hi -> (a, b)."""
    if not (isinstance(value, dict) and set(value) == {"uniform"}
            and isinstance(value["uniform"], list) and len(value["uniform"]) == 2):
        raise SpecError(f"{key}: expected {{uniform = [lo, hi]}} within [{lo}, {hi}] {unit}, "
                        f"got {value!r}")
    a = number(f"{key}.uniform[0]", value["uniform"][0], lo, hi, unit)
    b = number(f"{key}.uniform[1]", value["uniform"][1], lo, hi, unit)
    if a > b:
        raise SpecError(f"{key}.uniform: lower bound {a} exceeds upper bound {b}")
    return a, b


def distinct_list(key: str, value, what: str) -> list:
    """A non-empty list of distinct items; `what` says what they must be (in the message)."""
    if not isinstance(value, list) or not value or len(set(value)) != len(value):
        raise SpecError(f"{key}: expected a non-empty list of distinct {what}, got {value!r}")
    return value


def in_range(key: str, value, lo: float, hi: float, integer: bool = False):
    """A number (an integer with integer=True; not a boolean) in [lo, hi], returned as given;
    the message says "KEY must be a number in [lo, hi]" (the converge dialect)."""
    ok = (isinstance(value, int) if integer else isinstance(value, (int, float))) and \
        not isinstance(value, bool)
    if not ok or not lo <= value <= hi:
        kind = "an integer" if integer else "a number"
        raise SpecError(f"{key} must be {kind} in [{lo}, {hi}], got {value!r}")
    return value


def robot_file_of(data: dict) -> str | None:
    """The [robot] table's file (None without the table); SpecError names robot.file."""
    robot = data.get("robot")
    if robot is None:
        return None
    if not isinstance(robot, dict) or set(robot) != {"file"}:
        raise SpecError(f"[robot]: expected exactly one key, file = \"path/robot.toml\", got "
                        f"{robot!r}")
    if not isinstance(robot["file"], str) or not robot["file"]:
        raise SpecError(f"robot.file: expected a path to a robot file, got {robot['file']!r}")
    return robot["file"]
