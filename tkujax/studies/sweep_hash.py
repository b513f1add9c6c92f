"""The spec hash of a sweep: what makes two runs the same sweep (a rerun resumes only then).

The spec, the controller and model parameters (through the record schema,
`tkujax.studies.record_schema`: a field added since the first sweeps enters only when set), the
fixed-point defaults, and the rule changes that give a spec other records.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math

from tkujax.control.fixed import FixedPointConfig
from tkujax.control.params import ControllerParams
from tkujax.control.policy import Schedule, schedule_to_dict
from tkujax.model import ModelParams
from tkujax.sim.setup import RobotSetup
from tkujax.studies.record_schema import TREE_PASSES_BEFORE, hashed_fields
from tkujax.studies.spec import SweepSpec
from tkujax.studies.spec_program import hashed_raw


def shares_robot_draws(spec: SweepSpec) -> bool:
    """Whether the spec's records changed when one robot draw per push became shared by its
    settings: random [randomize] draws and more than one setting (control or grid point)."""
    n_settings = len(spec.control) * math.prod(
        len(v) for v in (spec.controller_grid | spec.fpga_grid).values())
    return any(isinstance(v, tuple) for v in spec.randomize.values()) and n_settings > 1


def spec_hash(spec: SweepSpec, params: ControllerParams, model_params: ModelParams,
              schedule: Schedule | None = None) -> str:
    """16 hex digits of sha256 over everything that fixes the sweep's records and outcomes
    (not the backend: a sweep may resume on another machine)."""
    # Fields added later enter the hash only when set, so older sweeps still resume. The model
    # enters in full otherwise: a changed default robot (e.g. the calibration) is another sweep.
    p = hashed_fields("controller_params", dataclasses.asdict(params))
    if isinstance(model_params, RobotSetup):   # a robot file: by its content and its model's
        m = {"robot sha256": model_params.digest}
    else:
        m = hashed_fields("model_params", dataclasses.asdict(model_params))
    parts = [hashed_raw(spec.raw), p, m]
    if spec.arithmetic == "fixed":   # the FixedPointConfig defaults fill every unset [fpga] key
        parts.append({"fixed_point_defaults": dataclasses.asdict(FixedPointConfig())})
    if spec.phase_default:   # random onsets changed meaning when the phase axis came in
        parts.append("push.random.onset_phase: uniform [0, 1) by default")
    if spec.ensemble is not None:   # the robots themselves, by the file's content
        parts.append({"randomize.ensemble sha256": spec.ensemble.sha256})
    if schedule is not None:        # a scheduled policy: its layout and numbers
        parts.append({"schedule": schedule_to_dict(schedule)})
    if spec.tree_passes != TREE_PASSES_BEFORE:   # another program: other rounding
        parts.append(f"tree passes: {spec.tree_passes}")
    if spec.decisions.early:   # another program, and readings up to each push's decision
        parts.append(spec.decisions.describe())
    if shares_robot_draws(spec):
        # The robot draws became shared by the settings of a push (records of older sweeps
        # differ): such a sweep is a new one.
        parts.append("randomize: one draw per push, shared by its control and grid settings")
    blob = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]
