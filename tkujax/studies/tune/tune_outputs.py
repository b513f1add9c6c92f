"""Tuning outputs a person reads: the convergence and evaluation plots, summary.md."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from tkujax.studies.tune.reparam import TUNABLE
from tkujax.studies.tune.tune_spec import parse_tune_spec


def plot_outputs(out: Path, rec: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = rec["run"]["curve"]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    axes[0].step([p["wall_s"] for p in curve], [p["best_loss"] for p in curve], where="post")
    axes[0].set_xlabel("wall clock (s, compile excluded)")
    axes[1].step([p["pushes"] for p in curve], [p["best_loss"] for p in curve], where="post")
    axes[1].set_xlabel("pushes simulated")
    for ax in axes:
        ax.set_ylabel("best hard-gate training loss")
        ax.grid(alpha=0.3)
    fig.suptitle(f"tkujax tune {rec['name']}: {rec['method']}, {rec['batch']} pushes x "
                 f"{rec['duration_s']} s ({', '.join(rec['devices'])})", fontsize=9)
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
            for name, mk in (("before", "k^-"), ("after", "C0o-")):
                if name in ev and "grid_fell" in ev[name]:
                    fell = np.asarray(ev[name]["grid_fell"], float)[sel]
                    ax.plot(J.ravel()[sel], fell, mk, ms=4,
                            label="paper" if name == "before" else f"tuned ({rec['method']})")
            ax.set_title(f"azimuth {a:g} deg (hard gate)", fontsize=9)
            ax.set_xlabel("impulse (N·s)")
            ax.set_ylabel("fell")
            ax.set_ylim(-0.1, 1.1)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "evaluation.png", dpi=90)
        plt.close(fig)


def summary_markdown(rec: dict, comparison: dict | None = None) -> str:
    run = rec["run"]
    lines = [f"# tkujax tune `{rec['name']}`", "",
             f"Method **{rec['method']}**: {run['iterations']} iterations, "
             f"{run['curve'][-1]['pushes']:,} pushes simulated, compile {run['compile_s']} s; "
             f"{rec['batch']} training pushes x {rec['duration_s']} s; devices "
             f"{', '.join(rec['devices'])}; total wall {rec['wall_s']} s.", "",
             "## Parameters (user units)", "", "| parameter | range | paper | tuned |",
             "|---|---|---|---|"]
    for f in rec["tuned"]:
        lo, hi = rec["ranges_user_units"][f]
        lines.append(f"| {f} ({TUNABLE[f][3] or '-'}) | [{lo:g}, {hi:g}] | "
                     f"{rec['params_user']['before'][f]:.4g} | "
                     f"{rec['params_user']['after'][f]:.4g} |")
    dec = rec.get("recommendation")
    if dec:
        lines[4:4] = ["## Recommendation (params_after.json)", "",
                      f"**{_first_upper(dec['reason'])}.**"
                      + ("" if dec["recommended"] == "after" else
                         " params_after.json is the starting set (`recommended_from`: start); "
                         "the search's result is in params_tuned.json."), "",
                      f"Rule: {dec['rule']}.", ""]
    ens = rec.get("ensembles") or {}
    w_harm = rec.get("spec", {}).get("tune", {}).get("loss", {}).get("w_harm", 0.0)
    setup = (["Robots: " + "; ".join(
        f"{k} = {v['path']} ({v['n']} members, sha256 {v['sha256'][:12]}…)"
        for k, v in ens.items()) + "; the other sets run on the default robot."] if ens else [])
    setup += ([f"Harm weight w_harm = {w_harm:g}: a push survived with control off counts "
               f"{1 + w_harm:g} times in the loss."] if w_harm else [])
    if setup:
        lines[4:4] = [" ".join(setup), ""]
    ev = rec["evaluation"]
    if ev:
        azs = sorted({a for v in ev.values() for a in v.get("max_impulse", {})}, key=float)
        lines += ["", "## Held-out evaluation (hard controller)", "",
                  "| parameters | held-out fall rate | recovered | held-out loss (+- s.e.) | "
                  "grid fall rate | " + " | ".join(f"max J @ {a} deg (N·s)" for a in azs) + " |",
                  "|---|---|---|---|---|" + "---|" * len(azs)]
        for n in ("before", "after"):
            v = ev.get(n, {})
            lines.append(
                f"| {'paper' if n == 'before' else 'tuned'} | {_pct(v.get('heldout_fall_rate'))} "
                f"| {v.get('heldout_recovered', '-')}/{v.get('heldout_n', '-')}"
                + (f" ({v['heldout_diverged']} diverged, left out)" if v.get("heldout_diverged")
                   else "") + " | "
                f"{_mean_se(v.get('heldout_push_loss'))} | {_pct(v.get('grid_fall_rate'))} | "
                + " | ".join(f"{v.get('max_impulse', {}).get(a, float('nan')):.2f}" for a in azs)
                + " |")
        if ev.get("after", {}).get("heldout_harmed_rate") is not None:
            b, a = ev.get("before", {}), ev["after"]
            lines += ["", f"Harm (held-out pushes, n = {a['heldout_harm_n']}): control "
                      f"off falls {_pct(a['heldout_off_fall_rate'])}; pushes that fall with "
                      f"control but not without: start {_pct(b.get('heldout_harmed_rate'))}, "
                      f"tuned {_pct(a['heldout_harmed_rate'])}."]
        if "heldout_fell" in ev.get("after", {}):
            d = (np.asarray(ev["after"]["heldout_fell"], float)
                 - np.asarray(ev["before"]["heldout_fell"], float))
            se = d.std(ddof=1) / math.sqrt(d.size) if d.size > 1 else float("nan")
            lines += ["", f"Paired held-out fall difference tuned - paper: "
                      f"{100 * d.mean():+.2f} +- {100 * se:.2f} pp (s.e., n = {d.size})"
                      + (" — significant." if d.mean() < -2 * se else " — not significant.")]
            lines += _by_direction(rec)
    lines += _shifted_section(rec)
    lines += gradient_section(rec["run"].get("gradient_diagnostics"))
    if comparison is not None:
        from tkujax.studies.tune.method_compare import compare_markdown

        lines += ["", compare_markdown(comparison).replace("# tkujax tune: method", "## Method")]
    return "\n".join(lines) + "\n"


def _by_direction(rec: dict) -> list[str]:
    """Held-out fall rate per direction sector (tkujax.analysis.compare's sectors: 0 deg =
    pushed from behind), before and after: a gain from behind must not hide a loss in front."""
    from tkujax.analysis.compare import SECTOR_NAMES, sector_index
    from tkujax.studies.tune.tune_spec import sample_pushes

    ev = rec["evaluation"]
    spec = parse_tune_spec(rec["spec"])
    az = sample_pushes(spec, spec.eval_n, spec.eval_seed)["azimuth_deg"]
    sector = sector_index(az, 4)
    rows = {}
    for name in ("before", "after"):
        v = ev.get(name, {})
        div = np.asarray(v.get("heldout_push_diverged", np.zeros(len(az), bool)), bool)
        if "heldout_fell" not in v or div.size != az.size:
            return []
        fell = np.full(az.size, np.nan)
        fell[~div] = np.asarray(v["heldout_fell"], float)
        rows[name] = fell
    out = ["", "Held-out fall rate by direction (pushes):", "",
           "| parameters | " + " | ".join(f"from {s}" for s in SECTOR_NAMES[4]) + " |",
           "|---|---|---|---|---|"]
    for name, fell in rows.items():
        cells = []
        for k in range(4):
            f = fell[(sector == k) & np.isfinite(fell)]
            cells.append(f"{100 * f.mean():.1f}% ({f.size})" if f.size else "-")
        out.append(f"| {'paper' if name == 'before' else 'tuned'} | " + " | ".join(cells) + " |")
    return out


def _shifted_section(rec: dict) -> list[str]:
    """The start and the tuned set on the shifted held-out pushes ([evaluate.shift])."""
    ev = rec.get("evaluation_shifted") or {}
    b, a = ev.get("before", {}), ev.get("after", {})
    if a.get("heldout_fall_rate") is None or b.get("heldout_fall_rate") is None:
        return []
    out = ["", "## Shifted held-out evaluation ([evaluate.shift], hard controller)", "",
           "| parameters | fall rate | recovered | loss (+- s.e.) | harmed |",
           "|---|---|---|---|---|"]
    for name, v in (("start", b), ("tuned", a)):
        out.append(f"| {name} | {_pct(v.get('heldout_fall_rate'))} | "
                   f"{v.get('heldout_recovered', '-')}/{v.get('heldout_n', '-')} | "
                   f"{_mean_se(v.get('heldout_push_loss'))} | "
                   f"{_pct(v.get('heldout_harmed_rate'))} |")
    fell = []
    for v in (b, a):
        div = np.asarray(v.get("heldout_push_diverged", []), bool)
        f = np.full(div.size, np.nan)
        f[~div] = np.asarray(v["heldout_fell"], float)
        fell.append(f)
    if fell[0].size == fell[1].size:
        d = fell[1] - fell[0]
        d = d[np.isfinite(d)]
        if d.size > 1:
            se = d.std(ddof=1) / math.sqrt(d.size)
            out += ["", f"Paired fall difference tuned - start: {100 * d.mean():+.2f} +- "
                    f"{100 * se:.2f} pp (s.e., n = {d.size})."]
    return out


def gradient_section(diag: dict | None) -> list[str]:
    """summary.md's gradient diagnostics (search.OneSeedCalls.record): per-push gradients'
    half-batch cosine, top-5 share and median norm (first, median and last call), and the
    checked steps' predicted against measured change of the differentiated loss."""
    if not diag or not diag["per_call"]:
        return []
    calls = diag["per_call"]
    cos = np.array([c["half_cosine"] for c in calls], float)
    top = np.array([c["top_share"] for c in calls], float)
    med = np.array([c["norm_quantiles"]["0.5"] if "0.5" in c["norm_quantiles"]
                    else c["norm_quantiles"][0.5] for c in calls], float)
    out = ["", "## Gradient diagnostics (per-push gradients, training batch)", "",
           f"{len(calls)} gradient calls"
           + (f", bundled (sigma {diag['bundle_sigma']:g}"
              f"{', antithetic' if diag['bundle_antithetic'] else ''})"
              if diag["bundle_sigma"] else "")
           + f"; diagnostics took {diag['diagnostics_s']} s of the budget.", "",
           "| | first | median | last |", "|---|---|---|---|"]
    for name, v in (("half-batch cosine", cos), ("top-5 share of |g|^2", top),
                    ("median per-push norm", med)):
        out.append(f"| {name} | {v[0]:.3g} | {np.nanmedian(v):.3g} | {v[-1]:.3g} |")
    checks = diag["step_checks"]
    if checks:
        out += ["", f"Steps checked every {diag['diagnose_every']} gradient calls (soft-gate "
                "loss, same batch):", "", "| call | step norm | cos(step, -g) | predicted | "
                "measured |", "|---|---|---|---|---|"]
        out += [f"| {c['call']} | {c['step_norm']:.3g} | {c['cos_step_neg_grad']:.3f} | "
                f"{c['predicted']:+.4g} | {c['measured']:+.4g} |" for c in checks]
    return out


def _first_upper(text: str) -> str:
    return text[:1].upper() + text[1:]


def _mean_se(x) -> str:
    if not x:
        return "-"
    x = np.asarray(x, float)
    se = np.std(x, ddof=1) / math.sqrt(x.size) if x.size > 1 else float("nan")
    return f"{x.mean():.4f} +- {se:.4f}"


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f}%"
