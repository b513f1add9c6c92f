"""Pushes while walking: a push's onset by gait phase, and the push set that compares walking
with the capture point moving the next footstep (WalkCommand.recovery = 1) against the same
walk without it (docs/walking.md).

`push_at_gait_phase` places a push at `gait_phase` in [0, 1) (0 = the left foot's touchdown,
`tkujax.control.gait.gait_phase`) of gait cycle `cycle` of a walk; `run_walk_pushes` runs a
grid of directions x impulses x phases with the recovery off and on (one or more recovery
settings: WalkCommand fields) on one engine and counts falls, the sideways pushes also by the
foot whose step they arrive in (`outward_step`).
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
    duration_s: float = DEFAULT_DURATION_S


def outward_step(azimuth_deg, gait_phase, command: WalkCommand) -> np.ndarray:
    """(int) 1 where a sideways push (azimuth not 0 or 180 deg) arrives in a step of the foot
    on the side it pushes toward (the one that can step outward: the left foot's for a push
    from the right), 0 where it arrives in the other foot's step (the offset must wait for a
    later step), -1 for pushes from behind or the front. The right foot's step spans gait
    phases [gamma / 4, gamma / 4 + 1/2) of the nominal schedule."""
    az = np.mod(np.asarray(azimuth_deg, np.float64), 360.0)
    start = 0.25 * float(command.double_support_ratio)
    right_steps = np.mod(np.asarray(gait_phase, np.float64) - start, 1.0) < 0.5
    toward_left = (az > 0.0) & (az < 180.0)
    out = np.where(toward_left, ~right_steps, right_steps).astype(int)
    return np.where((az == 0.0) | (az == 180.0), -1, out)


def run_walk_pushes(push_set: WalkPushSet, robot_file: str | None = None,
                    engine: str = "mujoco", who: Walker | None = None,
                    settings: dict[str, dict] | None = None) -> dict:
    """The push set with recovery off and on (balance control on in both): falls per run, per
    direction, per impulse and per phase, of the sideways pushes per foot whose step they
    arrive in (`outward_step`), the pushes each recovery run saves and fells, and the pushes
    that fall in one run only (of "recovery_on"). settings: {run name: WalkCommand fields} of
    the recovery-on runs (default {"recovery_on": {}}: the robot's defaults)."""
    who = who or walker(robot_file)
    settings = {"recovery_on": {}} if settings is None else settings
    grid = list(itertools.product(push_set.azimuths_deg, push_set.impulses_ns,
                                  push_set.phases))
    out = dict(robot=who.name, engine=engine, n=len(grid), speed_mps=push_set.speed_mps,
               set=dataclasses.asdict(push_set), settings=settings)
    fell = {}
    runs = {"recovery_off": dict(recovery=0.0)}
    runs.update({name: dict(fields, recovery=1.0) for name, fields in settings.items()})
    for label, fields in runs.items():
        cmd = WalkCommand.for_params(who.gait_params, push_set.speed_mps, **(who.gait | fields))
        pushes = stack_pushes([push_at_gait_phase(cmd, ph, imp, az, push_set.height_m,
                                                  push_set.duration_s)
                               for az, imp, ph in grid])
        horizon = float(np.max(np.asarray(pushes.onset_s))) + AFTER_PUSH_S
        t0 = time.perf_counter()
        series, outcomes = run_walk(who, [cmd] * len(grid), horizon, engine, pushes=pushes)
        fell[label] = np.asarray(outcomes.fell, bool)
        out[label] = _tally(fell[label], fell["recovery_off"], grid, push_set, cmd,
                            time.perf_counter() - t0,
                            np.asarray(series.step_weight)[:, -1] > 0.5)
    if "recovery_on" in fell:
        out["only_off"] = _listed(fell["recovery_off"] & ~fell["recovery_on"], grid)
        out["only_on"] = _listed(fell["recovery_on"] & ~fell["recovery_off"], grid)
    return out


def _tally(fell, off, grid, push_set: WalkPushSet, command: WalkCommand, wall: float,
           moved) -> dict:
    az, imp, ph = (np.array([g[i] for g in grid]) for i in range(3))
    outward = outward_step(az, ph, command)
    halves = {"outward_foot_step": outward == 1, "other_foot_step": outward == 0}
    return dict(falls=int(fell.sum()), wall_s=round(wall, 1), footsteps_moved=int(moved.sum()),
                saved=int((off & ~fell).sum()), felled=int((fell & ~off).sum()),
                by_azimuth={f"{a:g}": int(fell[az == a].sum()) for a in push_set.azimuths_deg},
                by_impulse={f"{i:g}": int(fell[imp == i].sum()) for i in push_set.impulses_ns},
                by_phase={f"{p:g}": int(fell[ph == p].sum()) for p in push_set.phases},
                sideways_by_step={k: dict(n=int(m.sum()), falls=int(fell[m].sum()),
                                          saved=int((off & ~fell & m).sum()),
                                          felled=int((fell & ~off & m).sum()))
                                  for k, m in halves.items()})


def _listed(mask, grid) -> list[dict]:
    return [dict(azimuth_deg=g[0], impulse_ns=g[1], gait_phase=g[2])
            for g, m in zip(grid, mask) if m]

