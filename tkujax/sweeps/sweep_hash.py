"""The spec hash of a sweep: what makes two runs the same sweep (a rerun resumes only then).

The spec, the controller and model parameters (through the record schema,
`tkujax.sweeps.record_schema`: a field added since the first sweeps enters only when set), the
fixed-point defaults, and the rule changes that give a spec other records.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math

from tkujax.control.fixed import FixedPointConfig
from tkujax.control.controller_params import ControllerParams
from tkujax.control.policy import Schedule, schedule_to_dict
from tkujax.model import ModelParams
from tkujax.sim.robot import Robot, as_robot
from tkujax.robot.fall_geoms import FALL_TEST_RULE
from tkujax.sweeps.record_schema import TREE_PASSES_BEFORE, hashed_fields
from tkujax.dialects.sweep_spec import SweepSpec
from tkujax.dialects.program_keys import hashed_raw


def shares_robot_draws(spec: SweepSpec) -> bool:
    """Whether the spec's records changed when one robot draw per push became shared by its
    settings: random [randomize] draws and more than one setting (control or grid point)."""
    n_settings = len(spec.control) * math.prod(
        len(v) for v in (spec.controller_grid | spec.fpga_grid).values())
    return any(isinstance(v, tuple) for v in spec.randomize.values()) and n_settings > 1


# What each part of the sweep's identity is, as a refusal names it (`changed_inputs`).
INPUT_NAMES = {
    "spec": "the spec",
    "controller_params": "the controller parameters (--params)",
    "model": "the model (--model)",
    "robot": "the robot file (--robot or [robot] file; with its model, included files and "
             "meshes)",
    "fixed_point_defaults": "the fixed-point defaults (tkujax's FixedPointConfig)",
    "phase_default": "the rule for random onsets",
    "ensemble": "the ensemble file ([randomize] ensemble)",
    "schedule": "the scheduled policy (--params)",
    "tree_passes": "the tree passes",
    "decisions": "the decisions (--decisions or [sweep] decisions)",
    "fall_test": "the fall test's geoms (tkujax.robot.fall_geoms)",
    "shared_draws": "the rule for robot draws",
}


def hash_parts(spec: SweepSpec, params: ControllerParams, robot: Robot | ModelParams | None,
               schedule: Schedule | None = None) -> dict[str, object]:
    """{input name (INPUT_NAMES): what of it fixes the records}, in the spec hash's order:
    every input a record depends on, by content (files by their sha256). robot: the Robot, or
    TKU-X's ModelParams (`as_robot`)."""
    robot = as_robot(robot)
    # Fields added later enter the hash only when set, so older sweeps still resume. The model
    # enters in full otherwise: a changed default robot (e.g. the calibration) is another sweep.
    parts: dict[str, object] = {"spec": hashed_raw(spec.raw),
                                "controller_params": hashed_fields(
                                    "controller_params", dataclasses.asdict(params))}
    if robot.builtin:
        parts["model"] = hashed_fields("model_params", dataclasses.asdict(robot.model_params))
    else:   # a robot file: by its content and its model's, and the fall test's geoms
        parts["robot"] = {"robot sha256": robot.digest}
        parts["fall_test"] = FALL_TEST_RULE
    if spec.arithmetic == "fixed":   # the FixedPointConfig defaults fill every unset [fpga] key
        parts["fixed_point_defaults"] = {
            "fixed_point_defaults": dataclasses.asdict(FixedPointConfig())}
    if spec.phase_default:   # random onsets changed meaning when the phase axis came in
        parts["phase_default"] = "push.random.onset_phase: uniform [0, 1) by default"
    if spec.ensemble is not None:   # the robots themselves, by the file's content
        parts["ensemble"] = {"randomize.ensemble sha256": spec.ensemble.sha256}
    if schedule is not None:        # a scheduled policy: its layout and numbers
        parts["schedule"] = {"schedule": schedule_to_dict(schedule)}
    if spec.tree_passes != TREE_PASSES_BEFORE:   # another program: other rounding
        parts["tree_passes"] = f"tree passes: {spec.tree_passes}"
    if spec.decisions.early:   # another program, and readings up to each push's decision
        parts["decisions"] = spec.decisions.describe()
    if shares_robot_draws(spec):
        # The robot draws became shared by the settings of a push (records of older sweeps
        # differ): such a sweep is a new one.
        parts["shared_draws"] = ("randomize: one draw per push, shared by its control and grid "
                                 "settings")
    return parts


def _digest(value) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:16]


def spec_hash(spec: SweepSpec, params: ControllerParams, robot: Robot | ModelParams | None,
              schedule: Schedule | None = None) -> str:
    """16 hex digits of sha256 over everything that fixes the sweep's records and outcomes
    (not the backend: a sweep may resume on another machine)."""
    return _digest(list(hash_parts(spec, params, robot, schedule).values()))


def input_digests(spec: SweepSpec, params: ControllerParams,
                  robot: Robot | ModelParams | None,
                  schedule: Schedule | None = None) -> dict[str, str]:
    """{input name: 16 hex digits of its part}: the manifest's `inputs`, which lets a refusal
    name the input that changed (`changed_inputs`)."""
    return {k: _digest(v) for k, v in hash_parts(spec, params, robot, schedule).items()}


def changed_inputs(recorded: dict | None, now: dict[str, str]) -> list[str]:
    """The INPUT_NAMES descriptions of the inputs whose digests differ between a manifest's
    `inputs` (`recorded`; None or empty for a manifest before them: nothing named) and `now`."""
    if not recorded:
        return []
    keys = [k for k in INPUT_NAMES if k in recorded or k in now]
    keys += sorted((set(recorded) | set(now)) - set(INPUT_NAMES))
    return [INPUT_NAMES.get(k, k) for k in keys if recorded.get(k) != now.get(k)]
