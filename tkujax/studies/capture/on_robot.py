"""Capture regions on a robot file: the checks `run_capture` makes before the [step] sweep.

The commanded step (tkujax.control.StepOverride) is in the controller's own frame: the swing
ankle's displacement from its stand place. On a robot file the controller's parameters are the
robot's (`tkujax.robot.geometry.controller_params_for` its measured legs), its analytic leg IK
gives TKU-X-convention joint targets and the robot's leg map (`tkujax.robot.robot_setup`) turns
them into its actuators' targets, so the override needs nothing robot-specific. What differs is
the geometry: the theory (LIP mass, CoM height, soles, ankles) and the leg reach l_max come from
the robot (`tkujax.studies.robot_inputs.capture_feet`), and the targets must lie within that reach.
"""

from __future__ import annotations

import dataclasses
import itertools

import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.sim.robot import Robot, as_robot
from tkujax.analysis.capturability import step_reach_m
from tkujax.dialects.sweep_spec import STEP_FIELDS, SweepSpec
from tkujax.dialects.validation import SpecError


def _grid(spec: SweepSpec, key: str) -> np.ndarray:
    return np.asarray(spec.step_grid.get(key, [STEP_FIELDS[key][2]]), float)


def check_targets(spec: SweepSpec, reach_m: float, name: str) -> None:
    """SpecError naming the keys and the allowed range when a commanded step (x_m, y_m; with
    steps = 2 also the second foot's (x2_m - x_m, y2_m - y_m) from its stand place) lies
    beyond the leg reach l_max."""
    two = (_grid(spec, "steps") > 1.5).any()
    for x, y in itertools.product(_grid(spec, "x_m"), _grid(spec, "y_m")):
        if np.hypot(x, y) > reach_m + 1e-9:
            raise SpecError(
                f"step.grid.x_m, step.grid.y_m: the target ({x:g}, {y:g}) m lies "
                f"{np.hypot(x, y):.3f} m from the swing foot's stand place, beyond {name}'s leg "
                f"reach l_max = {reach_m:.3f} m: keep sqrt(x_m^2 + y_m^2) <= {reach_m:.3f} m "
                f"(x_m, y_m in [{-reach_m:.3f}, {reach_m:.3f}] m)")
        if not two:
            continue
        for x2, y2 in itertools.product(_grid(spec, "x2_m"), _grid(spec, "y2_m")):
            d = np.hypot(x2 - x, y2 - y)
            if d > reach_m + 1e-9:
                raise SpecError(
                    f"step.grid.x2_m, step.grid.y2_m: the second step ({x2:g}, {y2:g}) m after "
                    f"({x:g}, {y:g}) m lands {d:.3f} m from its foot's stand place, beyond "
                    f"{name}'s leg reach l_max = {reach_m:.3f} m: keep "
                    f"sqrt((x2_m - x_m)^2 + (y2_m - y_m)^2) <= {reach_m:.3f} m")


def capture_robot_value(robot) -> Robot | None:
    """`robot` as a Robot (`as_robot`; None stays None: TKU-X); SpecError for anything else."""
    if robot is None:
        return None
    try:
        return as_robot(robot)
    except TypeError as err:
        raise SpecError(f"--robot: {err} (tkujax.studies.robot_inputs.capture_robot loads a "
                        "robot file and its capture geometry)") from None


def check_capture_robot(spec: SweepSpec, robot, feet, params: ControllerParams):
    """The robot's capture geometry `feet` with the reach of `params` (its controller with the
    spec's [controller] applied), None for TKU-X, after refusing what capture regions on a
    robot cannot use: a robot without its geometry or
    geometry without a robot, a spec naming another robot file, targets beyond the reach
    (`check_targets`)."""
    if robot is None:
        if spec.robot_file is not None:
            raise SpecError(f"robot.file: the spec runs on {spec.robot_file}: give its "
                            "Robot and capture geometry (robot=, feet=: "
                            "tkujax.studies.robot_inputs.capture_robot loads both), or run `tkujax "
                            "capture`")
        if feet is not None:
            raise SpecError("feet: a robot's capture geometry was given without its robot "
                            "(robot=, a Robot)")
        return None
    if feet is None:
        raise SpecError(f"--robot: capture regions on {robot.name} need its capture geometry "
                        "(feet=, tkujax.studies.robot_inputs.capture_feet)")
    if spec.robot_file is not None and spec.robot_file != robot.source:
        raise SpecError(f"robot.file: the spec names {spec.robot_file}, --robot gives "
                        f"{robot.source}")
    feet = dataclasses.replace(feet, reach_m=step_reach_m(params))
    check_targets(spec, feet.reach_m, robot.name)
    return feet
