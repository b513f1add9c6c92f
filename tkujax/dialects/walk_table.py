"""[walk] of a sweep spec: the robot walks while it is pushed (docs/walking.md).

    [walk]
    speed_mps = 0.1            # forward, m/s (default 0: stepping in place)
    lateral_mps = 0.0          # sideways, m/s (+ = left)
    step_period_s = 0.3        # default: the robot's (WalkCommand.for_params)
    recovery = ["off", "on"]   # the walking recovery (WalkCommand.recovery), crossed like control
    push_cycle = 9             # the gait cycle that push.*.gait_phase onsets fall in
    recovery_forward_gain = 1  # the recovery's forward footstep moves x this (0: none)
    recovery_late_swing_gain = 1   # a late sideways push's swing foot moves x this (0: the
                                   # support foot alone moves)
    recovery_hurry = 0         # the share of its remaining time a step that took an offset
                               # cuts (0: nominal timing; negative: time added)

    [push.grid]
    gait_phase = {start = 0, stop = 1, num = 8, endpoint = false}   # instead of onset_s

gait_phase in [0, 1): 0 is the left foot's nominal touchdown, 0.5 the right's
(`tkujax.control.gait.gait_phase`); the onset is `time_at_phase(gait_phase, push_cycle)` of the
walk. It replaces onset_s (and onset_phase) in [push.grid] and [push.random]. Every record of a
walking sweep carries gait_phase (derived from onset_s when not given), the commanded walk
(walk_speed_mps, walk_lateral_mps, walk_step_period_s, walk_recovery) and, as an outcome,
distance_m: the CoM's horizontal travel from the first step to the horizon or the fall.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from tkujax.control.gait import WALK_LIMITS, WalkCommand, gait_phase, time_at_phase
from tkujax.control.controller_params import ControllerParams
from tkujax.dialects.floor_table import check_floor_decisions
from tkujax.dialects.validation import SpecError, integer, number, table

GAIT_PHASE_KEY = "gait_phase"
GAIT_PHASE_UNIT = "(fraction of the gait cycle, 0 = left touchdown; 1 excluded)"
RECOVERY_SETTINGS = ("off", "on")
# [walk] keys: (lo, hi, unit); the limits of WalkCommand.validate.
WALK_FIELDS = {k: (*WALK_LIMITS[k], unit) for k, unit in (
    ("speed_mps", "m/s"), ("lateral_mps", "m/s"), ("step_period_s", "s"),
    ("recovery_forward_gain", "(a gain)"), ("recovery_late_swing_gain", "(a gain)"),
    ("recovery_hurry", "(a share of the step's remaining time)"))}
PUSH_CYCLE_RANGE = (0, 100)
DEFAULT_PUSH_CYCLE = 9      # as tkujax.walking.walk_push.PUSH_CYCLE: the recovery is armed
# The record columns of the commanded walk, and the WalkCommand field each one sets.
WALK_COLUMNS = {"walk_speed_mps": "speed_mps", "walk_lateral_mps": "lateral_mps",
                "walk_step_period_s": "step_period_s", "walk_recovery": "recovery"}


@dataclasses.dataclass(frozen=True)
class WalkSpec:
    """The validated [walk] table. `base`: the robot's WalkCommand with the spec's speeds and
    step period (recovery 0), as `resolve_walk` made it for the sweep's robot."""

    speed_mps: float = 0.0
    lateral_mps: float = 0.0
    step_period_s: float | None = None     # None: the robot's
    recovery_forward_gain: float | None = None     # WalkCommand's; None: the robot's, else 1
    recovery_late_swing_gain: float | None = None  # WalkCommand's; None: the robot's, else 1
    recovery_hurry: float | None = None            # WalkCommand's; None: the robot's, else 0
    recovery: tuple[str, ...] = ("off",)
    push_cycle: int = DEFAULT_PUSH_CYCLE
    base: WalkCommand | None = None

    def command(self) -> WalkCommand:
        if self.base is None:
            raise SpecError("[walk]: the walk is not resolved for a robot yet (resolve_walk)")
        return self.base


def parse_walk(data: dict) -> WalkSpec | None:
    """The [walk] table (None without one); SpecError names the key and its range."""
    if "walk" not in data:
        return None
    raw = table("walk", data["walk"], set(WALK_FIELDS) | {"recovery", "push_cycle"})
    vals = {k: number(f"walk.{k}", raw[k], *WALK_FIELDS[k]) for k in WALK_FIELDS if k in raw}
    recovery = raw.get("recovery", ["off"])
    if isinstance(recovery, (str, bool)):
        recovery = [recovery]
    recovery = ["on" if r is True else "off" if r is False else r for r in recovery] \
        if isinstance(recovery, list) else recovery
    if (not isinstance(recovery, list) or not recovery or len(set(recovery)) != len(recovery)
            or any(r not in RECOVERY_SETTINGS for r in recovery)):
        raise SpecError(f"walk.recovery: expected 'off', 'on', true, false or a list of distinct "
                        f"'off'/'on', got {raw.get('recovery')!r}")
    cycle = integer("walk.push_cycle", raw.get("push_cycle", DEFAULT_PUSH_CYCLE),
                    *PUSH_CYCLE_RANGE)
    return WalkSpec(recovery=tuple(recovery), push_cycle=cycle, **vals)


def gait_of(robot_file: str | None) -> tuple[ControllerParams, dict]:
    """The controller parameters the gait's defaults come from (TKU-X's paper parameters, or a
    robot file's scaled defaults: `tkujax.walking.walk.walker`) and the robot file's [walk]
    table over them ({} for TKU-X)."""
    if robot_file is None:
        return ControllerParams.paper(), {}
    from tkujax.walking.walk import walker
    who = walker(robot_file)
    return who.gait_params, who.gait


def resolve_walk(walk: WalkSpec, gait_params: ControllerParams,
                 robot_gait: dict | None = None) -> WalkSpec:
    """`walk` with its base command for the robot whose gait defaults are `gait_params` and
    whose robot file's [walk] table is `robot_gait` (the spec's keys win over it);
    SpecError from WalkCommand.validate."""
    fields = dict(robot_gait or {})
    if walk.step_period_s is not None:
        fields["step_period_s"] = walk.step_period_s
    for key in ("recovery_forward_gain", "recovery_late_swing_gain", "recovery_hurry"):
        if getattr(walk, key) is not None:
            fields[key] = getattr(walk, key)
    base = WalkCommand.for_params(gait_params, walk.speed_mps, walk.lateral_mps, **fields)
    try:
        base.validate()
    except ValueError as err:
        raise SpecError(f"[walk]: {err}") from None
    return dataclasses.replace(walk, base=base)


def onsets_at_phase(walk: WalkSpec, phase) -> np.ndarray:
    """The onsets (s) of gait phases `phase` in gait cycle walk.push_cycle of the walk, to the
    microsecond (the robot's parameters are float32)."""
    return np.round(np.asarray(time_at_phase(np.asarray(phase, np.float64),
                                             float(walk.push_cycle), _floats(walk.command())),
                               np.float64), 6)


def phases_at_onset(walk: WalkSpec, onset_s) -> np.ndarray:
    """The nominal gait phase in [0, 1) of each onset (s), to 1e-5 (the robot's parameters are
    float32: 5.97 s would otherwise be phase 0.9999996 of TKU-X's walk, not 0)."""
    phase = gait_phase(np.asarray(onset_s, np.float64), _floats(walk.command()))
    return np.mod(np.round(np.asarray(phase, np.float64), 5), 1.0)


def _floats(command: WalkCommand) -> WalkCommand:
    """The command's fields as numpy float64 (the schedule in numpy, outside any program)."""
    return WalkCommand(**{f.name: np.float64(getattr(command, f.name))
                          for f in dataclasses.fields(WalkCommand)})


def gait_phase_values(key: str, value, values_fn) -> np.ndarray:
    """Grid gait phases in [0, 1) (a range may use stop = 1 with endpoint = false)."""
    try:
        vals = values_fn(key, value, 0.0, 1.0, GAIT_PHASE_UNIT)
    except SpecError as err:
        raise SpecError(str(err).replace("[0.0, 1.0]", "[0, 1)")) from None
    if (vals >= 1.0).any():
        raise SpecError(f"{key}: {float(vals.max())!r} is out of range [0, 1) {GAIT_PHASE_UNIT}")
    return vals


def check_gait_phase_keys(part: str, keys, walk: WalkSpec | None, phase_key: str) -> None:
    """gait_phase needs [walk] and replaces onset_s and onset_phase in [push.PART]."""
    if GAIT_PHASE_KEY not in keys:
        return
    if walk is None:
        raise SpecError(f"push.{part}.{GAIT_PHASE_KEY}: a gait phase needs a [walk] table "
                        "(the robot walks); standing pushes take onset_s")
    both = sorted({"onset_s", phase_key} & set(keys))
    if both:
        raise SpecError(f"push.{part}: {GAIT_PHASE_KEY} gives the onset; leave out {both}")


def cross_walk(walk: WalkSpec | None, recs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every record once per walk.recovery setting (outermost), with the walk's columns and
    the gait phase of each onset. No [walk]: unchanged."""
    if walk is None:
        return recs
    base = walk.command()
    out = {k: np.concatenate([v] * len(walk.recovery)) for k, v in recs.items()}
    n = len(recs["control"])
    out["walk_recovery"] = np.concatenate([np.full(n, float(r == "on")) for r in walk.recovery])
    for col, field in WALK_COLUMNS.items():
        if col != "walk_recovery":
            out[col] = np.full(len(out["control"]), float(getattr(base, field)))
    given = np.isfinite(out[GAIT_PHASE_KEY])
    out[GAIT_PHASE_KEY] = np.where(given, out[GAIT_PHASE_KEY], phases_at_onset(walk,
                                                                             out["onset_s"]))
    return out


def walk_commands(base: WalkCommand, rec: dict) -> WalkCommand:
    """The records' WalkCommand: `base` with the walk_* columns of `rec` (numpy or traced)."""
    return dataclasses.replace(base, **{field: rec[col] for col, field in WALK_COLUMNS.items()})


def check_walk_sweep(spec) -> None:
    """Refuse what a walking sweep cannot run: commanded steps and the fixed-point twin. (Early
    decisions run: a walking lane is decided by a fall only, `tkujax.sim.lanes`.) For push
    sequences ([push.sequence]): no commanded step, and no early decisions (the settled rule
    would not wait for the last pulse); for slopes no early decisions (the lanes' program is
    the level floor's)."""
    check_floor_decisions(spec)
    if spec.sequence is not None and (spec.step_grid or spec.decisions.early):
        raise SpecError("[push.sequence]: a push sequence runs with the controller's own steps "
                        "and decisions = \"full\"; leave out [step] and early decisions")
    if spec.walk is None:
        return
    if spec.step_grid:
        raise SpecError("[step]: commanded steps do not run while walking; leave out [walk] or "
                        "[step]")
    if spec.arithmetic == "fixed":
        raise SpecError("[walk]: the fixed-point controller has no gait; use "
                        "controller.arithmetic = \"float\"")


def walk_base(spec):
    """A spec's base WalkCommand (None: a standing sweep)."""
    return None if spec.walk is None else spec.walk.command()


def walk_for_robot(spec, robot):
    """`spec` with its walk resolved for `robot` (a Robot given on the command line in
    place of the spec's [robot] file: its gait defaults); check its pushes' window again
    (`tkujax.dialects.push_limits.check_push_window`)."""
    if spec.walk is None or spec.robot_file == robot.source:
        return spec
    gait = robot.defaults if robot.defaults is not None else robot.params
    return dataclasses.replace(spec, walk=resolve_walk(spec.walk, gait, dict(robot.gait)))
