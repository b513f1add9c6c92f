"""Slopes: the floor pitched uphill or downhill, as a tilted gravity (RolloutConfig
.floor_pitch_deg).

Pitching the floor by theta about the world y axis (theta > 0: the floor rises toward +x,
the robot's forward in its stand, so a walk forward goes uphill) is, in the floor's frame, the
same physics as a level floor under gravity g (-sin theta, 0, -cos theta): every contact, the
IMU (its accelerometer reads the specific force against this gravity) and the fall test
(heights above the floor) stay as they are. The robot starts from its level stand and settles
on the slope in the first few hundred milliseconds (the walk starts at 0.3 s; pushes land
later). Both backends tilt the same way: MJX the traced model's opt.gravity, MuJoCo C a copy of
the host model.
"""

from __future__ import annotations

import copy
import math

import numpy as np

FLOOR_PITCH_RANGE_DEG = (-15.0, 15.0)


def check_floor_pitch(pitch_deg: float) -> float:
    """The pitch as a float; ValueError outside FLOOR_PITCH_RANGE_DEG (or not finite)."""
    lo, hi = FLOOR_PITCH_RANGE_DEG
    if isinstance(pitch_deg, bool) or not isinstance(pitch_deg, (int, float)) or not (
            lo <= pitch_deg <= hi):
        raise ValueError(f"floor_pitch_deg must be a number in [{lo:g}, {hi:g}] deg "
                         f"(+ = uphill toward +x), got {pitch_deg!r}")
    return float(pitch_deg)


def slope_gravity(pitch_deg: float, g: float) -> np.ndarray:
    """(3,) gravity (m/s^2) in the floor's frame of a floor pitched by pitch_deg."""
    th = math.radians(pitch_deg)
    return np.array([-g * math.sin(th), 0.0, -g * math.cos(th)])


def tilt_mjx_model(model, pitch_deg: float):
    """An MJX model whose gravity is the slope's (pitch 0: the model itself)."""
    if pitch_deg == 0.0:
        return model
    g = float(np.linalg.norm(np.asarray(model.opt.gravity)))
    gravity = np.asarray(slope_gravity(pitch_deg, g), np.asarray(model.opt.gravity).dtype)
    return model.replace(opt=model.opt.replace(gravity=gravity))


def tilt_host_model(model, pitch_deg: float):
    """A copy of a MuJoCo C model whose gravity is the slope's (pitch 0: the model itself)."""
    if pitch_deg == 0.0:
        return model
    tilted = copy.deepcopy(model)
    tilted.opt.gravity[:] = slope_gravity(pitch_deg, float(np.linalg.norm(model.opt.gravity)))
    return tilted
