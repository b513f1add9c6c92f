"""`tkujax tune --robot FILE --out DIR`: from a robot to its recovery controller, no spec.

Stages, each kept in DIR and skipped when done (rerun the command to resume):

1. `pushes.json`: the robot's push distributions (`tkujax.studies.robot_pushes`).
2. `tune/`: the recovery structure the evidence chose (`STRUCTURE`: the accelerometer gate,
   capture-point triggers, the widening sideways step, stance feedback, one step; on OP3 each
   of these lowered falls, a second step and a step toward the capture point sideways added
   them: docs/robots.md), started at the robot's scaled defaults with the conservative
   default's stance gains, tuned by CMA-ES (`tkujax.studies.tune`) over `TUNED` on the tuning
   pushes (seed `TUNE_SEED`) with the no-harm weight, for the budget's tuning share.
3. `heldout/`: a sweep of held-out pushes (seed `HELDOUT_SEED`, other onsets, longer
   rollouts), control off and on with the recommended set.
4. `compare/` and `verdict.json`: `tkujax compare` of the two; the controller passes when it
   falls less often than control off and no direction x impulse x phase cell with >= 100
   pushes falls more than 2 points more often. Then it is written next to the robot file
   (`<stem>_controller.json`) and named in it (`controller = ...`); otherwise the verdict says
   why it failed and the robot file is left as it was.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

from tkujax.robot.closed_loop import robot_setup
from tkujax.robot.own_controller import STANCE_GAINS, STANCE_SCALE
from tkujax.control.params import RECOMMENDED
from tkujax.studies.progress import StatusLog
from tkujax.studies.robot_pushes import robot_pushes
from tkujax.studies.robot_verdict import heldout_verdict, name_controller

TUNE_SEED, HELDOUT_SEED = 0, 11
TUNE_BATCH, TUNE_HORIZON_S, POPSIZE = 256, 1.5, 13
HELDOUT_HORIZON_S = 2.0
# The structure (module doc): flags and fixed values; the robot's geometry and scaled defaults
# (step period, lift, lean) stay underneath.
STRUCTURE = dict(accel_gate=RECOMMENDED["accel_gate"], cp_trigger=1.0, max_steps=1.0,
                 lateral_steps=1.0, cp_rate_blend=1.0, cp_gain_lateral=-1.0,
                 double_support_ratio=0.05, cp_gain=1.5)
TUNED = ("step_period", "double_support_ratio", "lift_height", "cp_gain",
         "cp_trigger_forward_m", "cp_trigger_backward_m", "cp_trigger_lateral_m",
         "cp_gain_lateral", "accel_gate") + STANCE_GAINS
TUNE_SHARE = 0.6                     # of --budget-s for the search's generations


def start_controller(robot) -> dict:
    """The tune's start on `robot`: STRUCTURE on its scaled defaults, the conservative
    default's stance gains, triggers at 15 % of the leg's reach (OP3's 3 cm)."""
    d = robot.defaults
    reach = float(d.thigh_length + d.calf_length)
    start = dict(STRUCTURE, step_period=float(d.step_period), lift_height=float(d.lift_height))
    start |= {k: STANCE_SCALE * RECOMMENDED[k] for k in STANCE_GAINS}
    start |= {k: round(0.15 * reach, 4) for k in ("cp_trigger_forward_m",
                                                   "cp_trigger_backward_m",
                                                   "cp_trigger_lateral_m")}
    return start


def ranges_for(robot, start: dict) -> dict:
    """Search ranges scaled to the robot, each holding the start strictly inside."""
    d = robot.defaults
    reach = float(d.thigh_length + d.calf_length)
    t = start["step_period"]
    return dict(step_period=[round(0.5 * t, 4), round(min(2.0, 2.0 * t), 4)],
                lift_height=[round(0.2 * start["lift_height"], 4),
                             round(min(0.1, 2.5 * start["lift_height"]), 4)],
                cp_gain=[0.3, 4.0], cp_gain_lateral=[-2.0, 0.5], accel_gate=[0.01, 1.0],
                cp_trigger_forward_m=[0.0, round(min(0.5, 0.6 * reach), 4)],
                cp_trigger_backward_m=[0.0, round(min(0.5, 0.6 * reach), 4)],
                cp_trigger_lateral_m=[0.0, round(min(0.5, 0.6 * reach), 4)])


def _uniform(pair) -> dict:
    return {"uniform": [float(pair[0]), float(pair[1])]}


def tune_spec(robot_file: str, robot, pushes: dict, iterations: int) -> dict:
    """The tune spec (as its TOML dict) of the robot's controller (module doc)."""
    start = start_controller(robot)
    return {
        "robot": {"file": robot_file},
        "tune": {"name": f"{robot.name}_controller", "seed": TUNE_SEED, "method": "cma",
                 "popsize": POPSIZE, "iterations": iterations, "batch": TUNE_BATCH,
                 "duration_s": TUNE_HORIZON_S, "params": list(TUNED), "float64": False,
                 "remat": True, "ranges": ranges_for(robot, start),
                 # OP3's loss: a harmed push costs twice a saved one (results/op3/).
                 "loss": dict(w_fall=1.0, w_recovery=1.0, w_step=0.1, w_harm=2.0)},
        "controller": start,
        "push": {"impulse_ns": _uniform(pushes["impulse_ns"]), "azimuth_deg": _uniform((0, 360)),
                 "height_m": _uniform(pushes["height_m"]), "onset_s": _uniform((0.25, 0.4)),
                 "duration_s": _uniform(pushes["duration_s"])},
        "baseline": {"sigma": 0.5},
    }


def heldout_spec(robot_file: str, robot, pushes: dict, n: int) -> dict:
    """The held-out sweep spec (as its TOML dict): other seed, onsets and horizon."""
    return {"robot": {"file": robot_file},
            "sweep": {"name": f"{robot.name}_heldout", "seed": HELDOUT_SEED,
                      "chunk_size": min(n, 8192), "duration_s": HELDOUT_HORIZON_S,
                      "control": ["off", "on"]},
            "push": {"random": {"n": n, "impulse_ns": _uniform(pushes["impulse_ns"]),
                                "azimuth_deg": _uniform((0, 360)),
                                "height_m": _uniform(pushes["height_m"]),
                                "onset_s": _uniform((0.3, 0.6)),
                                "duration_s": _uniform(pushes["duration_s"])}}}


def _stage_pushes(out: Path, robot, log) -> dict:
    path = out / "pushes.json"
    if path.is_file():
        return json.loads(path.read_text())
    log("pushes: probing where the robot standing still falls (MuJoCo C)")
    pushes = robot_pushes(robot).as_dict()
    path.write_text(json.dumps(pushes, indent=1) + "\n")
    return pushes


def _stage_tune(out: Path, robot_file: str, robot, pushes: dict, budget_s: float, log) -> dict:
    from tkujax.studies.tune import run_tune

    record_path = out / "tune" / "params_after.json"
    if record_path.is_file():
        return json.loads(record_path.read_text())
    spec = tune_spec(robot_file, robot, pushes, iterations=10_000)
    (out / "tune_spec.json").write_text(json.dumps(spec, indent=1) + "\n")
    log(f"tune: CMA-ES over {len(TUNED)} parameters, {budget_s:.0f} s of generations")
    run_tune(spec, out / "tune", quiet=True, compare=False, budget_s=budget_s, robot=robot)
    return json.loads(record_path.read_text())


def tune_robot_controller(robot_file: str | Path, out: str | Path, budget_s: float = 480.0,
                          heldout_n: int = 8192, write: bool = True,
                          log=None) -> dict:
    """Run the stages (module doc) for the robot file; returns the verdict's record."""
    if not (isinstance(budget_s, (int, float)) and math.isfinite(budget_s)
            and 30.0 <= budget_s <= 86_400.0):
        raise ValueError(f"budget_s must be in [30, 86400] s, got {budget_s!r}")
    if isinstance(heldout_n, bool) or not isinstance(heldout_n, int) \
            or not 64 <= heldout_n <= 1 << 20:
        raise ValueError(f"heldout_n must be an integer in [64, 1048576], got {heldout_n!r}")
    t0 = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log = log or StatusLog(budget_s)
    robot_file = str(Path(robot_file).resolve())
    robot = robot_setup(robot_file)
    pushes = _stage_pushes(out, robot, log)
    tuned = _stage_tune(out, robot_file, robot, pushes, TUNE_SHARE * budget_s, log)
    log("verdict: held-out pushes, control off and with the tuned controller")
    record = heldout_verdict(out, robot, heldout_spec(robot_file, robot, pushes, heldout_n),
                             tuned, method="cma", n_params=len(TUNED))
    record["wall_s"] = round(time.perf_counter() - t0, 1)     # this run of the command
    if record["passed"] and write:
        record["controller_file"] = str(name_controller(robot_file, tuned))
    (out / "verdict.json").write_text(json.dumps(record, indent=1) + "\n")
    return record

