"""Tuning on a robot file: `[robot] file` in a tune spec, or `tkujax tune --robot FILE`.

`on_robot(spec, robot)` applies a robot once: its Robot (tkujax.studies.robot_inputs.tune_robot
loads it) becomes the problem's model, and the start is the robot's scaled controller defaults
(`controller_params_for`) with the spec's [controller] applied. Refused, each a SpecError
naming the key: a --robot other than the spec's [robot] file, [model] overrides, robot
ensembles, float64, and a start outside tune.ranges (the ranges are the spec's, in SI units:
give ranges that fit the robot).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from typing import TYPE_CHECKING

from tkujax.control.io import controller_params_from
from tkujax.studies.tune.reparam import TUNABLE, user_factor
from tkujax.studies.validation import SpecError

if TYPE_CHECKING:
    from tkujax.studies.tune.spec import TuneSpec


def robot_file_of(data: dict) -> str | None:
    """The [robot] table's file (None without the table); SpecError names robot.file."""
    robot = data.get("robot")
    if robot is None:
        return None
    if not isinstance(robot, dict) or set(robot) != {"file"}:
        raise SpecError(f"[robot]: expected exactly one key, file = \"path/robot.toml\", got "
                        f"{robot!r}")
    if not isinstance(robot["file"], str) or not robot["file"]:
        raise SpecError(f"robot.file: expected a path to a robot file, got {robot['file']!r}")
    return robot["file"]


def check_start(spec: TuneSpec) -> None:
    """Start values must lie strictly inside the ranges (their latents are finite)."""
    for f, (a, b) in spec.reparam().user_ranges().items():
        v = float(getattr(spec.start, f)) / user_factor(f)
        if not a < v < b:
            raise SpecError(f"{TUNABLE[f][0]}: start value {v:g} (from [controller], the paper "
                            f"or the robot) must lie strictly inside tune.ranges ({a:g}, {b:g})")


def _same_file(a: str, b: str) -> bool:
    return Path(a).resolve() == Path(b).resolve()


def on_robot(spec: TuneSpec, robot=None) -> TuneSpec:
    """`spec` on `robot` (a Robot: `tkujax.studies.robot_inputs.tune_robot` loads the
    spec's [robot] file or --robot's; None: TKU-X, refused when the spec names a robot file)."""
    own = robot_file_of(spec.raw)
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
    # The scaled defaults, not the robot file's controller: a tune starts from the robot.
    base = robot.defaults if robot.defaults is not None else robot.params
    start = controller_params_from(base, spec.controller).validate()
    spec = dataclasses.replace(spec, robot=robot, start=start)
    check_start(spec)
    return spec


def robot_record(spec: TuneSpec) -> dict | None:
    """The robot file's name, path and sha256 for the tune's outputs (None: TKU-X)."""
    robot = spec.robot
    if robot is None or robot.builtin:
        return None
    return robot.record()
