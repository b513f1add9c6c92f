"""The pushes a robot is tuned and judged on, derived from the robot itself.

`robot_pushes(robot)` measures where the robot standing still (control off) falls: a ladder of
impulses in units of its own momentum scale m sqrt(g h), from eight directions at its CoM
height (MuJoCo C, `PROBE_*`), up to the impulse where about 80 % of the ladder's pushes fall
(`FALL_TARGET`). The distributions then span the hard part of the robot's range:

- impulses uniform in [IMPULSE_LO_FRAC, 1] x that impulse;
- contact heights on the trunk, uniform in HEIGHT_BAND x the CoM height (on TKU-X, inside
  its trunk: `contact_heights_m`);
- every direction, every hit phase (onsets uniform over several control periods);
- pulses of 10-80 ms.

The tuning set and the held-out set are drawn from them with different seeds and onsets
(`tkujax.studies.robot_tune`).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from tkujax.sim.push import make_push, stack_pushes
from tkujax.sim.options import RolloutConfig
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.sweeps.sweep import TKUX_HEIGHT_M

FALL_TARGET = 0.8                     # the ladder stops where this share of pushes falls
PROBE_STEPS = np.arange(1, 41) * 0.025   # x m sqrt(g h): 0.025 .. 1.0
PROBE_AZIMUTHS_DEG = tuple(range(0, 360, 45))
PROBE_ONSET_S, PROBE_DURATION_S, PROBE_HORIZON_S = 0.3, 0.02, 1.5
IMPULSE_LO_FRAC = 0.1
HEIGHT_BAND = (1.0, 1.2)              # x the CoM height: the trunk above the CoM
PULSE_S = (0.01, 0.08)


@dataclasses.dataclass(frozen=True)
class RobotPushes:
    """A robot's push distributions (uniform bounds, SI units) and what they came from."""

    impulse_ns: tuple[float, float]
    height_m: tuple[float, float]
    duration_s: tuple[float, float]
    fall80_ns: float                  # where FALL_TARGET of the probe's pushes fell
    ladder_ns: tuple[float, ...]      # the probe's impulses, and the share that fell at each
    ladder_fell: tuple[float, ...]

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def momentum_scale(mass_kg: float, com_height_m: float, g: float = 9.81) -> float:
    """m sqrt(g h), N s: the momentum of the robot falling through its own CoM height's time
    scale (a push of ~0.1-0.4 of it tips a standing humanoid)."""
    return mass_kg * math.sqrt(g * com_height_m)


def _probe(robot, impulses: np.ndarray) -> np.ndarray:
    """The share of PROBE_AZIMUTHS_DEG pushes of each impulse that fall, control off."""
    h = float(robot.defaults.com_height)
    pushes = stack_pushes([make_push(float(j), azimuth_deg=float(a), height_m=h,
                                     duration_s=PROBE_DURATION_S, onset_s=PROBE_ONSET_S)
                           for j in impulses for a in PROBE_AZIMUTHS_DEG])
    n = len(impulses) * len(PROBE_AZIMUTHS_DEG)
    _, out = simulate_mujoco(pushes, np.zeros(n), robot.defaults, robot=robot,
                             config=RolloutConfig(duration_s=PROBE_HORIZON_S))
    return np.asarray(out.fell, float).reshape(len(impulses), -1).mean(axis=1)


def _ladder(robot) -> np.ndarray:
    """The probe's impulses (N s): PROBE_STEPS x the robot's momentum scale."""
    mass_kg = float(robot.setup.host_model.body_subtreemass[1])   # body 1: the floating base
    return PROBE_STEPS * momentum_scale(mass_kg, float(robot.defaults.com_height))


def contact_heights_m(robot) -> tuple[float, float]:
    """HEIGHT_BAND x the CoM height; on the built-in TKU-X, inside its trunk (TKUX_HEIGHT_M: its
    CoM, 0.244 m high, sits below the trunk's 0.25 m, where a sweep refuses a push)."""
    h = float(robot.defaults.com_height)
    lo, hi = HEIGHT_BAND[0] * h, HEIGHT_BAND[1] * h
    if robot.builtin:
        lo, hi = (min(max(x, TKUX_HEIGHT_M[0]), TKUX_HEIGHT_M[1]) for x in (lo, hi))
    return round(lo, 4), round(hi, 4)


def _distributions(robot, top: float, ladder, fell) -> RobotPushes:
    return RobotPushes(
        impulse_ns=(round(IMPULSE_LO_FRAC * top, 4), round(top, 4)),
        height_m=contact_heights_m(robot),
        duration_s=PULSE_S, fall80_ns=round(top, 4),
        ladder_ns=tuple(round(float(x), 4) for x in ladder),
        ladder_fell=tuple(round(float(x), 4) for x in fell))


def widest_pushes(robot) -> RobotPushes:
    """The widest distributions `robot_pushes` can give `robot` (the ladder's top impulse),
    without simulating: what the tune's checks read before the probe runs."""
    ladder = _ladder(robot)
    return _distributions(robot, float(ladder[-1]), ladder, np.zeros(len(ladder)))


def robot_pushes(robot) -> RobotPushes:
    """The push distributions of `robot` (a Robot; see the module doc): the probe runs in
    rungs of eight impulses, stopping at the first rung that reaches FALL_TARGET."""
    ladder = _ladder(robot)
    fell: list[float] = []
    for start in range(0, len(ladder), 8):
        fell.extend(_probe(robot, ladder[start:start + 8]).tolist())
        if max(fell) >= FALL_TARGET:
            break
    fell_a = np.array(fell)
    reached = np.nonzero(fell_a >= FALL_TARGET)[0]
    top = float(ladder[reached[0]] if reached.size else ladder[len(fell) - 1])
    return _distributions(robot, top, ladder[:len(fell)], fell)
