"""[step] of a sweep spec: commanded recovery steps (`tkujax.control.StepOverride`), crossed
with every push record (`cross_steps`); `step_count` is how many records each push becomes.

    [step]
    reference = true           # also run each push with the controller's own step
    [step.grid]                # x_m, y_m: swing ankle vs its stand
    x_m = {start = -0.1, stop = 0.2, num = 21}
"""

from __future__ import annotations

import numpy as np

from tkujax.dialects.validation import SpecError, table, values

# [step.grid]: commanded steps (StepOverride fields); recorded as step_<name> columns.
STEP_FIELDS = {
    "x_m": (-0.3, 0.3, 0.0, "m"),
    "y_m": (-0.3, 0.3, 0.0, "m"),
    "start_delay_s": (0.0, 2.0, 0.0, "s"),
    "from_detection": (0.0, 1.0, 0.0, "(0 = after onset, 1 = after detection)"),
    "period_s": (0.0, 2.0, 0.0, "s (0 = the controller's step_period)"),
    "steps": (1.0, 2.0, 1.0, "(1 = one commanded step, 2 = a second step of the other foot)"),
    "x2_m": (-0.3, 0.3, 0.0, "m (second step; steps = 2)"),
    "y2_m": (-0.3, 0.3, 0.0, "m (second step; steps = 2)"),
    "delay2_s": (0.0, 2.0, 0.0, "s (first touchdown -> second step start)"),
}
SECOND_STEP_FIELDS = ("x2_m", "y2_m", "delay2_s")


def parse_step(data: dict) -> tuple[dict[str, np.ndarray], bool]:
    step = table("step", data.get("step", {}), {"grid", "reference"})
    grid = table("step.grid", step.get("grid", {}), STEP_FIELDS)
    reference = step.get("reference", True)
    if not isinstance(reference, bool):
        raise SpecError(f"step.reference: expected true or false, got {reference!r}")
    out = {k: values(f"step.grid.{k}", v, *STEP_FIELDS[k][:2], STEP_FIELDS[k][3])
           for k, v in grid.items()}
    if "from_detection" in out and not np.isin(out["from_detection"], (0.0, 1.0)).all():
        raise SpecError(f"step.grid.from_detection: expected 0 or 1, got {out['from_detection']}")
    if "steps" in out and not np.isin(out["steps"], (1.0, 2.0)).all():
        raise SpecError(f"step.grid.steps: expected 1 or 2, got {out['steps']}")
    if "period_s" in out and ((out["period_s"] > 0) & (out["period_s"] < 0.05)).any():
        raise SpecError(f"step.grid.period_s: expected 0 or a value in [0.05, 2.0] s, got "
                        f"{out['period_s']}")
    if step and not out:
        raise SpecError("[step]: give a [step.grid] (e.g. x_m, y_m) or leave [step] out")
    return out, reference



def cross_steps(spec, recs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Cross every record with [step.grid] (step_active = 1), plus, with step.reference, one
    copy with the controller's own step (step_active = 0). No [step]: unchanged. `case_id`
    numbers the records before crossing (the push a step belongs to). Order: reference copy
    first, then the step grid (outer) x records (inner)."""
    if not spec.step_grid:
        return recs
    n = len(recs["control"])
    cols = {k: spec.step_grid.get(k, np.array([STEP_FIELDS[k][2]])) for k in STEP_FIELDS}
    mesh = [m.ravel() for m in np.meshgrid(*cols.values(), indexing="ij")]
    if "steps" in spec.step_grid:
        # One-step targets ignore the second step's fields: keep each once (at the grid's
        # first x2_m, y2_m, delay2_s values), not once per second-step target.
        m = dict(zip(cols, mesh))
        first = np.all([m[k] == cols[k][0] for k in SECOND_STEP_FIELDS], 0)
        keep = (m["steps"] > 1.5) | first
        mesh = [v[keep] for v in mesh]
    n_steps = len(mesh[0])
    blocks = ([("ref", None)] if spec.step_reference else []) + [(i, i) for i in range(n_steps)]
    out = {k: np.concatenate([v] * len(blocks)) for k, v in recs.items()}
    out["case_id"] = np.tile(np.arange(n), len(blocks))
    out["step_active"] = np.concatenate([np.full(n, float(j is not None)) for _, j in blocks])
    for k, m in zip(STEP_FIELDS, mesh):
        out[f"step_{k}"] = np.concatenate([np.full(n, STEP_FIELDS[k][2] if j is None else m[j])
                                           for _, j in blocks])
    return out


def step_count(step_grid: dict[str, np.ndarray], reference: bool) -> int:
    """The records one push record becomes under [step] (1 without it): the reference copy and
    the step grid's targets, a one-step target once whatever the second step's fields."""
    if not step_grid:
        return 1
    sizes = {k: len(step_grid.get(k, [0])) for k in STEP_FIELDS}
    first = int(np.prod([n for k, n in sizes.items() if k not in SECOND_STEP_FIELDS + ("steps",)]))
    second = int(np.prod([sizes[k] for k in SECOND_STEP_FIELDS]))
    if "steps" in step_grid:   # one-step targets once, two-step ones per second-step target
        targets = first * int(np.sum(np.where(np.asarray(step_grid["steps"]) > 1.5, second, 1)))
    else:
        targets = first * second
    return targets + int(bool(reference))
