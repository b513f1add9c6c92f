"""Tuning on a robot file: `[robot] file` in a tune spec, or `tkujax tune --robot FILE`.

`on_robot(spec, robot)` applies a robot once: its Robot (tkujax.studies.robot_inputs.tune_robot
loads it) becomes the problem's model, and the start is the robot's scaled controller defaults
(`controller_params_for`) with the spec's [controller] applied. Refused, each a SpecError
naming the key: a --robot other than the spec's [robot] file, [model] overrides, robot
ensembles, float64, tune.start_policy, and a start outside tune.ranges (the ranges are the
spec's, in SI units: give ranges that fit the robot).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from tkujax.control.params_files import controller_params_from
from tkujax.model import ModelParams
from tkujax.studies.tune.reparam import check_start
from tkujax.dialects.validation import SpecError, robot_file_of


def _same_file(a: str, b: str) -> bool:
    return Path(a).resolve() == Path(b).resolve()


def on_robot(spec, robot=None) -> object:
    """`spec` on `robot` (a Robot: `tkujax.studies.robot_inputs.tune_robot` loads the
    spec's [robot] file or --robot's; None or the built-in Robot: TKU-X, refused when the spec
    names a robot file)."""
    own = robot_file_of(spec.raw)
    if robot is not None and robot.builtin:       # TKU-X: the spec's own model ([model])
        if robot.model_params != ModelParams():
            raise SpecError("robot: the built-in TKU-X with other model parameters; give them "
                            "in the spec's [model] table")
        robot = None
    if robot is None:
        if own is not None:
            raise SpecError(f"robot.file: the spec names {own}: give its Robot "
                            "(tkujax.studies.robot_inputs.tune_robot loads it)")
        return spec
    if own is not None and not _same_file(robot.source, own):
        raise SpecError(f"robot.file: the spec names {own}, --robot gives {robot.source}")
    if spec.model:
        raise SpecError("[model]: a robot file gives the model; remove [model] or the robot")
    if spec.robot_table:
        raise SpecError("randomize.ensemble: robot ensembles are of TKU-X's model; remove the "
                        "ensemble to tune on a robot file")
    if spec.float64:
        raise SpecError("tune.float64: a robot file's model runs in float32; set it false")
    if spec.start_policy is not None:
        raise SpecError("tune.start_policy: a policy file is TKU-X's controller; remove it to "
                        "tune on a robot file (the start is the robot's scaled defaults)")
    # The scaled defaults, not the robot file's controller: a tune starts from the robot.
    base = robot.defaults if robot.defaults is not None else robot.params
    start = controller_params_from(base, spec.controller).validate()
    spec = dataclasses.replace(spec, robot=robot, start=start)
    check_start(spec)
    return spec


def robot_record(spec) -> dict | None:
    """The robot file's name, path and sha256 for the tune's outputs (None: TKU-X)."""
    robot = spec.robot
    if robot is None or robot.builtin:
        return None
    return robot.record()
