"""[sweep] floor_pitch_deg and floor_roll_deg: a sweep on a tilted floor (tkujax.sim.slope).

    [sweep]
    floor_pitch_deg = 4.0    # -15 to 15 deg, + = uphill: the floor rises toward +x (forward)
    floor_roll_deg = -3.0    # -15 to 15 deg, + = the floor rises toward +y (the robot's left)

Each key left out is 0 (the level floor) and stays out of the spec as the hash reads it, so a
spec without it keeps its hash. A key set (non-zero) is stated in every record (`tkujax
compare` refuses to pair two floors). A slope runs with decisions = "full".
"""

from __future__ import annotations

import numpy as np

from tkujax.sim.slope import (FLOOR_PITCH_RANGE_DEG, FLOOR_PITCH_SIGN, FLOOR_ROLL_RANGE_DEG,
                              FLOOR_ROLL_SIGN, Floor)
from tkujax.dialects.validation import SpecError, number

# key: (range, unit as a refusal states it)
FLOOR_KEYS = {"floor_pitch_deg": (FLOOR_PITCH_RANGE_DEG, f"deg ({FLOOR_PITCH_SIGN})"),
              "floor_roll_deg": (FLOOR_ROLL_RANGE_DEG, f"deg ({FLOOR_ROLL_SIGN})")}
FLOOR_FIELDS = {k: (int, float) for k in FLOOR_KEYS}   # their [sweep] types


def parse_floor(sweep: dict) -> dict[str, float]:
    """{key: its checked value, 0.0 when left out} of the FLOOR_KEYS of a [sweep] table."""
    return {k: number(f"sweep.{k}", sweep.get(k, 0.0), *bounds, unit)
            for k, (bounds, unit) in FLOOR_KEYS.items()}


def spec_floor(spec) -> Floor:
    """A sweep's floor (its floor_pitch_deg and floor_roll_deg) as one value."""
    return Floor(spec.floor_pitch_deg, spec.floor_roll_deg)


def floor_columns(spec, n: int) -> dict[str, np.ndarray]:
    """The record columns of a sweep's floor over its n records: each key set (non-zero)."""
    return {k: np.full(n, getattr(spec, k)) for k in FLOOR_KEYS if getattr(spec, k)}


def check_floor_decisions(spec) -> None:
    """Refuse early decisions on a slope (the lanes' program is the level floor's)."""
    for k in FLOOR_KEYS:
        if getattr(spec, k) and spec.decisions.early:
            raise SpecError(f"sweep.{k}: a slope runs with decisions = \"full\"")
