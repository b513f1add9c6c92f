"""Tuning outputs a person reads: plots, summary.md and the verdict."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tkujax.studies.tune.reparam import TUNABLE
from tkujax.studies.tune.spec import parse_tune_spec


def _plot(out: Path, rec: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hist = rec["history"]
    it_pushes = [r["pushes_simulated"] for r in hist]
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    ax = axes[0]
    ax.plot(it_pushes, [np.nan if r["loss"] is None else r["loss"] for r in hist], "o-",
            label="gradient (Adam): loss at the current gate temperature")
    skipped = [r for r in hist if r["skipped"]]
    if skipped:
        ax.plot([r["pushes_simulated"] for r in skipped], [0] * len(skipped), "rx", ms=9,
                label="skipped (non-finite gradient)")
    es = rec["baseline"]["rows"]
    if es:
        ax.plot([r["pushes_simulated"] for r in es],
                [np.nan if r["best_loss"] is None else r["best_loss"] for r in es], "s-",
                label=f"(1+1)-ES best loss (tau {rec['baseline']['gate_temperature_deg']:g} deg)")
    tl = rec["train_loss"]
    for name, style in (("before", "k:"), ("gradient", "C0--"), ("baseline", "C1--")):
        if name in tl and tl[name]["hard"] is not None:
            ax.axhline(tl[name]["hard"], ls=style[2:] or ":", color=style[:2] if style[0] == "C"
                       else "k", lw=0.8, label=f"{name}: hard-gate training loss")
    ax.set_xlabel("pushes simulated")
    ax.set_ylabel("loss")
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(0.0, -0.18), ncol=2)
    ax.grid(alpha=0.3)
    ax = axes[1]
    ax.semilogy([r["iteration"] + 1 for r in hist],
                [np.nan if not r["grad_norm"] or not math.isfinite(r["grad_norm"])
                 else max(r["grad_norm"], 1e-12) for r in hist], "o-", label="|grad| (latent)")
    ax.set_xlabel("iteration")
    ax.set_ylabel("gradient norm")
    ax2 = ax.twinx()
    ax2.plot([r["iteration"] + 1 for r in hist], rec["temperatures_deg"], "g--", lw=1,
             label="gate temperature")
    ax2.set_ylabel("gate temperature (deg)", color="g")
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    fig.suptitle(f"tkujax tune {rec['name']}: {rec['batch']} pushes x {rec['duration_s']} s",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "loss_curve.png", dpi=90)
    plt.close(fig)

    ev = rec["evaluation"]
    if ev and any("grid_fell" in v for v in ev.values()):
        spec = parse_tune_spec(rec["spec"])
        J, A = np.meshgrid(spec.eval_impulse_ns, spec.eval_azimuth_deg, indexing="ij")
        azs = spec.eval_azimuth_deg
        fig, axes = plt.subplots(1, len(azs), figsize=(4.2 * len(azs), 3.4), squeeze=False)
        for i, a in enumerate(azs):
            ax = axes[0, i]
            sel = A.ravel() == a
            for name, mk in (("before", "k^-"), ("gradient", "C0o-"), ("baseline", "C1s-")):
                if name in ev and "grid_fell" in ev[name]:
                    fell = np.asarray(ev[name]["grid_fell"], float)[sel]
                    ax.plot(J.ravel()[sel], fell, mk, ms=4, label=name)
            ax.set_title(f"azimuth {a:g} deg (hard gate)", fontsize=9)
            ax.set_xlabel("impulse (N·s)")
            ax.set_ylabel("fell")
            ax.set_ylim(-0.1, 1.1)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "evaluation.png", dpi=90)
        plt.close(fig)


def summary_markdown(rec: dict) -> str:
    hist = rec["history"]
    names = [n for n in ("before", "gradient", "baseline") if n in rec["params_user"]]
    lines = [f"# tkujax tune `{rec['name']}`", "",
             f"{rec['batch']} training pushes x {rec['duration_s']} s, {rec['iterations']} "
             f"iterations, float64 = {rec['float64']}, remat = {rec['remat']}; devices "
             f"{', '.join(rec['devices'])}. Gate temperature annealed "
             f"{rec['temperatures_deg'][0]:.2f} -> {rec['temperatures_deg'][-1]:.2f} deg. "
             f"Simulated pushes: gradient {rec['pushes_simulated']['gradient']} (each with a "
             f"backward pass), baseline {rec['pushes_simulated']['baseline']} (forward only). "
             f"Wall: gradient {rec['wall_s']['gradient']} s (first iteration incl. compile "
             f"{rec['wall_s']['first_iteration_incl_compile']} s), baseline "
             f"{rec['wall_s']['baseline']} s, total {rec['wall_s']['total']} s.", "",
             "## Parameters (user units)", "",
             "| parameter | range | " + " | ".join(names) + " |",
             "|---|---|" + "---|" * len(names)]
    for f in rec["tuned"]:
        lo, hi = rec["ranges_user_units"][f]
        unit = TUNABLE[f][3]
        lines.append(f"| {f} ({unit or '-'}) | [{lo:g}, {hi:g}] | "
                     + " | ".join(f"{rec['params_user'][n][f]:.4g}" for n in names) + " |")
    tl = rec["train_loss"]
    lines += ["", "## Loss on the training batch (same pushes for all)", "",
              "| parameters | soft (final temperature) | soft (baseline's temperature) | "
              "hard gate |", "|---|---|---|---|"]
    fmt = lambda v: "-" if v is None else f"{v:.4f}"  # noqa: E731
    for n in names:
        lines.append(f"| {n} | {fmt(tl[n]['final_temperature'])} | "
                     f"{fmt(tl[n]['baseline_temperature'])} | {fmt(tl[n]['hard'])} |")
    ev = rec["evaluation"]
    if ev:
        azs = sorted({a for v in ev.values() for a in v.get("max_impulse", {})}, key=float)
        lines += ["", "## Held-out evaluation (hard controller, gate_temperature = 0)", "",
                  "Held-out pushes: same distribution, another seed, never used for tuning. "
                  "Max recoverable impulse: largest grid impulse below which every grid push of "
                  "that azimuth was survived.", "",
                  "| parameters | held-out fall rate | mean recovery (s) of the recovered | "
                  "recovered | held-out loss (+- s.e.) | grid fall rate | " + " | ".join(f"max J @ {a} deg (N·s)" for a in azs)
                  + " |", "|---|---|---|---|---|---|" + "---|" * len(azs)]
        for n in names:
            v = ev.get(n, {})
            lines.append(
                f"| {n} | {_pct(v.get('heldout_fall_rate'))} | "
                f"{fmt(v.get('heldout_mean_recovery_s'))} | "
                f"{v.get('heldout_recovered', '-')}/{v.get('heldout_n', '-')}"
                + (f" ({v['heldout_diverged']} diverged, left out)" if v.get("heldout_diverged")
                   else "") + " | "
                f"{_mean_se(v.get('heldout_push_loss'))} | {_pct(v.get('grid_fall_rate'))} | "
                + " | ".join(f"{v.get('max_impulse', {}).get(a, float('nan')):.2f}" for a in azs)
                + " |")
    gn = np.array([r["grad_norm"] for r in hist if r["finite"]], float)
    zero_frac = {}
    if hist and any(r["finite"] for r in hist):
        g = np.array([r["grad"] for r in hist if r["finite"]], float)
        zero_frac = {f: float(np.mean(np.abs(g[:, i]) < 1e-9)) for i, f in
                     enumerate(rec["tuned"])}
    lines += ["", "## Gradient diagnostics", "",
              f"Non-finite gradients: {rec['n_skipped']} of {len(hist)} iterations skipped "
              f"(iterations {rec['skipped_steps'] or 'none'}). Gradient norm (latent units): "
              + (f"median {np.median(gn):.3g}, min {gn.min():.3g}, max {gn.max():.3g}; clip at "
                 f"{rec['spec'].get('tune', {}).get('clip_norm', 1.0)}." if gn.size else "none")
              + " Share of iterations with an exactly-zero component: "
              + ", ".join(f"{f} {100 * v:.0f}%" for f, v in zero_frac.items()) + "."]
    lines += ["", "## Verdict", "", verdict(rec)]
    return "\n".join(lines) + "\n"


def _mean_se(x) -> str:
    if not x:
        return "-"
    x = np.asarray(x, float)
    se = np.std(x, ddof=1) / math.sqrt(x.size) if x.size > 1 else float("nan")
    return f"{x.mean():.4f} +- {se:.4f}"


def _paired(ev: dict, a: str, b: str) -> tuple[float, float]:
    """Mean and standard error of the per-push held-out loss difference a - b."""
    d = np.asarray(ev[a]["heldout_push_loss"]) - np.asarray(ev[b]["heldout_push_loss"])
    se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else float("nan")
    return float(np.mean(d)), se


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f}%"


def verdict(rec: dict) -> str:
    """One honest paragraph: did the gradient beat the baseline and the start point?"""
    tl, ev = rec["train_loss"], rec["evaluation"]
    if "baseline" not in tl:
        return "No baseline was run."
    g, b, s = (tl[n]["hard"] for n in ("gradient", "baseline", "before"))
    parts = [f"Hard-gate training loss: before {s:.4f}, gradient {g:.4f}, baseline {b:.4f}."]
    better_train = g is not None and b is not None and g < b
    if ev and "heldout_loss" in ev.get("gradient", {}):
        hg, hb, hs = (ev[n]["heldout_loss"] for n in ("gradient", "baseline", "before"))
        fg, fb, fs = (ev[n]["heldout_fall_rate"] for n in ("gradient", "baseline", "before"))
        parts.append(f"Held-out hard loss: before {hs:.4f}, gradient {hg:.4f}, baseline "
                     f"{hb:.4f}; held-out fall rate {_pct(fs)} / {_pct(fg)} / {_pct(fb)}.")
        better_held = hg < hb
        dm, dse = _paired(ev, "gradient", "baseline")
        parts.append(f"Paired per-push held-out loss difference gradient - baseline: "
                     f"{dm:+.4f} +- {dse:.4f} (s.e., n = {ev['gradient']['heldout_n']}).")
        if abs(dm) < 2 * dse:
            parts.append("That is within two standard errors: on this many held-out pushes the "
                         "two results are NOT distinguishable; the ordering stated next is not "
                         "significant.")
        if better_held and better_train:
            parts.append("The gradient result beats the gradient-free baseline on both the "
                         "training objective and the held-out pushes at equal simulated pushes.")
        elif better_held or better_train:
            parts.append("Mixed: the gradient result is better on "
                         + ("the held-out pushes" if better_held else "the training batch")
                         + " but not on " + ("the training batch" if better_held
                                             else "the held-out pushes") + ".")
        else:
            parts.append("The gradient result does NOT beat the gradient-free baseline.")
        gm, gse = _paired(ev, "gradient", "before")
        parts.append(f"Gradient - before (paired, held-out): {gm:+.4f} +- {gse:.4f}"
                     + (" (significant)." if gm < -2 * gse else " (not significant)."))
        if hg >= hs:
            parts.append("Gradient tuning did not improve on the starting (paper) parameters on "
                         "held-out pushes.")
    else:
        parts.append("The gradient result " + ("beats" if better_train else "does NOT beat")
                     + " the baseline on the training batch.")
    hist = rec["history"]
    n_fin = sum(r["finite"] for r in hist)
    parts.append(f"Diagnostics and caveats: {rec['n_skipped']} of {len(hist)} gradients were "
                 f"non-finite and skipped, {n_fin} applied; the recovery step's start is a "
                 "discrete event (the step weight crossing 1/2), so the gradient sees the step's "
                 "shape and length but not whether or when it is triggered, and contact "
                 "changes make MJX gradients noisy (see the gradient-norm panel of "
                 "loss_curve.png); the soft gate used during tuning is not the hard gate used "
                 "in the evaluation.")
    return " ".join(parts)
