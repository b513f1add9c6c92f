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
4. `compare/` and `first_verdict.json`: `tkujax compare` of the two; the controller passes
   when it falls less often than control off and no direction x impulse x phase cell with
   >= 100 pushes falls more than 2 points more often.
   `policy/` (the policy method; by default on a GPU where the policy has at least
   GRADIENTS_PAY_FROM_PARAMS parameters, `gradients_pay`; `policy_method`): a scheduled policy
   started at the CMA-ES result and trained by the gradient line search for the CMA-ES
   search's wall time, compile included (`tkujax.studies.robot_policy`), judged on the same
   held-out pushes; the better verdict is kept (`better_verdict`: passing, then fewer harmed
   cells, then fewer falls; the CMA-ES controller on a tie).
5. `retry/` (only when that controller fails while control off falls): the search again from
   the tuned controller, a harmed push weighing RETRY_HARM_WEIGHT (not 2) and twice the
   tuning pushes, for the same share of the budget; then the search's result (`tune/`'s
   params_tuned.json) is judged on the same held-out pushes (control on only, compared with
   step 3's control off). On OP3 this turned 0.678x with 4 harmed cells into 0.733x with
   none (results/robots/op3_command/).
6. `fallback/` (only when the retry's controller fails too, while control off falls): the
   conservative default (`structure_start(robot, "stance")`: half the recommended stance
   gains and the accelerometer gate, no step; untuned) judged on the same held-out pushes,
   so that a robot the search could not help still gets the controller that harms least
   when it passes; when it fails too, the same with its stance gains halved
   (`fallback_0.5/`), then quartered (`fallback_0.25/`) (`FALLBACK_SCALES`), until one
   passes.
7. `own/` (only when the robot has a controller of its own: the one its robot file names, or
   TKU-X's recommended policy): that controller judged on the same held-out pushes. It is
   kept, and nothing is written, unless this run's verdict is better (`better_verdict`; the
   own controller on a tie): a rerun with a smaller budget never replaces a better
   controller with a worse one.
8. `verdict.json`: the passing controller (else the one with fewer harmed cells, then fewer
   falls), with each stage's verdict under `stages`. A passing controller of this run is
   written next to the robot file (`<stem>_controller.json`) and named in it
   (`controller = ...`); otherwise the verdict says why it failed and the robot file is left
   as it was.

`--robot tkux` (`robot_inputs.BUILTIN_ROBOT`) runs the same stages on the built-in TKU-X: the
specs name no robot file, and a passing controller that beats the recommended policy is
written to `controller.json` in the output folder (the package's policy is replaced by hand
only).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

from tkujax.control.params_files import RECOMMENDED_POLICY_PATH, controller_params_from
from tkujax.robot import robot_from_file
from tkujax.robot.description import load_description
from tkujax.sim.robot import builtin_robot
from tkujax.robot.own_controller import STANCE_GAINS
from tkujax.sweeps.progress import StatusLog
from tkujax.studies.robot_inputs import is_builtin
from tkujax.studies.robot_pushes import robot_pushes
from tkujax.studies.robot_policy import (MIN_BUDGET_S, POLICY, POLICY_METHOD, policy_budget_s,
                                         policy_size, policy_spec, returned_start,
                                         run_policy_method)
from tkujax.studies.robot_structure import STRUCTURES, choose_structure, structure_start
from tkujax.studies.robot_tune_specs import (RETRY_HARM_WEIGHT, check_stages, heldout_spec,
                                             tune_spec)
from tkujax.studies.robot_verdict import heldout_verdict, write_controller
from tkujax.dialects.sweep_spec import SpecError

TUNE_SHARE = 0.6                     # of --budget-s for the search's generations
# The policy method runs by default from this many parameters: on TKU-X the gradient line
# search beat sep-CMA-ES at equal wall time from 160 parameters up (from the paper's
# controller), and lost below and from a CMA-ES-tuned start (docs/tuning.md; on OP3 its
# 127-parameter policy from the CMA-ES result gained nothing at 152 s,
# results/robots/op3_command/policy_h200/).
GRADIENTS_PAY_FROM_PARAMS = 160
# The fallback's ladder (step 6): the conservative default, then its stance gains halved and
# quartered. A conservative default can harm a cell at the 2-point rule's edge (the Berkeley
# Humanoid's, +2.2 points in one run: results/robots/berkeley_humanoid/README.md);
# tests/test_robot_tune.py runs the ladder.
FALLBACK_SCALES = (1.0, 0.5, 0.25)


def _stage_pushes(out: Path, robot, log) -> dict:
    path = out / "pushes.json"
    if path.is_file():
        return json.loads(path.read_text())
    log("pushes: probing where the robot standing still falls (MuJoCo C)")
    pushes = robot_pushes(robot).as_dict()
    path.write_text(json.dumps(pushes, indent=1) + "\n")
    return pushes


def _stage_structure(out: Path, robot, pushes: dict, log, given: str | None = None) -> dict:
    """structure.json: the probe's choice, or `given` (--structure) without a probe; a kept
    record of another structure than `given` is refused (SpecError)."""
    path = out / "structure.json"
    if path.is_file():
        record = json.loads(path.read_text())
        if given is not None and record["chosen"] != given:
            raise SpecError(f"--structure {given}: {out} holds a run of structure "
                            f"{record['chosen']!r}; choose another --out")
        return record
    if given is not None:
        record = dict(chosen=given, why=f"{given}: given (--structure), no probe")
    else:
        log("structure: a step or stance feedback alone, on the robot's pushes (MuJoCo C)")
        record = choose_structure(robot, pushes)
    path.write_text(json.dumps(record, indent=1) + "\n")
    return record


def _stage_tune(folder: Path, robot_file: str, robot, pushes: dict, structure: str,
                budget_s: float, log, retry_from: dict | None = None) -> dict:
    from tkujax.studies.tune import run_tune

    # The retry takes the search's result, not the tune's recommendation: that keeps the start
    # unless the held-out falls drop, while the retry may trade falls for harm, which the
    # verdict judges (results/robots/op3_command/: kept 15.6 % over 12.7 %, 0.5 -> 0.1 % harmed).
    name = "params_tuned.json" if retry_from is not None else "params_after.json"
    record_path = folder / "tune" / name
    if record_path.is_file():
        return json.loads(record_path.read_text())
    folder.mkdir(parents=True, exist_ok=True)
    spec = tune_spec(robot_file, robot, pushes, structure, iterations=10_000,
                     retry_from=retry_from)
    (folder / "tune_spec.json").write_text(json.dumps(spec, indent=1) + "\n")
    weight = spec["tune"]["loss"]["w_harm"]
    log(f"{'retry' if retry_from else 'tune'}: CMA-ES over {len(spec['tune']['params'])} "
        f"parameters ({structure}, harm weight {weight:g}), {budget_s:.0f} s of generations")
    run_tune(spec, folder / "tune", quiet=True, compare=False, budget_s=budget_s, robot=robot)
    return json.loads(record_path.read_text())


def tuned_method(params: dict, n_params: int) -> tuple[str, int]:
    """(method, number of tuned parameters) of the search's recommendation: the tune keeps its
    start when the search's result falls more on its own held-out pushes (`recommended_from`
    "start"), and then no parameter was tuned (Unitree G1 and H1: results/robots/)."""
    if params.get("recommended_from") == "start":
        return ("none (the structure's start: the search's result fell more on the tune's "
                "held-out pushes)", 0)
    return "cma", n_params


def should_retry(first: dict) -> bool:
    """Step 5 runs when the first controller failed on pushes control off falls on (a verdict
    with no cell to judge, or nothing to judge, is not helped by a search)."""
    return (not first["passed"] and first["ratio"] is not None
            and first["cells_checked"] > 0)


def better_verdict(a: dict, b: dict) -> dict:
    """The verdict to report of two: a passing one, else fewer harmed cells, then fewer falls
    (`a` on a tie)."""
    def key(v):
        return (not v["passed"], len(v["harmed_cells"]), v["on_fall"])
    return b if key(b) < key(a) else a


def _summary(v: dict) -> dict:
    keys = ("on_fall", "ratio", "harmed_cells", "cells_checked", "passed", "why", "wall_s")
    return {k: v[k] for k in keys}


def _stage_retry(out: Path, robot_file: str, robot, pushes: dict, structure: str,
                 budget_s: float, log, best: dict, best_params: dict, tuned: dict, held: dict):
    """Step 5 (module doc): (the verdict to report, its controller's parameter dict). `best`
    and `best_params`: the verdict and controller so far; `tuned`: the CMA-ES result, where
    the search starts again."""
    if hasattr(log, "add_budget"):
        log.add_budget(budget_s)
    log(f"retry: {best['why']}; the search again from the CMA-ES result, harm weight "
        f"{RETRY_HARM_WEIGHT:g} (the budget grows by {budget_s:.0f} s)")
    again = _stage_tune(out / "retry", robot_file, robot, pushes, structure,
                        TUNE_SHARE * budget_s, log, retry_from=tuned)
    log("verdict: the retry's controller on the same held-out pushes")
    second = heldout_verdict(out / "retry", robot, held, again, method="cma",
                             n_params=len(STRUCTURES[structure]["tuned"]),
                             reference=out / "heldout")
    record = better_verdict(best, second)
    record["stages"] = dict(best["stages"], retry=_summary(second))
    record["chosen_stage"] = ("retry" if record is second
                              else best.get("chosen_stage", "tune"))
    return record, (again if record is second else best_params)


def _stage_policy(out: Path, robot_file: str, robot, pushes: dict, structure: str, log,
                  record: dict, params: dict, held: dict, forced: bool):
    """The policy method (module doc, step 4): (the verdict to report, its controller's
    parameter or policy dict). Not `forced`: only where `gradients_pay`."""
    start = tune_spec(robot_file, robot, pushes, structure, iterations=10_000,
                      retry_from=params)["controller"]
    cma = tune_spec(robot_file, robot, pushes, structure, iterations=10_000)
    n_params = policy_size(policy_spec(cma, start, MIN_BUDGET_S))
    if not (forced or gradients_pay(n_params)):
        log(f"policy: not run by default here ({n_params} parameters; it runs on a GPU from "
            f"{GRADIENTS_PAY_FROM_PARAMS}, where the line search beat CMA-ES; --policy-method "
            "on runs it)")
        return record, params
    history = json.loads((out / "tune" / "history.json").read_text())
    budget = max(MIN_BUDGET_S, policy_budget_s(history))
    spec = policy_spec(cma, start, budget)
    if hasattr(log, "add_budget"):
        log.add_budget(budget)
    policy = run_policy_method(out / "policy", spec, robot, log)
    if policy is None:
        return record, params
    if returned_start(policy, spec):
        why = ("the line search returned its start, the CMA-ES controller: no step lowered "
               "the validation falls")
        log(f"policy: {why}")
        record["stages"] = dict(record["stages"], policy=dict(
            returned_start=True, why=why, n_params=policy_size(spec),
            budget_s=round(budget, 1)))
        return record, params
    log("verdict: the policy on the same held-out pushes")
    verdict = heldout_verdict(out / "policy", robot, held, policy,
                              method=f"{POLICY_METHOD} ({POLICY} policy)",
                              n_params=policy_size(spec), reference=out / "heldout")
    stages = dict(record["stages"], policy=_summary(verdict) | {"budget_s": round(budget, 1)})
    best = better_verdict(record, verdict)
    best["stages"] = stages
    best["chosen_stage"] = "policy" if best is verdict else record.get("chosen_stage", "tune")
    return best, (policy if best is verdict else params)


def gradients_pay(n_params: int) -> bool:
    """Whether the policy method runs by default (`--policy-method auto`): where JAX runs on a
    GPU (on a CPU the gradient through MJX of a robot file's model compiles for minutes) and
    the policy has at least GRADIENTS_PAY_FROM_PARAMS parameters."""
    import jax

    return jax.default_backend() == "gpu" and n_params >= GRADIENTS_PAY_FROM_PARAMS


def fallback_params(robot, scale: float) -> dict:
    """The conservative default (`structure_start(robot, "stance")`) with its stance gains
    times `scale`, as a parameter dict."""
    start = structure_start(robot, "stance")
    start |= {k: scale * start[k] for k in STANCE_GAINS}
    return dataclasses.asdict(controller_params_from(robot.defaults, start))


def fallback_stage(scale: float) -> tuple[str, str]:
    """(folder and stage name, what it judges) of the fallback at `scale` of the conservative
    default's stance gains."""
    if scale == 1.0:
        return "fallback", "the conservative default"
    return f"fallback_{scale:g}", f"the conservative default, its stance gains x {scale:g}"


def _stage_fallback(out: Path, robot, held: dict, log, record: dict, params: dict):
    """Step 6 (module doc): (the verdict to report, its controller's parameter dict). The
    ladder FALLBACK_SCALES stops at the first controller that passes."""
    best, stages = record, dict(record["stages"])
    for scale in FALLBACK_SCALES:
        stage, what = fallback_stage(scale)
        log(f"fallback: {best['why']}; {what} (stance feedback, no step) on the same held-out "
            "pushes")
        candidate = fallback_params(robot, scale)
        (out / stage).mkdir(exist_ok=True)
        verdict = heldout_verdict(out / stage, robot, held, candidate, method=f"none ({what})",
                                  n_params=0, reference=out / "heldout")
        stages[stage] = _summary(verdict)
        if better_verdict(best, verdict) is verdict:
            best, params = verdict, candidate
            best["chosen_stage"] = stage
        if best["passed"]:
            break
    best["stages"] = stages
    best.setdefault("chosen_stage", record.get("chosen_stage", "tune"))
    return best, params


def robot_of(robot_arg: str | Path):
    """(the Robot, its robot file's resolved path; None for the built-in TKU-X)."""
    if is_builtin(robot_arg):
        return builtin_robot(), None
    path = str(Path(robot_arg).resolve())
    return robot_from_file(path), path


def own_controller(robot, robot_file: str | None) -> tuple[dict, str] | None:
    """(the robot's own controller as a parameter or policy file's dict, where it is) before
    this run: TKU-X's recommended policy, else the controller its robot file names; None
    when the file names none."""
    if robot_file is None:
        return json.loads(RECOMMENDED_POLICY_PATH.read_text()), "the recommended policy"
    path = load_description(robot_file).controller_path
    return None if path is None else (json.loads(path.read_text()), f"file {path.name}")


def _stage_own(out: Path, robot, robot_file: str | None, held: dict, log, record: dict,
               params: dict):
    """Step 7 (module doc): (the verdict to report, its controller's dict, whether it is the
    robot's own). The own controller is kept in own/controller.json when first judged, so a
    rerun judges the same one after a run has replaced it."""
    kept = out / "own" / "controller.json"
    if kept.is_file():
        own, where = json.loads(kept.read_text()), json.loads(
            (out / "own" / "where.json").read_text())["where"]
    else:
        found = own_controller(robot, robot_file)
        if found is None:
            return record, params, False
        own, where = found
        kept.parent.mkdir(parents=True, exist_ok=True)
        # where.json first: controller.json marks the pair complete for a rerun.
        (out / "own" / "where.json").write_text(json.dumps(dict(where=where)) + "\n")
        kept.write_text(json.dumps(own, indent=1) + "\n")
    log(f"verdict: the robot's own controller ({where}) on the same held-out pushes")
    verdict = heldout_verdict(out / "own", robot, held, own,
                              method=f"none (the robot's own controller, {where}, kept)",
                              n_params=0, reference=out / "heldout")
    stages = dict(record["stages"], own=_summary(verdict) | {"where": where})
    # The own controller on a tie: a controller is replaced only by a better one.
    best = better_verdict(verdict, record)
    best["stages"] = stages
    best["chosen_stage"] = "own" if best is verdict else record.get("chosen_stage", "tune")
    return best, (own if best is verdict else params), best is verdict


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
                          heldout_n: int = 8192, write: bool = True, retry: bool = True,
                          log=None, structure: str | None = None,
                          policy_method: bool | None = None) -> dict:
    """Run the stages (module doc) for the robot file ("tkux": the built-in TKU-X);
    returns the verdict's record. retry False: steps 5 and 6 never run. structure: one of
    STRUCTURES instead of the probe's choice (None: the probe chooses). policy_method: run the
    policy method of step 4 (None: where `gradients_pay`)."""
    if structure is not None and structure not in STRUCTURES:
        raise ValueError(f"structure must be one of {sorted(STRUCTURES)}, got {structure!r}")
    if not (isinstance(budget_s, (int, float)) and math.isfinite(budget_s)
            and 30.0 <= budget_s <= 86_400.0):
        raise ValueError(f"budget_s must be in [30, 86400] s, got {budget_s!r}")
    if isinstance(heldout_n, bool) or not isinstance(heldout_n, int) \
            or not 64 <= heldout_n <= 1 << 20:
        raise ValueError(f"heldout_n must be an integer in [64, 1048576], got {heldout_n!r}")
    t0 = time.perf_counter()
    out = Path(out)
    log = log or StatusLog(budget_s=budget_s, desc="tune --robot ")
    robot, robot_file = robot_of(robot_file)
    check_stages(robot_file, robot, heldout_n)
    out.mkdir(parents=True, exist_ok=True)
    claim_out(out, robot)
    pushes = _stage_pushes(out, robot, log)
    structure = _stage_structure(out, robot, pushes, log, given=structure)
    name = structure["chosen"]
    n_params = len(STRUCTURES[name]["tuned"])
    tuned = _stage_tune(out, robot_file, robot, pushes, name, TUNE_SHARE * budget_s, log)
    held = heldout_spec(robot_file, robot, pushes, heldout_n)
    log("verdict: held-out pushes, control off and with the tuned controller")
    method, n_params = tuned_method(tuned, n_params)
    first = heldout_verdict(out, robot, held, tuned, method=method, n_params=n_params)
    (out / "first_verdict.json").write_text(json.dumps(first, indent=1) + "\n")
    record, params = first, tuned
    record["stages"], record["chosen_stage"] = {"tune": _summary(first)}, "tune"
    if policy_method is not False:
        record, params = _stage_policy(out, robot_file, robot, pushes, name, log, record,
                                       params, held, forced=policy_method is True)
    if retry and should_retry(record):
        record, params = _stage_retry(out, robot_file, robot, pushes, name, budget_s, log,
                                      record, params, tuned, held)
        if should_retry(record):
            record, params = _stage_fallback(out, robot, held, log, record, params)
    record, params, kept_own = _stage_own(out, robot, robot_file, held, log, record, params)
    record["structure"] = dict(chosen=name, why=structure["why"])
    record["wall_s"] = round(time.perf_counter() - t0, 1)     # this run of the command
    if record["passed"] and write and not kept_own:
        record["controller_file"] = str(write_controller(robot_file, params, out))
    (out / "verdict.json").write_text(json.dumps(record, indent=1) + "\n")
    return record
