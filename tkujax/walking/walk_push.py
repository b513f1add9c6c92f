"""Pushes while walking: a push's onset by gait phase, and the push set that compares walking
with the capture point moving the next footstep (WalkCommand.recovery = 1) against the same
walk without it (docs/walking.md).

`push_at_gait_phase` places a push at `gait_phase` in [0, 1) (0 = the left foot's touchdown,
`tkujax.control.gait.gait_phase`) of gait cycle `cycle` of a walk; `run_walk_pushes` runs a
grid of directions x impulses x phases twice (recovery off, on) on one engine and counts falls.
"""

from __future__ import annotations

import dataclasses
import itertools
import time

import numpy as np

from tkujax.control.gait import WalkCommand, time_at_phase
from tkujax.sim.push import DEFAULT_DURATION_S, make_push, stack_pushes
from tkujax.walking.walk import Walker, run_walk, walker

PUSH_CYCLE = 9          # pushes land in the 10th gait cycle: the trigger is armed (walk_recovery)
AFTER_PUSH_S = 3.0      # simulated after the onset: a fall shows well within it


def push_at_gait_phase(command: WalkCommand, gait_phase: float, impulse_ns: float,
                       azimuth_deg: float = 0.0, height_m: float | None = None,
                       duration_s: float = DEFAULT_DURATION_S, cycle: int = PUSH_CYCLE):
    """A Push (tkujax.sim.push.make_push, validated) whose onset is the nominal time of
    `gait_phase` in [0, 1) of gait cycle `cycle` of the walk `command` (0 = the cycle that
    starts at the first left touchdown). height_m None: make_push's default (TKU-X's chest)."""
    if not 0.0 <= gait_phase < 1.0:
        raise ValueError(f"gait_phase must be in [0, 1), got {gait_phase!r}")
    if isinstance(cycle, bool) or not isinstance(cycle, int) or not 0 <= cycle <= 100:
        raise ValueError(f"cycle must be an integer in [0, 100], got {cycle!r}")
    onset = float(time_at_phase(float(gait_phase), float(cycle), command))
    extra = {} if height_m is None else dict(height_m=float(height_m))
    return make_push(float(impulse_ns), float(azimuth_deg), duration_s=float(duration_s),
                     onset_s=onset, **extra)


@dataclasses.dataclass(frozen=True)
class WalkPushSet:
    """A grid of pushes on a walk: directions (deg, 0 = from behind, 90 = from the robot's
    right, pushing it left), impulses (N s), gait phases; at height_m (None: TKU-X's
    default) and the walk's speed (m/s)."""

    speed_mps: float = 0.1
    azimuths_deg: tuple[float, ...] = (0.0, 90.0, 180.0, 270.0)
    impulses_ns: tuple[float, ...] = (0.4, 0.6, 0.8, 1.0, 1.2, 1.6)
    phases: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75)
    height_m: float | None = None


def run_walk_pushes(push_set: WalkPushSet, robot_file: str | None = None,
                    engine: str = "mujoco", who: Walker | None = None) -> dict:
    """The push set with recovery off and on (balance control on in both): falls per run, per
    direction, per impulse and per phase, and the pushes that fall in one run only."""
    who = who or walker(robot_file)
    grid = list(itertools.product(push_set.azimuths_deg, push_set.impulses_ns,
                                  push_set.phases))
    out = dict(robot=who.name, engine=engine, n=len(grid), speed_mps=push_set.speed_mps,
               set=dataclasses.asdict(push_set))
    fell = {}
    for label, recovery in (("recovery_off", 0.0), ("recovery_on", 1.0)):
        cmd = WalkCommand.for_params(who.gait_params, push_set.speed_mps, recovery=recovery)
        pushes = stack_pushes([push_at_gait_phase(cmd, ph, imp, az, push_set.height_m)
                               for az, imp, ph in grid])
        horizon = float(np.max(np.asarray(pushes.onset_s))) + AFTER_PUSH_S
        t0 = time.perf_counter()
        series, outcomes = run_walk(who, [cmd] * len(grid), horizon, engine, pushes=pushes)
        fell[label] = np.asarray(outcomes.fell, bool)
        out[label] = _tally(fell[label], grid, push_set, time.perf_counter() - t0,
                            np.asarray(series.step_weight)[:, -1] > 0.5)
    out["only_off"] = _listed(fell["recovery_off"] & ~fell["recovery_on"], grid)
    out["only_on"] = _listed(fell["recovery_on"] & ~fell["recovery_off"], grid)
    return out


def _tally(fell, grid, push_set: WalkPushSet, wall: float, moved) -> dict:
    az, imp, ph = (np.array([g[i] for g in grid]) for i in range(3))
    return dict(falls=int(fell.sum()), wall_s=round(wall, 1), footsteps_moved=int(moved.sum()),
                by_azimuth={f"{a:g}": int(fell[az == a].sum()) for a in push_set.azimuths_deg},
                by_impulse={f"{i:g}": int(fell[imp == i].sum()) for i in push_set.impulses_ns},
                by_phase={f"{p:g}": int(fell[ph == p].sum()) for p in push_set.phases})


def _listed(mask, grid) -> list[dict]:
    return [dict(azimuth_deg=g[0], impulse_ns=g[1], gait_phase=g[2])
            for g, m in zip(grid, mask) if m]

