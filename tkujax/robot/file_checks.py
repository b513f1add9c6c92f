"""The robot file's error and the checks its tables share (keys, strings, numbers), each
naming the key it refuses."""

from __future__ import annotations

import math

from tkujax.model.files import SpecError


class RobotFileError(SpecError):
    """A problem with a robot file or its model; the message names the key."""


def check_keys(data: dict, allowed, required, table: str) -> None:
    """Unknown and missing keys of `table` ("" for the top level, else e.g. "legs.left")."""
    unknown = sorted(set(data) - set(allowed))
    if unknown:
        raise RobotFileError(f"{table or 'top level'}: unknown key(s) {unknown}; allowed: "
                             f"{list(allowed)}")
    missing = [k for k in required if k not in data]
    if missing:
        prefix = f"{table}." if table else ""
        raise RobotFileError(f"{table or 'top level'}: missing required key(s) "
                             f"{[f'{prefix}{k}' for k in missing]}")


def string(data: dict, key: str, table: str = "") -> str:
    """A non-empty string at `table.key`."""
    value = data.get(key)
    if not isinstance(value, str) or not value:
        where = f"{table}.{key}" if table else key
        raise RobotFileError(f"{where}: expected a non-empty string, got {value!r}")
    return value


def number(key: str, value, lo: float, hi: float, unit: str, lo_open: bool = False) -> float:
    """A finite number (not a boolean) in [lo, hi] ((lo, hi] when lo_open), as a float."""
    rng = f"{'(' if lo_open else '['}{lo:g}, {hi:g}] {unit}".rstrip()
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise RobotFileError(f"{key}: expected a number in {rng}, got {value!r}")
    if value < lo or value > hi or (lo_open and value == lo):
        raise RobotFileError(f"{key}: {value!r} is out of range {rng}")
    return float(value)
