"""Declarative sweep specs (TOML): parsing, validation, and expansion into push records.

A spec names what varies and how: grids (every combination) and/or seeded random samples over
the push (impulse, azimuth, contact height, onset, duration), controller parameters, and model
randomisation. Everything is checked before anything runs: unknown keys, wrong types and
out-of-range values raise SpecError naming the key and the allowed range.

    [sweep]
    name = "stability_map"
    seed = 0
    chunk_size = 1024          # pushes per compiled batch and per result file
    duration_s = 2.4           # simulated time per push
    control = ["off", "on"]    # every push is run with each listed setting

    [push.grid]                # lists, or {start, stop, num[, endpoint]} ranges
    impulse_ns = {start = 0.2, stop = 3.0, num = 15}
    azimuth_deg = {start = 0, stop = 360, num = 24, endpoint = false}

    onset_phase = {start = 0, stop = 1, num = 10, endpoint = false}

    [push.random]              # seeded samples, added to the grid ({uniform = [lo, hi]})
    n = 0

onset_phase (a tkujax axis): the push's phase within the 30 ms control period, in [0, 1).
The two onset keys combine: onset = the last controller tick at or before onset_s (ticks at
k * 30 ms) + onset_phase * 30 ms (`tkujax.sim.push.onset_from_phase`); onset_s = 0.75 with
phases 0, 0.1, ... gives 0.750, 0.753, ... s. Without onset_phase, onset_s is used as given
(specs written before the key run unchanged). In [push.random] the phase is drawn uniformly
over [0, 1) by default unless onset_s or onset_phase is given there. Phase 0.6 puts a 20 ms
pulse's peak on the controller's IMU sample (`tkujax.sim.push.peak_on_sample_phase`). Every
record carries an onset_phase column (derived from onset_s when not given).

    [controller]               # fixed ControllerParams overrides (angles in degrees)
    step_period = 0.3
    [controller.grid]          # ControllerParams varied as a grid (crossed with the pushes)
    [randomize]                # per-push model/sensor randomisation ({uniform = [lo, hi]} or
                               # a value)
    ensemble = "results/calibration/ensemble.json"   # one member robot drawn per push
                               # (tkujax.model.ensemble; the other keys apply on top of it)

[randomize] ensemble: each push draws one member uniformly (integer robot_id in [0, n), with the
sweep seed, after the other [randomize] draws), shared by the push's control and grid settings;
the records carry it in a robot_id column. The path is relative to the current directory (or
absolute); the file is read and validated here, and its sha256 enters the sweep's hash.

FPGA fixed-point controller (`tkujax.control.fixed`):

    [controller]
    arithmetic = "fixed"       # default "float"; "fixed" runs controller_step_fx in the loop
    [fpga]                     # FixedPointConfig fields (FPGA_FIELDS); unset keys keep its defaults
    angle_frac_bits = 15       # <group>_int_bits / <group>_frac_bits for angle, rate, length,
    cordic_iterations = 16     #   accel, unit, state, cov; angle_state_frac_bits sets both
    latency_ticks = 0          #   angle and state fraction bits; coef_bits, cordic_guard_bits,
    latency_frac = 0.0         #   rounding ("nearest" / "truncate"), ik_guard_bits
    # ControllerParams options the twin does not implement (accel_gate, cp_excess, ...) must
    # stay at their defaults: tkujax.control.fixed.check_supported.
    [controller.grid]
    fpga.cordic_iterations = [6, 8, 12]   # any [fpga] key gridded: one record column fpga_<key>

    [step]                     # capture regions: commanded recovery steps
                               # (tkujax.control.StepOverride)
    reference = true           # also run each push with the controller's own step
    [step.grid]                # crossed with every push record; x_m, y_m: swing ankle vs its stand
    x_m = {start = -0.1, stop = 0.2, num = 21}
    y_m = [0.0]
    start_delay_s = [0.03]     # after the push onset (from_detection = 0) or the detection (1)

[walk] and gait_phase: studies.spec_walk; [push.sequence]: spec_sequence; [push] kind (velocity
kicks): spec_kick; [sweep] floor_pitch_deg, floor_roll_deg: floor_table. See docs/walking.md.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import math
from pathlib import Path
from typing import Any

import numpy as np

from tkujax.control.fixed.config import FixedPointConfig
from tkujax.control.params_files import checked_value
from tkujax.model.ensemble import load_ensemble
from tkujax.model.model_params import ModelParams
from tkujax.sim.push import onset_from_phase, onset_phase
from tkujax.dialects.program_keys import SWEEP_TREE_PASSES, Decisions, decisions_of, tree_passes_of
from tkujax.dialects.push_limits import (MAX_CHUNK_SIZE, MAX_RECORDS, MAX_SEED, PHASE_KEY,
                                         PHASE_UNIT, PUSH_FIELDS, check_limits, record_count)
from tkujax.dialects.step_table import STEP_FIELDS, cross_steps, parse_step
from tkujax.dialects.kick_table import kick_columns, kick_push_table, on_ticks, push_kind
from tkujax.dialects.sequence_table import (SequenceSpec, check_sequence, draw_sequence,
                                            parse_sequence)
from tkujax.dialects.walk_table import (GAIT_PHASE_KEY, GAIT_PHASE_UNIT, WalkSpec,
                                        check_gait_phase_keys, check_walk_sweep, cross_walk,
                                        gait_of, gait_phase_values, onsets_at_phase,
                                        parse_walk, resolve_walk)
from tkujax.dialects.floor_table import FLOOR_FIELDS, floor_columns, parse_floor
from tkujax.dialects.fpga_table import (ARITHMETIC, FPGA_COLUMN, FPGA_FIELDS,
                                        check_fixed_controller, fixed_point_config, parse_fpga)
from tkujax.dialects.validation import SpecError, number, read_toml, table, uniform, values

# Re-exported: the names other modules import from here.
__all__ = ["ARITHMETIC", "SWEEP_TREE_PASSES", "Decisions", "FPGA_COLUMN", "FPGA_FIELDS",
           "STEP_FIELDS", "PUSH_FIELDS", "PHASE_KEY", "MAX_RECORDS", "MAX_CHUNK_SIZE", "MAX_SEED",
           "record_count", "SpecError", "read_toml", "fixed_point_config", "parse_spec",
           "load_spec", "expand", "parse_randomize", "parse_ensemble", "controller_value",
           "controller_values", "EnsembleRef", "SweepSpec"]


# ControllerParams fields a spec may set; *_deg fields are given in degrees. Their ranges are
# ControllerParams.validate's (tkujax.control.params_files.checked_value), stated there once.
CONTROLLER_FIELDS = (
    "step_period", "double_support_ratio", "lift_height", "eps_forward_deg", "eps_backward_deg",
    "cp_angle_offset_deg", "cp_gain", "gate_temperature_deg", "lateral_steps", "eps_lateral_deg",
    "kalman_q", "kalman_r", "accel_gate",
    # Recovery extensions (ControllerParams docstring); their "off" values are the paper.
    "cp_rate_blend", "cp_lookahead_s", "cp_trigger", "cp_trigger_forward_m",
    "cp_trigger_backward_m", "cp_trigger_lateral_m", "cp_gain_lateral", "stance_ankle_kp",
    "stance_ankle_kd", "stance_hip_kp", "stance_hip_kd", "stance_roll_kp", "stance_roll_kd",
    "stance_limit", "max_steps", "step_shift_m",
)
# Randomisation: multiplicative scales and additive values applied per push.
RANDOMIZE_FIELDS = {
    "link_mass_scale": (0.5, 1.5, "x (all bodies)"),
    "torso_com_offset_x_m": (-0.05, 0.05, "m (chest body CoM, forward)"),
    "floor_friction": (0.1, 2.0, ""),
    "servo_kp_scale": (0.5, 1.5, "x (all actuators)"),
    "gyro_noise_std": (0.0, 1.0, "rad/s"),
    "accel_noise_std": (0.0, 5.0, "m/s^2"),
}
RANDOMIZE_DEFAULTS = {"link_mass_scale": 1.0, "torso_com_offset_x_m": 0.0, "floor_friction": None,
                      "servo_kp_scale": 1.0, "gyro_noise_std": 0.0, "accel_noise_std": 0.0}
# [randomize] ensemble = "PATH": one member of an ensemble of robots per push (`EnsembleRef`);
# recorded per record in ROBOT_ID_COLUMN. Not a RANDOMIZE_FIELDS entry: tune specs take it apart
# (tkujax.studies.tune.tune_spec), with another meaning of the column (a row of the tune's robot
# table).
ENSEMBLE_KEY = "ensemble"
ROBOT_ID_COLUMN = "robot_id"
SWEEP_FIELDS = {"name": str, "seed": int, "chunk_size": int, "duration_s": (int, float),
                "control": list, "description": str, "tree_passes": str, "decisions": str,
                "lanes": int, "segment_ticks": int, **FLOOR_FIELDS}


@dataclasses.dataclass(frozen=True)
class EnsembleRef:
    """[randomize] ensemble: the file as the spec gives it, its absolute path, the sha256 of its
    content and its members' ModelParams. Equal (and hashed) by content: the cache key of the
    ensemble's compiled robots."""

    path: str = dataclasses.field(compare=False)
    resolved: str = dataclasses.field(compare=False)
    sha256: str
    members: tuple[ModelParams, ...] = dataclasses.field(compare=False, repr=False)
    default_member: int = dataclasses.field(compare=False, default=0)

    @property
    def n(self) -> int:
        return len(self.members)

    def describe(self) -> dict:
        """The manifest's record of the ensemble."""
        return dict(path=self.path, resolved=self.resolved, sha256=self.sha256, n=self.n,
                    default_member=self.default_member)


def parse_ensemble(value, key: str = f"randomize.{ENSEMBLE_KEY}") -> EnsembleRef:
    """randomize.ensemble (or another spec key naming an ensemble file, `key`: tune specs also
    take evaluate.shift.ensemble): read and validate the file (`load_ensemble`); SpecError names
    the key and the file's problem."""
    if not isinstance(value, str) or not value.strip():
        raise SpecError(f"{key}: expected the path of an ensemble file (a string, relative to "
                        f"the current directory or absolute), got {value!r}")
    path = Path(value).expanduser()
    try:
        ens = load_ensemble(path)
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
    except (ValueError, OSError) as err:
        raise SpecError(f"{key}: {err}") from None
    return EnsembleRef(path=value, resolved=str(path.resolve()), sha256=digest,
                       members=ens.members, default_member=ens.default_member)


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """A validated spec. `raw` is the parsed TOML (recorded in the manifest)."""

    name: str
    seed: int
    chunk_size: int
    duration_s: float
    control: tuple[str, ...]
    push_grid: dict[str, np.ndarray]
    push_random: dict[str, tuple[float, float]]
    n_random: int
    controller: dict[str, float]
    controller_grid: dict[str, np.ndarray]
    randomize: dict[str, Any]
    raw: dict
    phase_default: bool = False   # [push.random] draws onset_phase uniformly by default
    step_grid: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    step_reference: bool = True
    arithmetic: str = "float"
    fpga: dict[str, Any] = dataclasses.field(default_factory=dict)
    fpga_grid: dict[str, np.ndarray] = dataclasses.field(default_factory=dict)
    ensemble: EnsembleRef | None = None   # [randomize] ensemble
    tree_passes: str = SWEEP_TREE_PASSES[0]   # [sweep] tree_passes (SWEEP_TREE_PASSES)
    robot_file: str | None = None   # [robot] file: a robot file (tkujax.robot), absolute
    decisions: Decisions = Decisions()   # [sweep] decisions, lanes, segment_ticks
    walk: WalkSpec | None = None   # [walk]: the robot walks (tkujax.dialects.walk_table)
    sequence: SequenceSpec | None = None   # [push.sequence] (tkujax.dialects.sequence_table)
    push_kind: str = "impulse"   # [push] kind (tkujax.dialects.kick_table)
    floor_pitch_deg: float = 0.0   # [sweep] floor_pitch_deg: a slope (floor_table)
    floor_roll_deg: float = 0.0    # [sweep] floor_roll_deg: a sideways slope

    def fixed_point_config(self, rec: dict | None = None) -> FixedPointConfig | None:
        """The FixedPointConfig of a record (its fpga_* columns over [fpga]); None for float."""
        if self.arithmetic != "fixed":
            return None
        grid = {k: rec[FPGA_COLUMN + k] for k in self.fpga_grid} if rec is not None else {}
        return fixed_point_config(self.fpga | grid)

    def records(self) -> dict[str, np.ndarray]:
        """Expand into one record per push (columns of equal length, deterministic order)."""
        return expand(self)


def controller_value(where: str, key: str, value) -> float:
    """A spec-style ControllerParams value (key a field, or FIELD_deg in degrees), in the range
    ControllerParams.validate allows; SpecError names `where` and the range."""
    try:
        return checked_value(where, key, value)
    except ValueError as err:
        raise SpecError(str(err)) from err


def controller_values(where: str, key: str, value) -> np.ndarray:
    """A list, a scalar or a {start, stop, num, endpoint} range of a controller key (as
    `validation.values`), every value checked by `controller_value`."""
    if isinstance(value, dict):
        for end in ("start", "stop"):
            if end in value:
                controller_value(f"{where}.{end}", key, value[end])
    elif isinstance(value, list):
        for i, v in enumerate(value):
            controller_value(f"{where}[{i}]", key, v)
    else:
        controller_value(where, key, value)
    return values(where, value, -math.inf, math.inf)


def _phase_values(key: str, value) -> np.ndarray:
    """Grid phases: in [0, 1) (a range may use stop = 1 with endpoint = false)."""
    try:
        vals = values(key, value, 0.0, 1.0, PHASE_UNIT)
    except SpecError as err:   # the range is half-open: say so
        raise SpecError(str(err).replace("[0.0, 1.0]", "[0, 1)")) from None
    if (vals >= 1.0).any():
        raise SpecError(f"{key}: {float(vals.max())!r} is out of range [0, 1) {PHASE_UNIT}")
    return vals


def _random_phase(key: str, value, unit: str) -> tuple[float, float]:
    """push.random.KEY = {uniform = [lo, hi]} of a phase: draws in [lo, hi), lo < 1."""
    try:
        lo, hi = uniform(f"push.random.{key}", value, 0.0, 1.0, unit)
    except SpecError as err:
        raise SpecError(str(err).replace("[0.0, 1.0]", "[0, 1)")) from None
    if lo >= 1.0:   # draws are in [lo, hi): hi = 1 is fine, lo = 1 would give phase 1
        raise SpecError(f"push.random.{key}.uniform[0]: {lo!r} is out of range [0, 1) {unit}")
    return lo, hi


def parse_randomize(data: dict) -> dict[str, Any]:
    """The validated [randomize] table: {key: (lo, hi) for uniform draws, or a fixed value}."""
    rand = table("randomize", data.get("randomize", {}), RANDOMIZE_FIELDS)
    randomize = {}
    for k, v in rand.items():
        lo, hi, unit = RANDOMIZE_FIELDS[k]
        randomize[k] = (uniform(f"randomize.{k}", v, lo, hi, unit) if isinstance(v, dict)
                        else number(f"randomize.{k}", v, lo, hi, unit))
    return randomize


def _parse_sweep(data: dict) -> dict:
    """The checked [sweep] table (with chunk_size, duration_s, control and seed filled in;
    a walking sweep's control defaults to ["on"]: the walking recovery needs the controller)."""
    sweep = dict(table("sweep", data.get("sweep", {}), SWEEP_FIELDS))
    if "walk" in data:
        sweep.setdefault("control", ["on"])
    for k, types in SWEEP_FIELDS.items():
        if k in sweep and (isinstance(sweep[k], bool) or not isinstance(sweep[k], types)):
            raise SpecError(f"sweep.{k}: expected {getattr(types, '__name__', 'a number')}, "
                            f"got {sweep[k]!r}")
    chunk = sweep.setdefault("chunk_size", 1024)
    if not 1 <= chunk <= MAX_CHUNK_SIZE:
        raise SpecError(f"sweep.chunk_size: {chunk} is out of range [1, {MAX_CHUNK_SIZE}]")
    seed = sweep.setdefault("seed", 0)
    if not 0 <= seed <= MAX_SEED:
        raise SpecError(f"sweep.seed: {seed} is out of range [0, {MAX_SEED}] (JAX's PRNGKey "
                        "keeps 32 bits)")
    sweep["duration_s"] = number("sweep.duration_s", sweep.get("duration_s", 2.4), 0.1, 30.0,
                                 "s")
    sweep |= parse_floor(sweep)
    control = sweep.setdefault("control", ["off", "on"])
    if (not control or any(not isinstance(c, str) or c not in ("on", "off") for c in control)
            or len(set(control)) != len(control)):
        raise SpecError(f"sweep.control: expected a list of distinct 'on'/'off', "
                        f"got {list(control)!r}")
    return sweep


def parse_spec(data: dict) -> SweepSpec:
    """Validate a parsed TOML document."""
    table("top level", data, {"sweep", "push", "controller", "randomize", "step", "fpga",
                              "robot", "walk"})
    sweep = _parse_sweep(data)
    robot_file = _robot_file(data)
    walk = parse_walk(data)
    if walk is not None:
        walk = resolve_walk(walk, *gait_of(robot_file))
    chunk, duration, control = sweep["chunk_size"], sweep["duration_s"], tuple(sweep["control"])
    tree_passes = tree_passes_of(sweep)

    push = table("push", data.get("push", {}), {"grid", "random", "sequence", "kind"})
    kind = push_kind(push)
    push = kick_push_table(push)   # a kick sweep's tables in the impulse spec's terms
    sequence = parse_sequence(push)
    phase_keys = {PHASE_KEY, GAIT_PHASE_KEY}
    grid = table("push.grid", push.get("grid", {}), set(PUSH_FIELDS) | phase_keys)
    check_gait_phase_keys("grid", grid, walk, PHASE_KEY)
    push_grid = {k: (_phase_values(f"push.grid.{k}", v) if k == PHASE_KEY else
                     gait_phase_values(f"push.grid.{k}", v, values) if k == GAIT_PHASE_KEY else
                     values(f"push.grid.{k}", v, *PUSH_FIELDS[k][:2], PUSH_FIELDS[k][3]))
                 for k, v in grid.items()}
    rnd = table("push.random", push.get("random", {}), set(PUSH_FIELDS) | phase_keys | {"n"})
    check_gait_phase_keys("random", rnd, walk, PHASE_KEY)
    n_random = rnd.get("n", 0)
    if (isinstance(n_random, bool) or not isinstance(n_random, int)
            or not 0 <= n_random <= 10_000_000):
        raise SpecError(f"push.random.n: expected an integer in [0, 10000000], got {n_random!r}")
    push_random = {k: uniform(f"push.random.{k}", v, *PUSH_FIELDS[k][:2], PUSH_FIELDS[k][3])
                   for k, v in rnd.items() if k not in ("n", PHASE_KEY, GAIT_PHASE_KEY)}
    for key, unit in ((PHASE_KEY, PHASE_UNIT), (GAIT_PHASE_KEY, GAIT_PHASE_UNIT)):
        if key in rnd:
            push_random[key] = _random_phase(key, rnd[key], unit)
    # Random pushes without an onset of their own sample the whole control period.
    phase_default = n_random > 0 and not ({"onset_s"} | phase_keys) & set(rnd)
    if phase_default:
        push_random[PHASE_KEY] = (0.0, 1.0)
    if not push_grid and n_random == 0:
        raise SpecError("[push]: give a [push.grid] or [push.random] with n > 0: nothing to run")
    check_sequence(sequence, np.concatenate([push_grid.get("duration_s", [PUSH_FIELDS[
        "duration_s"][2]]), push_random.get("duration_s", [PUSH_FIELDS["duration_s"][2]])]))

    ctrl = table("controller", data.get("controller", {}),
                  set(CONTROLLER_FIELDS) | {"grid", "arithmetic"})
    controller = {k: controller_value(f"controller.{k}", k, v)
                  for k, v in ctrl.items() if k not in ("grid", "arithmetic")}
    cgrid = dict(table("controller.grid", ctrl.get("grid", {}),
                        set(CONTROLLER_FIELDS) | {"fpga"}))
    arithmetic, fpga, fpga_grid = parse_fpga(data, ctrl, cgrid.pop("fpga", {}))
    controller_grid = {k: controller_values(f"controller.grid.{k}", k, v)
                       for k, v in cgrid.items()}
    both = sorted(set(controller) & set(controller_grid))
    if both:
        raise SpecError(f"controller: {both} set both as fixed values and in [controller.grid]")

    rand = table("randomize", data.get("randomize", {}), set(RANDOMIZE_FIELDS) | {ENSEMBLE_KEY})
    ensemble = parse_ensemble(rand[ENSEMBLE_KEY]) if ENSEMBLE_KEY in rand else None
    randomize = parse_randomize({"randomize": {k: v for k, v in rand.items()
                                               if k != ENSEMBLE_KEY}})
    step_grid, step_reference = parse_step(data)
    if arithmetic == "fixed" and step_grid:
        raise SpecError("[step]: commanded steps have no fixed-point controller twin; "
                        "use controller.arithmetic = \"float\"")
    if arithmetic == "fixed":
        check_fixed_controller(controller, controller_grid)
    spec = check_limits(SweepSpec(name=sweep.get("name", "sweep"), seed=sweep["seed"],
                     chunk_size=chunk, duration_s=duration, control=control,
                     push_grid=push_grid, push_random=push_random, n_random=n_random,
                     controller=controller, controller_grid=controller_grid,
                     randomize=randomize, raw=data, phase_default=phase_default,
                     step_grid=step_grid,
                     step_reference=step_reference, arithmetic=arithmetic, fpga=fpga,
                     fpga_grid=fpga_grid, ensemble=ensemble, tree_passes=tree_passes,
                     robot_file=robot_file, decisions=decisions_of(sweep, chunk), walk=walk,
                     sequence=sequence, push_kind=kind,
                     floor_pitch_deg=sweep["floor_pitch_deg"],
                     floor_roll_deg=sweep["floor_roll_deg"]))
    check_walk_sweep(spec)
    return spec


def _robot_file(data: dict) -> str | None:
    """[robot] file = "PATH" (from the current directory): the robot file (docs/robots.md)."""
    path = table("robot", data.get("robot", {}), {"file"}).get("file")
    if path is not None and not (isinstance(path, str) and Path(path).is_file()):
        raise SpecError(f"robot.file: expected the path of a robot file, got {path!r}")
    return None if path is None else str(Path(path).resolve())


def load_spec(path: str | Path) -> SweepSpec:
    return parse_spec(read_toml(path))


def _onsets(spec: SweepSpec, pushes: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The pushes with their onsets: from the gait phase (a walking sweep), from the phase in
    the control period, on the controller's ticks (velocity kicks); the phase columns of the
    onsets given in seconds."""
    if spec.walk is not None:   # onsets by gait phase: the walk's nominal time of the phase
        gait = np.isfinite(pushes[GAIT_PHASE_KEY])
        pushes["onset_s"] = np.where(gait, onsets_at_phase(
            spec.walk, np.where(gait, pushes[GAIT_PHASE_KEY], 0.0)), pushes["onset_s"])
    given = np.isfinite(pushes[PHASE_KEY])
    pushes["onset_s"] = np.where(given, onset_from_phase(pushes["onset_s"],
                                                         np.where(given, pushes[PHASE_KEY], 0.0)),
                                 pushes["onset_s"])
    pushes[PHASE_KEY] = np.where(given, pushes[PHASE_KEY], onset_phase(pushes["onset_s"]))
    if spec.push_kind == "velocity_kick":   # kicks act on the controller's ticks
        pushes["onset_s"] = on_ticks(pushes["onset_s"])
        pushes[PHASE_KEY] = onset_phase(pushes["onset_s"])
        if GAIT_PHASE_KEY in pushes:        # the gait phase of the tick (`cross_walk`)
            pushes[GAIT_PHASE_KEY] = np.full(len(pushes["onset_s"]), np.nan)
    return pushes


def expand(spec: SweepSpec) -> dict[str, np.ndarray]:
    """One record per (push, controller-grid point, control setting), as columns.

    `from_grid` marks grid pushes (True) and random samples (False).
    Order: control setting (outermost), controller grid, grid pushes then random pushes.
    Randomisation columns are drawn once per push from the spec's seed and shared by all of
    its control settings and controller-grid points, so that control off and on (or two grid
    points) of one push run on the same robot: comparisons are paired. With [randomize]
    ensemble, the member (robot_id, uniform in [0, n)) is drawn last, the same way.
    """
    rng = np.random.default_rng(spec.seed)
    defaults = {k: v[2] for k, v in PUSH_FIELDS.items()}
    # Grid pushes: Cartesian product over the given fields (others at their defaults); the phase
    # is crossed last, so the order of specs without it is unchanged. NaN: no phase given.
    # A walking sweep's gait phase is crossed after them all (NaN: the onset is given).
    fields = list(PUSH_FIELDS) + [PHASE_KEY] + ([GAIT_PHASE_KEY] if spec.walk else [])
    cols = {k: np.array([defaults[k]]) for k in PUSH_FIELDS} | {
        k: np.array([np.nan]) for k in fields[len(PUSH_FIELDS):]}
    grid_cols = {}
    if spec.push_grid:
        cols.update(spec.push_grid)
        mesh = np.meshgrid(*[cols[k] for k in fields], indexing="ij")
        grid_cols = {k: m.ravel() for k, m in zip(fields, mesh)}
    n_grid = len(next(iter(grid_cols.values()))) if grid_cols else 0
    rand_cols = {}
    for k in PUSH_FIELDS:
        if k in spec.push_random:
            lo, hi = spec.push_random[k]
            rand_cols[k] = rng.uniform(lo, hi, spec.n_random)
        else:
            rand_cols[k] = np.full(spec.n_random, defaults[k])
    # Drawn after the other fields: their values do not depend on whether a phase is drawn.
    for k in fields[len(PUSH_FIELDS):]:   # the onset phase, then the gait phase
        rand_cols[k] = (rng.uniform(*spec.push_random[k], spec.n_random)
                        if k in spec.push_random else np.full(spec.n_random, np.nan))
    pushes = _onsets(spec, {k: np.concatenate([grid_cols.get(k, np.zeros(0)), rand_cols[k]])
                            for k in fields})
    n_push = n_grid + spec.n_random

    # [fpga] grid points are crossed like controller-grid points (one column fpga_<key> each).
    cgrid = spec.controller_grid | {FPGA_COLUMN + k: v for k, v in spec.fpga_grid.items()}
    combos = list(itertools.product(*cgrid.values())) if cgrid else [()]
    is_grid = np.arange(n_push) < n_grid
    records: dict[str, list] = {k: [] for k in fields}
    records["control"] = []
    records["from_grid"] = []
    for k in cgrid:
        records[k] = []
    for control in spec.control:
        for combo in combos:
            for k in fields:
                records[k].append(pushes[k])
            records["control"].append(np.full(n_push, control == "on"))
            records["from_grid"].append(is_grid)
            for k, v in zip(cgrid, combo):
                records[k].append(np.full(n_push, v))
    out = {k: np.concatenate(v) for k, v in records.items()}
    n_settings = len(spec.control) * len(combos)
    for k, v in spec.randomize.items():
        draw = rng.uniform(*v, n_push) if isinstance(v, tuple) else np.full(n_push, v)
        out[k] = np.tile(draw, n_settings)
    if spec.ensemble is not None:   # drawn after the others: their values do not change
        out[ROBOT_ID_COLUMN] = np.tile(rng.integers(0, spec.ensemble.n, n_push), n_settings)
    # The later pulses of a [push.sequence] last: the other columns keep their values.
    kick = spec.push_kind == "velocity_kick"
    out |= draw_sequence(spec.sequence, rng, pushes, n_settings, on_ticks if kick else None)
    out = cross_walk(spec.walk, cross_steps(spec, out))
    if kick:
        out = kick_columns(out)
    out |= floor_columns(spec, len(out["control"]))   # a slope: compare checks it
    out["push_id"] = np.arange(len(out["control"]))
    return out
