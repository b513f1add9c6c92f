"""The sweep manifest's record schema: which parameter fields each schema version records.

A sweep's manifest.json records the ControllerParams, ModelParams and (fixed-point sweeps)
FixedPointConfig defaults it ran with. Fields come into these dataclasses over time, so an older
manifest lacks some. This module is the one place that says which fields each schema version
has and which value a field takes when a manifest predates it. Three things follow from it:

- the spec hash (`tkujax.sweeps.sweep_hash`): a field added after the first sweeps enters the
  hash only when it differs from its value-before, so a sweep that leaves it off keeps its hash
  and an older sweep still resumes;
- the replay (`tkujax.sweeps.replay`): a field the manifest lacks takes its value-before, the
  value that reproduces the code from before the field existed (not necessarily today's
  default), and the replay reports which fields it filled;
- new manifests record `SCHEMA_VERSION` ("schema_version") with every field.

Versions:
  1  manifests without "schema_version": tkujax wrote them while the fields of ADDED_FIELDS came
     in one by one, so a version-1 manifest records FIRST_FIELDS and any subset of the rest.
  2  "schema_version": 2; records every field of FIRST_FIELDS and ADDED_FIELDS.
  3  also records "tree_passes" (SweepSpec.tree_passes); a manifest before it ran MJX's passes
     (`manifest_spec`).
  4  also records "decisions" ("full" or "early"; SweepSpec.decisions, with "lanes" and
     "segment_ticks" when early); a manifest before it ran the full horizon. Early records
     carry a decided_s column.
  5  also records controller_params.cp_gain_lateral (the widening step; 1.0 before it).
  6  also records "runs" (every run's id, backend, devices, commit; earlier entries never
     rewritten), "inputs" (each input's digest, `tkujax.sweeps.sweep_hash.input_digests`) and
     in each chunk's entry the run_id, backend, device and git_commit that wrote it; the
     top-level backend, git_commit and devices are the first run's. Before it, the top level
     named the last run's backend for every chunk (`tkujax.sweeps.replay.record_backend`).
  7  also records controller_params.step_shift_m (the support shift of a step; 0.0 before it).

Adding a field to one of the three dataclasses: append an AddedField with `since` =
SCHEMA_VERSION + 1 and the value that reproduces the code without it, and bump SCHEMA_VERSION
(tests/test_records.py checks that the newest version names every field of today's classes).
"""

from __future__ import annotations

import dataclasses

from tkujax.control.fixed.config import FixedPointConfig
from tkujax.control.params_files import controller_params_from_dict
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.model.params_json import model_params_from_dict
from tkujax.dialects.sweep_spec import SweepSpec, parse_spec
from tkujax.dialects.program_keys import decisions_of

SCHEMA_VERSION = 7
UNVERSIONED = 1               # the version of a manifest that records none
SCHEMA_KEY = "schema_version"
# The sweep's passes over the body tree, recorded from version 3 on, and what ran before.
TREE_PASSES_KEY = "tree_passes"
TREE_PASSES_BEFORE = "mjx"
# How the sweep decided its pushes, recorded from version 4 on, and what ran before.
DECISIONS_KEY = "decisions"
DECISIONS_BEFORE = "full"

# The manifest keys of the parameter groups and the dataclass each records.
GROUPS: dict[str, type] = {"controller_params": ControllerParams, "model_params": ModelParams,
                           "fixed_point_defaults": FixedPointConfig}

# Fields every manifest records (schema version 1 on).
FIRST_FIELDS: dict[str, tuple[str, ...]] = {
    "controller_params": (
        "control_period", "step_period", "double_support_ratio", "lift_height", "eps_forward",
        "eps_backward", "standing_lean", "cp_angle_offset", "cp_gain", "gate_temperature",
        "lateral_steps", "eps_lateral", "gravity", "kalman_q", "kalman_r", "hip_offset_y",
        "hip_to_ankle_z", "thigh_length", "calf_length", "leg_length", "com_height"),
    "model_params": (
        "ankle_height_m", "calf_length_m", "thigh_length_m", "pelvis_height_m", "chest_height_m",
        "neck_height_m", "head_radius_m", "hip_offset_y_m", "torso_half_width_m",
        "torso_half_depth_m", "shoulder_offset_y_m", "upper_arm_length_m", "forearm_length_m",
        "foot_length_m", "foot_width_m", "foot_forward_offset_m", "total_mass_kg",
        "pelvis_mass_kg", "chest_mass_kg", "head_mass_kg", "arm_mass_kg", "leg_mass_kg",
        "leg_mass_fractions", "chest_com_frac", "stand_lean_deg", "stand_hip_to_ankle_m",
        "floor_friction", "timestep_s", "solver_iterations", "ls_iterations", "leg_servo",
        "arm_servo"),
    "fixed_point_defaults": (
        "angle", "rate", "length", "accel", "unit", "state", "cov", "coef_bits",
        "cordic_iterations", "cordic_guard_bits", "rounding", "latency_ticks", "latency_frac",
        "straight_through"),
}


@dataclasses.dataclass(frozen=True)
class AddedField:
    """A field that came in after the first sweeps.

    before: its value in a manifest that predates it (the code as it ran without the field).
    since: the first schema version whose every manifest records it."""

    group: str
    name: str
    before: object
    since: int


def _controller(name: str, before: float) -> AddedField:
    return AddedField("controller_params", name, before, since=2)


ADDED_FIELDS: tuple[AddedField, ...] = (
    # Detection and capture-point options; 0 is "off".
    _controller("cp_excess", 0.0),
    _controller("cp_update_window", 0.0),
    _controller("accel_gate", 0.0),
    # The recovery extensions: capture-point rate and look-ahead, the stepping trigger and its
    # thresholds, stance feedback, more than one step. Each value is its feature off (the
    # thresholds matter only with cp_trigger on; max_steps 1 is the single step).
    _controller("cp_rate_blend", 0.0),
    _controller("cp_lookahead_s", 0.0),
    _controller("cp_trigger", 0.0),
    _controller("cp_trigger_forward_m", 0.05),
    _controller("cp_trigger_backward_m", 0.1),
    _controller("cp_trigger_lateral_m", 0.09),
    _controller("stance_ankle_kp", 0.0),
    _controller("stance_ankle_kd", 0.0),
    _controller("stance_hip_kp", 0.0),
    _controller("stance_hip_kd", 0.0),
    _controller("stance_roll_kp", 0.0),
    _controller("stance_roll_kd", 0.0),
    _controller("stance_limit", 0.3),
    _controller("max_steps", 1.0),
    # The sideways step's gain (negative: the widening step); 1.0 is the step toward the
    # capture point that every controller took before it.
    AddedField("controller_params", "cp_gain_lateral", 1.0, since=5),
    AddedField("controller_params", "step_shift_m", 0.0, since=7),
    # The IMU low-pass filters: before them the controller read the instantaneous sample
    # (0 = no filter), not today's default cut-off.
    AddedField("model_params", "accel_lowpass_hz", 0.0, since=2),
    AddedField("model_params", "gyro_lowpass_hz", 0.0, since=2),
    # The inverse kinematics' guard bits. A replay runs today's default, 4, where the code
    # before them had the equivalent of 0: an older fixed-point record may replay differently
    # (the replay reports the field). The fixed-point defaults enter the spec hash in full.
    AddedField("fixed_point_defaults", "ik_guard_bits", 4, since=2),
)

# The groups whose added fields enter the spec hash only when set (differ from `before`).
HASHED_WHEN_SET = ("controller_params", "model_params")


def fields_of(version: int, group: str) -> tuple[str, ...]:
    """The fields of `group` that every manifest of schema `version` records."""
    return FIRST_FIELDS[group] + tuple(f.name for f in ADDED_FIELDS
                                       if f.group == group and f.since <= version)


def added_fields(group: str) -> dict[str, AddedField]:
    """{name: AddedField} of `group`."""
    return {f.name: f for f in ADDED_FIELDS if f.group == group}


def manifest_version(manifest: dict) -> int:
    """The manifest's schema version (UNVERSIONED when it records none)."""
    version = manifest.get(SCHEMA_KEY, UNVERSIONED)
    if isinstance(version, bool) or not isinstance(version, int) or not (
            UNVERSIONED <= version <= SCHEMA_VERSION):
        raise ValueError(f"manifest {SCHEMA_KEY} must be an integer in [{UNVERSIONED}, "
                         f"{SCHEMA_VERSION}] (a newer tkujax may have written it), got {version!r}")
    return version


def hashed_fields(group: str, values: dict) -> dict:
    """`values` ({field: value} of a parameter group) without the added fields left at their
    value-before: what the spec hash sees, so a sweep that leaves a new field off keeps the
    hash it had before the field existed."""
    if group not in HASHED_WHEN_SET:
        return dict(values)
    added = added_fields(group)
    return {k: v for k, v in values.items() if not (k in added and v == added[k].before)}


def filled_fields(manifest: dict, group: str) -> dict[str, object]:
    """{field: value-before} of the added fields that the manifest's `group` lacks (none when
    the manifest records no such group). A manifest of schema version 2 on that lacks a field
    its version records is damaged: ValueError names the field."""
    recorded = manifest.get(group)
    if recorded is None:
        return {}
    version = manifest_version(manifest)
    lacking = [name for name in fields_of(version, group) if name not in recorded]
    if lacking and version > UNVERSIONED:
        raise ValueError(f"manifest {group} lacks {lacking}, which schema version {version} "
                         "records")
    return {name: f.before for name, f in added_fields(group).items() if name not in recorded}


def fields_missing(manifest: dict) -> dict[str, object]:
    """{"GROUP.FIELD": the value a replay uses} for every field of today's ControllerParams,
    ModelParams and (a fixed-point sweep) FixedPointConfig that the manifest does not record:
    an older tkujax wrote it, and a different outcome may be the code's change since, not a
    fault of the record. An added field takes its value-before, any other today's default.
    A manifest without a model (None, {}: the default robot) or with a robot file's reports
    none of the model's."""
    missing = {}
    for group, cls in GROUPS.items():
        recorded = manifest.get(group)
        if recorded is None or (group == "model_params" and (not recorded
                                                              or "robot_sha256" in recorded)):
            continue                     # the default robot, or a robot file's (its sha256)
        before = filled_fields(manifest, group)
        default = cls()
        missing |= {f"{group}.{f.name}": before.get(f.name, getattr(default, f.name))
                    for f in dataclasses.fields(cls) if f.name not in recorded}
    return missing


def manifest_model_params(manifest: dict) -> ModelParams | None:
    """The sweep's ModelParams from its manifest (None when it records none: the default
    robot), validated by the model's JSON loader; an added field the manifest lacks takes its
    value-before."""
    recorded = manifest.get("model_params")
    if not recorded:
        return None
    filled = dict(recorded, **filled_fields(manifest, "model_params"))
    return model_params_from_dict(filled, "manifest model_params")


def manifest_controller_params(manifest: dict, where: str) -> ControllerParams:
    """The sweep's ControllerParams from its manifest, validated (ValueError names `where` and
    the key); an added field the manifest lacks takes its value-before."""
    recorded = manifest["controller_params"]
    filled = dict(recorded, **filled_fields(manifest, "controller_params"))
    return controller_params_from_dict(filled, where, base=ControllerParams())


def manifest_spec(manifest: dict) -> SweepSpec:
    """The manifest's SweepSpec, with the tree passes and the decisions the sweep ran
    (TREE_PASSES_BEFORE, DECISIONS_BEFORE for a manifest that predates the key, whatever
    today's default)."""
    spec = parse_spec(manifest["spec"])
    sweep = dict(manifest["spec"].get("sweep", {}))
    sweep.update({k: manifest[k] for k in ("lanes", "segment_ticks") if k in manifest})
    decisions = decisions_of(sweep, spec.chunk_size,
                             manifest.get(DECISIONS_KEY, DECISIONS_BEFORE))
    return dataclasses.replace(spec, tree_passes=manifest.get(TREE_PASSES_KEY,
                                                              TREE_PASSES_BEFORE),
                               decisions=decisions)
