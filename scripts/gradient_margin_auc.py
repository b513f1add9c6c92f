"""ROC AUC of the bounded DCM margin (tkujax.gradients.margin) against the hard fall, on
pushes spread around the fall boundary, with MuJoCo C (CPU), against the tuning loss's fall term
(tkujax.studies.tune.loss) as the baseline.

Two push sets from two seeds: "dev" (where the margin's options were compared) and "held_out"
(the figures to quote). Controllers: the recommended scalar controller, the recommended
scheduled policy, control off.

  python scripts/gradient_margin_auc.py --out /tmp/margin_auc [--n 256] [--duration 1.5]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control import ControllerParams
from tkujax.control.params_files import recommended_policy
from tkujax.sim.push import CONTROL_PERIOD_S, Push
from tkujax.sim.rollout_mjx import RolloutConfig
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.gradients.auc import roc_auc, roc_curve
from tkujax.gradients.margin import MarginConfig, batched_margin
from tkujax.studies.tune.loss import LossConfig, push_loss

VARIANTS = {
    "margin": MarginConfig(),
    "margin_drop_airborne": MarginConfig(drop_airborne_foot=True),
    "margin_hard_max": MarginConfig(softmax_m=1e-4),
    "margin_soft_20mm": MarginConfig(softmax_m=0.02),
    "margin_window_0.3s": MarginConfig(window_s=0.3),
    "margin_window_0.4s": MarginConfig(window_s=0.4),
}


def sample_pushes(n: int, seed: int, impulse_ns=(0.6, 3.2)) -> Push:
    """n pushes: impulse, azimuth, hit phase within a control period, height and duration
    uniform (the ranges of sweeps/recovery_eval.toml's random pushes)."""
    rng = np.random.default_rng(seed)
    f = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    onset = 0.3 + CONTROL_PERIOD_S * rng.uniform(0.0, 1.0, n)
    return Push(f(rng.uniform(*impulse_ns, n)), f(rng.uniform(0.0, 2 * np.pi, n)),
                f(rng.uniform(0.30, 0.42, n)), f(rng.uniform(0.01, 0.05, n)), f(onset))


def scores(series, onset_s, early_ticks: int) -> dict[str, np.ndarray]:
    """Every candidate score of each push (higher = more likely to fall); the "early_" ones
    read only the first early_ticks ticks (before most falls: a prediction, not a record)."""
    full = jax.tree_util.tree_map(jnp.asarray, series)
    early = jax.tree_util.tree_map(lambda x: x[:, :early_ticks], full)
    onset = jnp.asarray(onset_s, jnp.float32)
    out = {}
    for prefix, s in (("", full), ("early_", early)):
        for name, cfg in VARIANTS.items():
            out[prefix + name] = np.asarray(
                jax.jit(lambda a, b, c=cfg: batched_margin(a, b, c))(s, onset))
        soft = jax.jit(jax.vmap(lambda a, b: push_loss(a, b, LossConfig())))(s, onset)
        out[prefix + "soft_fall_term"] = np.asarray(soft["fall"])
        out[prefix + "soft_total"] = np.asarray(soft["total"])
    return out


def run_set(pushes: Push, duration_s: float, controllers: dict, early_ticks: int) -> dict:
    """{controller: dict(fell, diverged, scores)} on one push set."""
    cfg = RolloutConfig(duration_s=duration_s)
    res = {}
    for name, (enabled, params, schedule) in controllers.items():
        t0 = time.time()
        series, out = simulate_mujoco(pushes, enabled, params, config=cfg, n_threads=1,
                                      schedule=schedule)
        res[name] = dict(fell=np.asarray(out.fell), diverged=np.asarray(out.diverged),
                         scores=scores(series, pushes.onset_s, early_ticks))
        print(f"  {name}: {time.time() - t0:.1f} s, fell {res[name]['fell'].mean():.3f}",
              flush=True)
    return res


def aucs(res: dict) -> dict:
    """AUC of every score per controller and pooled over controllers (diverged left out)."""
    table = {}
    names = list(next(iter(res.values()))["scores"])
    for ctrl, r in {**res, "pooled": None}.items():
        if r is None:
            r = {k: np.concatenate([v[k] for v in res.values()]) for k in ("fell", "diverged")}
            r["scores"] = {s: np.concatenate([v["scores"][s] for v in res.values()])
                           for s in names}
        keep = ~r["diverged"]
        table[ctrl] = dict(n=int(keep.sum()), fell=int(r["fell"][keep].sum()),
                           **{s: roc_auc(r["scores"][s][keep], r["fell"][keep]) for s in names})
    return table


def figure(res: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ctrl, r in res.items():
        for s, style in (("margin", "-"), ("soft_fall_term", ":")):
            fpr, tpr = roc_curve(r["scores"][s], r["fell"])
            auc = roc_auc(r["scores"][s], r["fell"])
            axes[0].plot(fpr, tpr, style, label=f"{ctrl} {s} AUC {auc:.3f}")
        m = r["scores"]["margin"] * 100
        axes[1].scatter(m, r["fell"] + 0.08 * (list(res).index(ctrl) - 1), s=6, label=ctrl)
    axes[0].set(xlabel="false positive rate", ylabel="true positive rate",
                title="held-out pushes: ROC against the hard fall")
    axes[0].legend(fontsize=7)
    axes[1].set(xlabel="DCM margin (cm)", ylabel="fell (jittered by controller)",
                title="margin by outcome")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--n-dev", type=int, default=128)
    ap.add_argument("--duration", type=float, default=1.5)
    ap.add_argument("--early-s", type=float, default=0.6,
                    help="the early scores read the series up to this time (s; onsets 0.30-0.33)")
    a = ap.parse_args()
    early_ticks = int(round(a.early_s / CONTROL_PERIOD_S))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    pol_params, pol_schedule = recommended_policy()
    controllers = {"recommended": (1.0, ControllerParams.recommended(), None),
                   "policy": (1.0, pol_params, pol_schedule),
                   "off": (0.0, ControllerParams.recommended(), None)}
    result = dict(duration_s=a.duration, early_s=a.early_s, variants={k: dataclasses.asdict(v)
                                                   for k, v in VARIANTS.items()})
    sets = {"dev": (a.n_dev, 101), "held_out": (a.n, 202)}
    for name, (n, seed) in sets.items():
        print(name, flush=True)
        res = run_set(sample_pushes(n, seed), a.duration, controllers, early_ticks)
        result[name] = dict(seed=seed, n=n, auc=aucs(res))
        if name == "held_out":
            figure(res, out / "margin_auc.png")
    (out / "margin_auc.json").write_text(json.dumps(result, indent=1) + "\n")
    for name in sets:
        for ctrl, row in result[name]["auc"].items():
            print(name, ctrl, {k: (round(v, 4) if isinstance(v, float) else v)
                               for k, v in row.items()})


if __name__ == "__main__":
    main()
