"""Slopes: the floor pitched uphill or downhill and rolled sideways, as a tilted gravity
(RolloutConfig.floor_pitch_deg, RolloutConfig.floor_roll_deg; one Floor value inside).

Pitching the floor by theta about the world y axis (theta > 0: the floor rises toward +x,
the robot's forward in its stand, so a walk forward goes uphill) and then rolling it by phi
about the world x axis (phi > 0: the floor rises toward +y, the robot's left) turns it by

    R = Rx(phi) Ry(-theta),   Rx(a) = [[1, 0, 0], [0, cos a, -sin a], [0, sin a, cos a]],
                              Ry(a) = [[cos a, 0, sin a], [0, 1, 0], [-sin a, 0, cos a]].

In the floor's frame the world's gravity (0, 0, -g) is R^T (0, 0, -g) = Ry(theta) Rx(-phi)
(0, 0, -g) = g (-sin theta cos phi, -sin phi, -cos theta cos phi), of magnitude g: the same
physics as a level floor under that gravity. Every contact, the IMU (its accelerometer reads
the specific force against this gravity) and the fall test (heights above the floor) stay as
they are. The robot starts from its level stand and settles on the slope in the first few
hundred milliseconds (the walk starts at 0.3 s; pushes land later). Both backends tilt the
same way: MJX the traced model's opt.gravity, MuJoCo C a copy of the host model.
"""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np

FLOOR_PITCH_RANGE_DEG = (-15.0, 15.0)
FLOOR_ROLL_RANGE_DEG = FLOOR_PITCH_RANGE_DEG
FLOOR_PITCH_SIGN = "+ = uphill toward +x"
FLOOR_ROLL_SIGN = "+ = the floor rises toward +y"


def _check_angle(name: str, deg: float, bounds: tuple[float, float], sign: str) -> float:
    lo, hi = bounds
    if isinstance(deg, bool) or not isinstance(deg, (int, float)) or not lo <= deg <= hi:
        raise ValueError(f"{name} must be a number in [{lo:g}, {hi:g}] deg ({sign}), "
                         f"got {deg!r}")
    return float(deg)


def check_floor_pitch(pitch_deg: float) -> float:
    """The pitch as a float; ValueError outside FLOOR_PITCH_RANGE_DEG (or not finite)."""
    return _check_angle("floor_pitch_deg", pitch_deg, FLOOR_PITCH_RANGE_DEG, FLOOR_PITCH_SIGN)


def check_floor_roll(roll_deg: float) -> float:
    """The roll as a float; ValueError outside FLOOR_ROLL_RANGE_DEG (or not finite)."""
    return _check_angle("floor_roll_deg", roll_deg, FLOOR_ROLL_RANGE_DEG, FLOOR_ROLL_SIGN)


def slope_gravity(pitch_deg: float, g: float, roll_deg: float = 0.0) -> np.ndarray:
    """(3,) gravity (m/s^2) in the floor's frame of a floor pitched by pitch_deg, then rolled
    by roll_deg (the module doc). Roll 0: exactly the pitched floor's (-g sin, 0, -g cos)."""
    th, ph = math.radians(pitch_deg), math.radians(roll_deg)
    return np.array([-g * math.sin(th) * math.cos(ph), -g * math.sin(ph) if roll_deg else 0.0,
                     -g * math.cos(th) * math.cos(ph)])


@dataclasses.dataclass(frozen=True)
class Floor:
    """The floor's inclination: pitch_deg, then roll_deg (the module doc; each checked, as a
    float). Floor() is the level floor (LEVEL_FLOOR). Hashable: a cache key."""

    pitch_deg: float = 0.0
    roll_deg: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "pitch_deg", check_floor_pitch(self.pitch_deg))
        object.__setattr__(self, "roll_deg", check_floor_roll(self.roll_deg))

    @property
    def is_level(self) -> bool:
        """Both angles 0: the model's own gravity, the program unchanged."""
        return self.pitch_deg == 0.0 and self.roll_deg == 0.0

    def gravity(self, g: float) -> np.ndarray:
        """(3,) gravity (m/s^2) in this floor's frame (slope_gravity)."""
        return slope_gravity(self.pitch_deg, g, self.roll_deg)


LEVEL_FLOOR = Floor()


def tilt_mjx_model(model, floor: Floor):
    """An MJX model whose gravity is the floor's (a level floor: the model itself)."""
    if floor.is_level:
        return model
    g = float(np.linalg.norm(np.asarray(model.opt.gravity)))
    gravity = np.asarray(floor.gravity(g), np.asarray(model.opt.gravity).dtype)
    return model.replace(opt=model.opt.replace(gravity=gravity))


def tilt_host_model(model, floor: Floor):
    """A copy of a MuJoCo C model whose gravity is the floor's (a level floor: the model
    itself)."""
    if floor.is_level:
        return model
    tilted = copy.deepcopy(model)
    tilted.opt.gravity[:] = floor.gravity(float(np.linalg.norm(model.opt.gravity)))
    return tilted
