"""The robot's controller: the one its robot file names, else a conservative default.

`controller = "op3_controller.json"` in a robot file (relative to it) names a parameter file
(`tkujax.control.params_files`) or a scheduled policy file (`save_policy_json`, as
`tkujax tune --robot` writes when its policy method wins); sweeps, maps, capture and compare
use it (capture and walking the policy's scalars), `--params` overrides it, and control off
stays available. A robot without one gets `conservative_controller`: the paper's
controller at the robot's scaled defaults with its steps switched off, half the recommended
controller's stance feedback (ankle and hip on pitch, ankle on roll) and its accelerometer
gate. Steps at scaled defaults doubled OP3's falls; stance feedback alone moves no foot. At the
recommended gains it harmed Booster T1 pushed from behind at 8.6-15.8 N s (59 falls against 54
with control off, MuJoCo C); at half of them it saved 9 of those 54 and harmed none, and on
every direction it lowered T1's falls from 53 to 45 and TKU-X's from 79 to 75 of 160, and left
OP3's unchanged (`STANCE_SCALE`). `tests/test_robot_controller.py` checks that it harms none
of TKU-X, OP3 and Booster T1 on push sets where control off falls.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from tkujax.control.params_files import (is_policy, load_controller_params_json,
                                         load_policy_json)
from tkujax.control.controller_params import RECOMMENDED, ControllerParams
from tkujax.robot.description import RobotDescription
from tkujax.robot.file_checks import RobotFileError

NO_STEP_THRESHOLD_RAD = math.pi / 2 - 1e-6     # the lean thresholds no standing robot reaches
STANCE_SCALE = 0.5      # of the recommended stance gains (module doc)
STANCE_GAINS = ("stance_ankle_kp", "stance_ankle_kd", "stance_hip_kp", "stance_hip_kd",
                "stance_roll_kp", "stance_roll_kd")
CONSERVATIVE_SOURCE = ("conservative default (no tuned controller: stance feedback and the "
                       "accelerometer gate, no steps)")


def conservative_controller(scaled: ControllerParams) -> ControllerParams:
    """`scaled` (the robot's scaled defaults) without steps, with STANCE_SCALE of the
    recommended stance feedback and its accelerometer gate (module doc)."""
    return dataclasses.replace(
        scaled, eps_forward=NO_STEP_THRESHOLD_RAD, eps_backward=NO_STEP_THRESHOLD_RAD,
        cp_trigger=0.0, lateral_steps=0.0, max_steps=1.0, **conservative_stance()).validate()


def conservative_stance() -> dict:
    """STANCE_SCALE of the recommended stance gains and its accelerometer gate."""
    return {k: STANCE_SCALE * RECOMMENDED[k] for k in STANCE_GAINS} | {
        "accel_gate": RECOMMENDED["accel_gate"]}


def robot_controller(desc: RobotDescription,
                     scaled: ControllerParams) -> tuple[ControllerParams, object, str]:
    """(the robot's controller, its Schedule or None, where it came from): the parameter or
    policy file its robot file names, else the conservative default."""
    if desc.controller_path is None:
        return conservative_controller(scaled), None, CONSERVATIVE_SOURCE
    params, schedule = controller_file(desc.controller_path, "controller", policy=True)
    return params, schedule, f"file {desc.controller_path.name}"


def walking_controller(desc: RobotDescription, standing: ControllerParams,
                       source: str) -> tuple[ControllerParams, str]:
    """(the controller while walking, where it came from): the file `walk_controller` names,
    else the standing one (`standing`, from `source`). A standing controller tuned for pushes
    can be wrong for a gait: OP3's tuned stance gains (ankle kp 2.5) fell walking at 0.2 m/s
    and backward, where its earlier controller's (0.34) walk (docs/robots.md)."""
    if desc.walk_controller_path is None:
        return standing, source
    return controller_file(desc.walk_controller_path, "walk_controller")[0], \
        f"file {desc.walk_controller_path.name}"


def controller_file(path: Path, key: str, policy: bool = False) -> tuple[ControllerParams, object]:
    """(parameters, Schedule or None) of the file a robot file's `key` names: a parameter file,
    or with `policy` also a scheduled policy file (`save_policy_json`; the gait runs no
    schedule, so `walk_controller` names a parameter file). RobotFileError names the key when
    the file cannot be read."""
    import json
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RobotFileError(f"{key}: {path} is not a readable JSON "
                             f"parameter file: {err}") from err
    if is_policy(data) and not policy:
        raise RobotFileError(f"{key}: {path} is a scheduled policy, which the gait does not "
                             "run; name a parameter file")
    try:
        if is_policy(data):
            return load_policy_json(path)
        return load_controller_params_json(path), None
    except ValueError as err:
        raise RobotFileError(f"{key}: {err}") from err
