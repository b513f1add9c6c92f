"""`tkujax tune --robot FILE --out DIR`: from a robot to its recovery controller, no spec.

Stages, each kept in DIR and skipped when done (rerun the command to resume):

1. `pushes.json`: the robot's push distributions (`tkujax.studies.robot_pushes`).
2. `structure.json`: the recovery structure, chosen on the robot
   (`tkujax.studies.robot_structure`): OP3's (the accelerometer gate, capture-point triggers,
   the widening sideways step, stance feedback, one step) or stance feedback without a step.
   `tune/`: its start tuned by CMA-ES (`tkujax.studies.tune`) on the tuning pushes (seed
   `TUNE_SEED`) with the no-harm weight, for the budget's tuning share.
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

from tkujax.robot import robot_from_file
from tkujax.sweeps.progress import StatusLog
from tkujax.studies.robot_pushes import (PROBE_DURATION_S, PROBE_HORIZON_S, PROBE_ONSET_S,
                                         robot_pushes, widest_pushes)
from tkujax.studies.robot_structure import STRUCTURES, choose_structure, structure_start
from tkujax.studies.robot_verdict import heldout_verdict, name_controller
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.dialects.push_limits import check_push_end
from tkujax.studies.tune.tune_spec import parse_tune_spec

TUNE_SEED, HELDOUT_SEED = 0, 11
TUNE_BATCH, TUNE_HORIZON_S, POPSIZE = 256, 1.5, 13
HELDOUT_HORIZON_S = 2.0
TUNE_SHARE = 0.6                     # of --budget-s for the search's generations
DEGREE_KEYS = ("eps_forward", "eps_backward")


def ranges_for(robot, start: dict, tuned: tuple[str, ...]) -> dict:
    """Search ranges of the tuned fields scaled to the robot, each holding the start strictly
    inside (the stance gains keep the tune's default ranges)."""
    d = robot.defaults
    reach = float(d.thigh_length + d.calf_length)
    ranges = dict(cp_gain=[0.3, 4.0], cp_gain_lateral=[-2.0, 0.5], accel_gate=[0.01, 1.0],
                  cp_trigger_forward_m=[0.0, round(min(0.5, 0.6 * reach), 4)],
                  cp_trigger_backward_m=[0.0, round(min(0.5, 0.6 * reach), 4)],
                  cp_trigger_lateral_m=[0.0, round(min(0.5, 0.6 * reach), 4)])
    if "step_period" in start:
        t, lift = start["step_period"], start["lift_height"]
        ranges |= dict(step_period=[round(0.5 * t, 4), round(min(2.0, 2.0 * t), 4)],
                       lift_height=[round(0.2 * lift, 4), round(min(0.1, 2.5 * lift), 4)])
    if "step_shift_m" in start:
        ranges["step_shift_m"] = [0.0, round(min(0.25, max(0.02, 2.0 * start["step_shift_m"])), 4)]
    return {k: v for k, v in ranges.items() if k in tuned}


def _uniform(pair) -> dict:
    return {"uniform": [float(pair[0]), float(pair[1])]}


def tune_spec(robot_file: str, robot, pushes: dict, structure: str, iterations: int) -> dict:
    """The tune spec (as its TOML dict) of the robot's controller in `structure` (module doc)."""
    start = structure_start(robot, structure)
    tuned = STRUCTURES[structure]["tuned"]
    # The spec dialect gives the lean thresholds in degrees.
    controller = {(f"{k}_deg" if k in DEGREE_KEYS else k): (math.degrees(v) if k in DEGREE_KEYS
                                                            else v)
                  for k, v in start.items()}
    return {
        "robot": {"file": robot_file},
        "tune": {"name": f"{robot.name}_controller", "seed": TUNE_SEED, "method": "cma",
                 "popsize": POPSIZE, "iterations": iterations, "batch": TUNE_BATCH,
                 "duration_s": TUNE_HORIZON_S, "params": list(tuned), "float64": False,
                 "remat": True, "ranges": ranges_for(robot, start, tuned),
                 # OP3's loss: a harmed push costs twice a saved one (results/op3/).
                 "loss": dict(w_fall=1.0, w_recovery=1.0, w_step=0.1, w_harm=2.0)},
        "controller": controller,
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


def _stage_structure(out: Path, robot, pushes: dict, log) -> dict:
    path = out / "structure.json"
    if path.is_file():
        return json.loads(path.read_text())
    log("structure: a step or stance feedback alone, on the robot's pushes (MuJoCo C)")
    record = choose_structure(robot, pushes)
    path.write_text(json.dumps(record, indent=1) + "\n")
    return record


def _stage_tune(out: Path, robot_file: str, robot, pushes: dict, structure: str,
                budget_s: float, log) -> dict:
    from tkujax.studies.tune import run_tune

    record_path = out / "tune" / "params_after.json"
    if record_path.is_file():
        return json.loads(record_path.read_text())
    spec = tune_spec(robot_file, robot, pushes, structure, iterations=10_000)
    (out / "tune_spec.json").write_text(json.dumps(spec, indent=1) + "\n")
    log(f"tune: CMA-ES over {len(spec['tune']['params'])} parameters ({structure}), "
        f"{budget_s:.0f} s of generations")
    run_tune(spec, out / "tune", quiet=True, compare=False, budget_s=budget_s, robot=robot)
    return json.loads(record_path.read_text())


def check_stages(robot_file: str, robot, heldout_n: int) -> None:
    """The stages' pushes checked before anything is simulated, by the checks of sweeps and
    tunes (`tkujax.dialects.push_limits`, `tkujax.studies.tune.limits`): the probe's pushes
    within its horizon, and the tune and held-out specs of every structure, built with the
    widest pushes the probe can give, parsed (SpecError names the stage's key)."""
    check_push_end("the probe's onset + pulse (tkujax.studies.robot_pushes.PROBE_ONSET_S + "
                   "PROBE_DURATION_S)", PROBE_ONSET_S + PROBE_DURATION_S,
                   "PROBE_HORIZON_S", PROBE_HORIZON_S)
    widest = widest_pushes(robot).as_dict()
    for structure in STRUCTURES:
        parse_tune_spec(tune_spec(robot_file, robot, widest, structure, iterations=10_000))
    parse_spec(heldout_spec(robot_file, robot, widest, heldout_n))


def claim_out(out: Path, robot) -> None:
    """The stages kept in `out` are this robot's: `robot.json` names the robot file and its
    sha256 (with its model, included files and meshes); SpecError when it names another, or
    the file changed since (the kept stages would be another robot's)."""
    path = out / "robot.json"
    mine = dict(robot=robot.name, robot_file=robot.source, robot_sha256=robot.digest)
    if path.is_file():
        held = json.loads(path.read_text())
        if held.get("robot_sha256") != robot.digest:
            raise SpecError(f"{out} holds the stages of robot {held.get('robot')!r} "
                            f"({held.get('robot_file')}, sha256 {held.get('robot_sha256')}); "
                            f"{robot.source} is {robot.digest} (another robot, or the file, its "
                            "model, included files or meshes changed). Nothing was written: "
                            "choose another --out")
        return
    path.write_text(json.dumps(mine, indent=1) + "\n")


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
    log = log or StatusLog(budget_s=budget_s, desc="tune --robot ")
    robot_file = str(Path(robot_file).resolve())
    robot = robot_from_file(robot_file)
    check_stages(robot_file, robot, heldout_n)
    out.mkdir(parents=True, exist_ok=True)
    claim_out(out, robot)
    pushes = _stage_pushes(out, robot, log)
    structure = _stage_structure(out, robot, pushes, log)
    name = structure["chosen"]
    tuned = _stage_tune(out, robot_file, robot, pushes, name, TUNE_SHARE * budget_s, log)
    log("verdict: held-out pushes, control off and with the tuned controller")
    record = heldout_verdict(out, robot, heldout_spec(robot_file, robot, pushes, heldout_n),
                             tuned, method="cma", n_params=len(STRUCTURES[name]["tuned"]))
    record["structure"] = dict(chosen=name, why=structure["why"])
    record["wall_s"] = round(time.perf_counter() - t0, 1)     # this run of the command
    if record["passed"] and write:
        record["controller_file"] = str(name_controller(robot_file, tuned))
    (out / "verdict.json").write_text(json.dumps(record, indent=1) + "\n")
    return record

