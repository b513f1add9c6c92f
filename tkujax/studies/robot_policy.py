"""The policy method of `tkujax tune --robot` (tkujax.studies.robot_tune): a scheduled policy
trained by the gradient line search for the wall time the CMA-ES search took.

The CMA-ES search tunes the structure's parameters as one set. The policy keeps them as its
scalars and schedules the schedulable ones (not the accelerometer gate, `UNSCHEDULABLE`) over
8 push-direction sectors of the filtered state (`POLICY`, tkujax.control.policy), starting at
the CMA-ES result with a zero table, which is the same controller. The line search
(`POLICY_METHOD`: the gradient as a direction, its step measured on the hard loss; the method
that beat sep-CMA-ES from 160 parameters on TKU-X, docs/tuning.md) moves it for the CMA-ES
search's compile plus search time, its own compile included (`policy_budget_s`). It returns
its incumbent with the lowest hard fall rate on validation pushes, the start first, so a
search that finds nothing better returns the CMA-ES controller. The held-out verdict then
judges it beside the CMA-ES controller on the same pushes.

The gradient needs MJX's Newton solver at one iteration (`differentiable`): with more it runs
a while loop, which reverse mode cannot differentiate. TKU-X's model runs so everywhere; a
robot file's may ask for more (`[solver] iterations`). The line search then trains on the
one-iteration model, and the verdict judges the policy on the robot's own.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path

from tkujax.control.policy import UNSCHEDULABLE

POLICY, POLICY_METHOD = "sectors8", "linesearch"
# The line search's settings of the TKU-X studies (specs/tune/tune_policy_current.toml):
# gradient windows of 5 ticks, each push's gradient clipped at the median norm, rays from 4
# latent units down by sqrt(1/2), the soft gate's temperature for the gradient.
LINESEARCH_TUNE = dict(gradient_window_ticks=5, clip_norm=1.0, sharpness=4.0)
LINESEARCH_STUDY = dict(groups=4, temperature_deg=0.5, push_clip=1.0, ray_radius=4.0,
                        ray_ratio=0.7071, select="validation", select_every_s=20.0,
                        heldout_checkpoints=2, budget_includes_compile=True, seeds=[0],
                        seeds_side_by_side=False)
# The least wall time the policy's search is given, compile included (its compile alone took
# 79 s on one H200 for OP3: results/robots/op3_command/policy_h200/policy_run.json).
MIN_BUDGET_S = 30.0


def scheduled_fields(tuned) -> list[str]:
    """The tuned fields a policy may schedule."""
    return [f for f in tuned if f not in UNSCHEDULABLE]


def policy_spec(cma_spec: dict, start: dict, budget_s: float) -> dict:
    """The study spec (TOML dict) of the policy method: the CMA-ES stage's spec `cma_spec`
    (its pushes, loss and ranges) started at `start` (that search's result, as a [controller]
    table), one sectors8 policy, the line search, `budget_s` with its compile."""
    tune = dict(cma_spec["tune"])
    tune |= dict(name=f"{tune['name']}_policy", policy=POLICY, method=POLICY_METHOD,
                 schedule=scheduled_fields(tune["params"]), **LINESEARCH_TUNE)
    study = dict(policies=[POLICY], methods=[POLICY_METHOD], budget_s=float(budget_s),
                 **LINESEARCH_STUDY)
    return cma_spec | {"tune": tune, "controller": start, "study": study}


def policy_budget_s(history: dict) -> float:
    """The CMA-ES search's compile plus search seconds, from its history.json record."""
    run = history["run"]
    curve = run.get("curve") or [{"wall_s": 0.0}]
    return float(run.get("compile_s", 0.0)) + float(curve[-1]["wall_s"])


def differentiable(robot):
    """`robot` with its model's Newton solver at one iteration (module doc); itself when it
    runs so already."""
    import jax

    from tkujax.sim.mjx_import import mjx

    host = robot.setup.host_model
    if host.opt.iterations == 1:
        return robot
    model = copy.deepcopy(host)
    model.opt.iterations = 1
    device = jax.local_devices()[0]
    return dataclasses.replace(robot, setup=robot.setup._replace(
        host_model=model, device_model=mjx.put_model(model, device=device)))


def run_policy_method(folder: Path, spec: dict, robot, log) -> dict | None:
    """Run the study of `spec` (`policy_spec`) into folder/study (resumable: a finished run
    is kept) and return its best policy as a policy file's dict, or None when the structure
    schedules nothing."""
    from tkujax.studies.tune import run_tune

    if not spec["tune"]["schedule"]:
        return None
    best = folder / "study" / "best_policy.json"
    if not best.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "policy_spec.json").write_text(json.dumps(spec, indent=1) + "\n")
        log(f"policy: the line search on a {POLICY} policy ({policy_size(spec)} parameters) "
            f"from the CMA-ES result, {spec['study']['budget_s']:.0f} s with its compile")
        run_tune(spec, folder / "study", quiet=True, robot=differentiable(robot))
    return json.loads(best.read_text())


def returned_start(policy: dict, spec: dict) -> bool:
    """Whether the line search returned its start (`policy_spec`'s [controller], a zero
    table): no step lowered the validation falls. That policy is the CMA-ES controller but for
    the start's nudge inside its ranges, which flips a few chaotic outcomes (8 of 8,192 on
    TKU-X: results/robots/tkux/README.md), so it is not judged as a controller of its own."""
    if any(v != 0.0 for row in policy["schedule"]["table"] for v in row):
        return False
    scalars, start = policy["controller"], spec["controller"]
    return all(math.isclose(float(scalars[k]), float(start[k]), rel_tol=1e-9, abs_tol=1e-12)
               for k in spec["tune"]["params"])


def policy_size(spec: dict) -> int:
    """The policy's tuned parameters: its scalars and its 8 sectors x scheduled fields."""
    return len(spec["tune"]["params"]) + 8 * len(spec["tune"]["schedule"])
