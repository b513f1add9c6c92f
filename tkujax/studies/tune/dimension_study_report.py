"""The dimension study's summary: the held-out fall rate per (parameters, method) pooled over
seeds (`aggregate`), the method recommended per dimension, study.md and the study's plots."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

def aggregate(rows: list[dict], key: str = "heldout_fall") -> dict:
    """{(n_params, policy): {method: (mean, sd, n)}} over seeds."""
    agg: dict = {}
    for r in rows:
        v = r.get(key)
        if v is None or not math.isfinite(v):
            continue
        agg.setdefault((r["n_params"], r["policy"]), {}).setdefault(r["method"], []).append(v)
    return {k: {m: (float(np.mean(v)), float(np.std(v, ddof=1)) if len(v) > 1 else 0.0,
                    len(v)) for m, v in ms.items()} for k, ms in sorted(agg.items())}


def recommend_methods(rows: list[dict], key: str = "heldout_fall") -> dict[int, str]:
    """Per parameter count: the method with the lowest mean fall rate over seeds."""
    return {n: min(ms, key=lambda m: ms[m][0]) for (n, _), ms in aggregate(rows, key).items()}


def study_markdown(rows: list[dict], spec=None) -> str:
    devices = sorted({r["device"] for r in rows if r.get("device")})
    lines = ["# tkujax tune: dimension study", ""]
    if spec is not None:
        s = spec.study
        lines += [f"Spec {spec.name}: policies {s['policies']}, methods {s['methods']}, seeds "
                  f"{s['seeds']}, {s['budget_s']:g} s of wall clock per run (compile "
                  f"{'included' if s.get('budget_includes_compile') else 'excluded'}), batch "
                  f"{spec.batch} pushes x {spec.duration_s} s"
                  + ("; the seeds of one policy and method side by side, sharing one device "
                     "and one budget (study.seeds_side_by_side)." if s.get("seeds_side_by_side")
                     else "; one run after another, each with the device alone."), ""]
    lines += [f"Devices: {', '.join(devices) or '-'}. Runs finished: {len(rows)}.", ""]
    shares: dict[int, int] = {}
    for r in rows:
        k = int(r.get("side_by_side") or 1)       # rows from before the option: alone
        shares[k] = shares.get(k, 0) + 1
    if any(k > 1 for k in shares):
        parts = [f"{c} run(s) " + ("had the device alone" if k == 1 else
                                   f"shared it {k} ways ({k} seeds side by side)")
                 for k, c in sorted(shares.items())]
        lines += ["Device sharing (`side_by_side`): " + "; ".join(parts) + ". Seeds side by "
                  "side run in lockstep in one batch and share one wall-clock budget, so each "
                  "seed had a share of the device (about 1/S to 1/2 of it for S seeds), the same "
                  "for every method of a group size: compare methods at equal sharing.", ""]
    for key, title in (("heldout_fall", "Held-out fall rate (training distribution)"),
                       ("shifted_fall", "Shifted held-out fall rate"),
                       ("above_fall", "Fall rate above the training impulses")):
        agg = aggregate(rows, key)
        if not agg:
            continue
        methods = sorted({m for ms in agg.values() for m in ms})
        # The start once per policy and seed (every run of a seed evaluates it on the same
        # pushes).
        firsts = {(r["policy"], r["seed"]): r for r in rows}
        start = aggregate([dict(r, method="start", **{key: r.get("start_" + key)})
                           for r in firsts.values()], key)
        lines += [f"## {title}", "", "mean ± sd over seeds (n); start = the search's start "
                  "(the spec's controller, or its tune.start_policy) on the same pushes.", "",
                  "| policy | n_params | start | " + " | ".join(methods) + " |",
                  "|---|---|---|" + "---|" * len(methods)]
        for (n, pol), ms in agg.items():
            st = start.get((n, pol), {}).get("start")
            cell = lambda v: (f"{100 * v[0]:.1f} ± {100 * v[1]:.1f} % ({v[2]})"  # noqa: E731
                              if v else "-")
            lines.append(f"| {pol} | {n} | {cell(st)} | "
                         + " | ".join(cell(ms.get(m)) for m in methods) + " |")
        lines.append("")
    rec = recommend_methods(rows)
    if rec:
        lines += ["## Method per size (lowest mean held-out fall rate)", "",
                  "| n_params | method |", "|---|---|"]
        lines += [f"| {n} | {m} |" for n, m in rec.items()]
        lines.append("")
    return "\n".join(lines)


def plot_study(out: Path, rows: list[dict], runs: list[dict]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = sorted({r["method"] for r in rows})
    colors = {m: f"C{i}" for i, m in enumerate(methods)}
    fig, ax = plt.subplots(figsize=(6, 4.2))
    for key, style in (("heldout_fall", "-o"), ("shifted_fall", "--s")):
        agg = aggregate(rows, key)
        for m in methods:
            pts = sorted((n, v[m][0], v[m][1]) for (n, _), v in agg.items() if m in v)
            if pts:
                n, y, e = map(np.array, zip(*pts))
                ax.errorbar(n, 100 * y, 100 * e, fmt=style, color=colors[m], capsize=3,
                            label=f"{m} ({key.split('_')[0]})")
    ax.set_xscale("log")
    _label(ax, "parameters tuned", "fall rate (%)")
    _save(fig, out / "study.png")

    policies = list(dict.fromkeys(r["policy"] for r in sorted(runs, key=lambda r: r["n_params"])))
    fig, axes = plt.subplots(1, len(policies), figsize=(4 * len(policies), 3.6), squeeze=False)
    for ax, pol in zip(axes[0], policies):
        seen = set()
        for r in runs:
            if r["policy"] != pol or not r.get("curve"):
                continue
            t = [p["wall_s"] for p in r["curve"]]
            y = [p["best_loss"] for p in r["curve"]]
            ax.step(t, y, where="post", color=colors.get(r["method"], "k"), alpha=0.8,
                    label=None if r["method"] in seen else r["method"])
            seen.add(r["method"])
        ax.set_title(f"{pol} ({next(r['n_params'] for r in runs if r['policy'] == pol)} "
                     "params)", fontsize=9)
        _label(ax, "wall clock (s, compile excluded)", "best hard training loss")
    _save(fig, out / "convergence.png")

    # The gradient methods keep their best iterate, so the curves above cannot show a descent
    # that goes the wrong way: the hard loss of every Adam iterate (extra.iterate_loss) can.
    its = [r for r in runs if r.get("extra", {}).get("iterate_loss")]
    if its:
        fig, ax = plt.subplots(figsize=(6, 4.2))
        for i, r in enumerate(sorted(its, key=lambda r: (r["n_params"], r["method"],
                                                          r["seed"]))):
            label = f"{r['policy']} {r['method']} s{r['seed']}"
            if r.get("push_clip"):
                label += f" (push_clip {r['push_clip']:g})"
            ax.plot(r["extra"]["iterate_loss"], "-o", ms=3, color=f"C{i % 10}", label=label)
        _label(ax, "Adam iteration", "hard training loss of the iterate")
        _save(fig, out / "iterates.png")


def _label(ax, xlabel: str, ylabel: str) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)


def _save(fig, path: Path) -> None:
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def comparison_runs(runs: list[dict]) -> list[dict]:
    """summary_runs.json: per run method, kind ("gradient": the method uses the first-order
    gradient, else "zeroth"), policy, n_params, seed, wall_s (compile included: the charged
    compile with study.budget_includes_compile, else the measured warm-up, plus the search),
    heldout_fall, device."""
    from tkujax.studies.tune.searchers import SEARCHERS

    out = []
    for r in sorted(runs, key=lambda r: (r["n_params"], r["method"], r["seed"])):
        cls = SEARCHERS.get(r["method"])
        wall = r["wall_s"] if r.get("budget_includes_compile") else (
            (r.get("compile_s") or 0.0) + (r.get("wall_s") or 0.0))
        out.append(dict(method=r["method"],
                        kind="gradient" if cls is not None and cls.uses_gradient else "zeroth",
                        policy=r.get("policy"), n_params=r["n_params"], seed=r["seed"],
                        wall_s=round(float(wall), 3), heldout_fall=r.get("heldout_fall"),
                        device=r.get("device")))
    return out


def plot_heldout_vs_wall(out: Path, runs: list[dict]) -> None:
    """heldout_vs_wall.png: held-out fall rate of the best-so-far against wall clock (compile
    included), one panel per policy (size), one colour per method, one line per seed (runs
    without a held-out curve: their final point only)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    methods = sorted({r["method"] for r in runs})
    colors = {m: f"C{i}" for i, m in enumerate(methods)}
    policies = list(dict.fromkeys(r["policy"] for r in sorted(runs, key=lambda r: r["n_params"])))
    fig, axes = plt.subplots(1, len(policies), figsize=(4 * len(policies), 3.6), squeeze=False)
    finals = {(e["policy"], e["method"], e["seed"]): e for e in comparison_runs(runs)}
    for ax, pol in zip(axes[0], policies):
        seen = set()
        for r in (r for r in runs if r["policy"] == pol):
            pts = r.get("heldout_curve") or [dict(
                wall_s=finals[(pol, r["method"], r["seed"])]["wall_s"],
                heldout_fall=r.get("heldout_fall"))]
            t = [0.0] + [p["wall_s"] for p in pts]
            y = [r.get("start_heldout_fall")] + [p["heldout_fall"] for p in pts]
            ax.plot(t, [100 * v if v is not None else np.nan for v in y], "-o", ms=3,
                    drawstyle="steps-post", color=colors[r["method"]], alpha=0.8,
                    label=None if r["method"] in seen else r["method"])
            seen.add(r["method"])
        for b in {r.get("budget_s") for r in runs if r["policy"] == pol} - {None}:
            ax.axvline(b, color="0.5", ls=":", lw=1)                    # the budget
        ax.set_title(f"{pol} ({next(r['n_params'] for r in runs if r['policy'] == pol)} "
                     "params)", fontsize=9)
        _label(ax, "wall clock (s, compile included)", "held-out fall rate (%)")
    _save(fig, out / "heldout_vs_wall.png")


def plot_validation_vs_wall(out: Path, runs: list[dict]) -> None:
    """validation_vs_wall.png (runs with study.select = "validation"): the hard fall rate of
    each method's INCUMBENT (the Adam iterate, the CMA-ES mean) on the validation pushes as
    the search goes, the mean over seeds, one panel per policy: where a method's steps lead,
    not only what it returns (the best of these, the start included)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = [r for r in runs if r.get("selection_curve")]
    if not runs:
        return
    methods = sorted({r["method"] for r in runs})
    colors = {m: f"C{i}" for i, m in enumerate(methods)}
    policies = list(dict.fromkeys(r["policy"] for r in sorted(runs, key=lambda r: r["n_params"])))
    fig, axes = plt.subplots(1, len(policies), figsize=(4 * len(policies), 3.6), squeeze=False)
    for ax, pol in zip(axes[0], policies):
        for m in methods:
            curves = [r["selection_curve"] for r in runs
                      if r["policy"] == pol and r["method"] == m]
            if not curves:
                continue
            n = min(len(c) for c in curves)
            t = np.mean([[p["wall_s"] for p in c[:n]] for c in curves], axis=0)
            y = np.mean([[p["fall"] for p in c[:n]] for c in curves], axis=0)
            ax.plot(t, 100 * y, "-o", ms=3, color=colors[m], label=f"{m} ({len(curves)} seeds)")
        ax.set_title(f"{pol} ({next(r['n_params'] for r in runs if r['policy'] == pol)} "
                     "params)", fontsize=9)
        _label(ax, "search clock (s, after the compile)", "incumbent's validation fall (%)")
    _save(fig, out / "validation_vs_wall.png")
