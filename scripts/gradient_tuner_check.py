"""Per-push gradient diagnostics of the margin loss through the tuner (TuneProblem), on CPU.

Starts: the recommended controller (its 16 tuned scalars, specs/tune/tune_recovery_ensemble.toml's
tune.params and ranges) and the sectors8 policy at the same scalars; each with and without
truncated backpropagation windows (tune.gradient_window_ticks). The spec's push distribution,
on the default robot (no ensemble), its randomisation and sensor noise kept, tune.loss.kind =
"margin" with its defaults (w_recovery 1, w_step 0.1), no harm weight.

For each: the per-push gradients of one batch (TuneProblem.grouped_value_and_grad with groups =
n, soft gate at 0.5 deg as the tuner's gradient methods), their diagnostics
(`tkujax.gradients.diagnostics.summary`), and the step check along -g/|g| at a few step
sizes (latent units) on the same batch and gate: predicted (first order) against measured.

    python scripts/gradient_tuner_check.py --out results/gradient_tuner_check_cpu
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.gradients.diagnostics import step_check, summary
from tkujax.studies.tune.reparam import DEG
from tkujax.studies.tune.tune_spec import make_problem, parse_tune_spec, sample_pushes
from tkujax.dialects.validation import read_toml

SPEC = "specs/tune/tune_recovery_ensemble.toml"
TAU = 0.5 * DEG
STEPS = (0.01, 0.1, 0.3)


def spec_for(policy: str, window: int | None, batch: int, duration_s: float,
             w_recovery: float):
    data = read_toml(SPEC)
    data["randomize"].pop("ensemble")
    data["evaluate"].pop("shift", None)
    tune = data["tune"]
    tune.update(batch=batch, duration_s=duration_s, policy=policy, diagnose_every=0)
    tune["loss"] = dict(kind="margin", w_recovery=w_recovery, w_step=0.1)
    if window is not None:
        tune["gradient_window_ticks"] = window
    if policy != "scalars":
        tune["schedule"] = ["cp_gain", "stance_ankle_kp", "stance_hip_kp", "stance_roll_kp"]
    spec = parse_tune_spec(data)
    return dataclasses.replace(spec, start=ControllerParams.recommended())


def check(policy: str, window: int | None, batch: int, duration_s: float,
          w_recovery: float) -> dict:
    spec = spec_for(policy, window, batch, duration_s, w_recovery)
    reparam = spec.policy_reparam()
    problem = make_problem(spec, reparam)
    z0 = reparam.latent_of(spec.base_params())
    if not np.all(np.isfinite(z0)):
        raise SystemExit(f"{policy}: the recommended controller lies outside the ranges")
    recs = sample_pushes(spec, batch, spec.seed)
    keys = jax.random.split(jax.random.PRNGKey(spec.seed), batch)
    t0 = time.perf_counter()
    losses, per_push = problem.grouped_value_and_grad(z0, TAU, recs, keys, batch)
    t_grad = time.perf_counter() - t0
    _, aux = problem.forward(z0, 0.0, recs, keys)
    finite = np.all(np.isfinite(per_push), axis=1)
    g = np.where(finite[:, None], per_push, 0.0)
    loss = lambda z: problem.forward(z, TAU, recs, keys)[0]  # noqa: E731
    t0 = time.perf_counter()
    checks = step_check(loss, z0, g.mean(0), STEPS)
    t_fwd = (time.perf_counter() - t0) / (len(STEPS) + 1)
    return dict(policy=policy, gradient_window_ticks=window, w_recovery=w_recovery,
                n_params=int(z0.size), batch=batch, duration_s=duration_s,
                loss_soft_gate=float(np.nanmean(losses)),
                hard_fell=int(np.sum(aux["outcomes"]["fell"])), nonfinite=int((~finite).sum()),
                first_call_s=round(t_grad, 1), forward_s=round(t_fwd, 2),
                diagnostics=summary(g),
                step_checks=[dict(step=c.step, predicted=c.predicted, measured=c.measured,
                                  ratio=c.ratio) for c in checks])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--batch", type=int, default=32)
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--window", type=int, default=5, help="ticks (5 = 0.15 s)")
    ap.add_argument("--runs", default="scalars:none:1,scalars:W:1,sectors8:none:1,"
                    "sectors8:W:1,scalars:none:0",
                    help="policy:window(none|W):w_recovery, comma separated")
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    results = []
    for item in a.runs.split(","):
        policy, window, w_rec = item.split(":")
        w = None if window == "none" else a.window
        r = check(policy, w, a.batch, a.duration, float(w_rec))
        results.append(r)
        d = r["diagnostics"]
        print(f"{policy:9s} window {str(w):4s} w_rec {w_rec}: k {r['n_params']}, fell "
              f"{r['hard_fell']}/{a.batch}, half-cos {d['half_cosine']:+.3f}, top5 "
              f"{d['top_share']:.3f}, steps "
              + " ".join(f"{c['step']:g}: {c['predicted']:+.4f}/{c['measured']:+.4f}"
                         for c in r["step_checks"]), flush=True)
        (out / "gradient_tuner_check.json").write_text(json.dumps(results, indent=1,
                                                                  default=float) + "\n")


if __name__ == "__main__":
    main()
