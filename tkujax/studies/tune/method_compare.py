"""`[compare]`: every method x seed at one wall-clock budget, evaluated on held-out pushes of the
training distribution AND on a shifted distribution (model variations and contact heights
never used in training), with paired differences against the paper's values.

Per seed s: the training batch is drawn with seed tune.seed + s; the held-out pushes with
evaluate.seed + s (never equal to a training seed); the shifted pushes with evaluate.seed +
1000 + s. Every candidate (the paper's values and each method's best latent) is evaluated with
the hard controller on the same pushes and sensor-noise keys, so differences are paired per
push. The paired difference of a method against the paper is the mean over pushes of
fell(method) - fell(paper), with its standard error; seeds are then pooled (mean of the per-seed
differences, standard error over seeds).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from collections.abc import Callable

import jax
import numpy as np

from tkujax.studies.tune.problem import TuneProblem
from tkujax.studies.tune.search import SearchConfig, run_search
from tkujax.studies.tune.start_policy import start_latent
from tkujax.studies.tune.tune_spec import TuneSpec, ensembles_record, sample_pushes, shifted


def fell_rates(problem: TuneProblem, latents: dict, records: dict, keys, batch: int) -> dict:
    """{name: (n,) fell as float, NaN where the rollout diverged (never counted either way)}."""
    records = problem.with_off_survived(records, keys, batch)   # once for every candidate
    out = {}
    for name, z in latents.items():
        aux = problem.forward_padded(z, 0.0, records, keys, batch)
        fell = np.asarray(aux["outcomes"]["fell"], float)
        diverged = aux["outcomes"].get("diverged") if hasattr(aux["outcomes"], "get") else None
        if diverged is not None:
            fell = np.where(np.asarray(diverged, bool), np.nan, fell)
        out[name] = fell
    return out


def paired(a: np.ndarray, b: np.ndarray) -> tuple[float, float, int]:
    """Mean and standard error of a - b over pushes where both are defined; and that count."""
    d = a - b
    d = d[np.isfinite(d)]
    if d.size < 2:
        return float("nan"), float("nan"), int(d.size)
    return float(d.mean()), float(d.std(ddof=1) / math.sqrt(d.size)), int(d.size)


def run_compare(spec: TuneSpec, out: Path, problem: TuneProblem,
                log: Callable[[str], None] = print) -> dict:
    c = spec.compare
    reparam = spec.policy_reparam()
    z0 = start_latent(spec, reparam)
    cfg = SearchConfig(budget_s=c["budget_s"], popsize=c["popsize"], sigma0=c["sigma0"],
                       zo_sigma=c["zo_sigma"], groups=c["groups"],
                       learning_rate=c["learning_rate"], temperature_deg=c["temperature_deg"],
                       push_clip=c["push_clip"], ray_radius=c["ray_radius"],
                       ray_ratio=c["ray_ratio"])
    shift_spec = shifted(spec)
    runs, evals = [], []
    for s in c["seeds"]:
        train = sample_pushes(spec, spec.batch, spec.seed + s)
        keys = jax.random.split(jax.random.PRNGKey(spec.seed + s), spec.batch)
        latents = {"paper": z0}
        for m in c["methods"]:
            log(f"compare: seed {s}, method {m}, budget {cfg.budget_s:g} s ...")
            r = run_search(m, problem, z0, train, keys, cfg, seed=s, log=log)
            r["params_user"] = reparam.user(r["z_best"])
            runs.append(r)
            latents[m] = np.asarray(r["z_best"])
        ev = dict(seed=s)
        for label, sp, eseed in (("heldout", spec, spec.eval_seed + s),
                                 ("shifted", shift_spec, spec.eval_seed + 1000 + s)):
            if sp is None:
                continue
            recs = sample_pushes(sp, c["eval_n"], eseed)
            ekeys = jax.random.split(jax.random.PRNGKey(eseed), c["eval_n"])
            fell = fell_rates(problem, latents, recs, ekeys, spec.batch)
            ev[label] = {name: dict(fall_rate=float(np.nanmean(f)),
                                    diverged=int(np.sum(~np.isfinite(f))),
                                    vs_paper=dict(zip(("mean", "se", "n"),
                                                      paired(f, fell["paper"]))))
                         for name, f in fell.items()}
            log(f"  {label}: " + ", ".join(f"{k} {v['fall_rate']:.3f}"
                                           for k, v in ev[label].items()))
        evals.append(ev)
    pooled = _pool(evals, ["paper", *c["methods"]])
    record = dict(name=spec.name, config=dataclasses.asdict(cfg), methods=c["methods"],
                  seeds=c["seeds"], batch=spec.batch, duration_s=spec.duration_s,
                  tuned=list(reparam.fields), runs=runs, evaluations=evals, pooled=pooled,
                  winner=_winner(pooled, c["methods"]),
                  shift=None if spec.shift is None else _jsonable(spec.shift),
                  ensembles=ensembles_record(spec), model=dict(spec.model),
                  devices=[str(d) for d in jax.devices()])
    (out / "compare.json").write_text(json.dumps(record, indent=1, default=json_default))
    _plot_curves(out / "convergence.png", record)
    (out / "compare.md").write_text(compare_markdown(record))
    return record


def _pool(evals: list[dict], names: list[str]) -> dict:
    """Per label and name: the mean fall rate over seeds, and the paired difference against
    the paper pooled over seeds (mean of per-seed means; standard error over seeds)."""
    pooled = {}
    for label in ("heldout", "shifted"):
        if not all(label in e for e in evals):
            continue
        pooled[label] = {}
        for name in names:
            rates = np.array([e[label][name]["fall_rate"] for e in evals])
            diffs = np.array([e[label][name]["vs_paper"]["mean"] for e in evals])
            ses = np.array([e[label][name]["vs_paper"]["se"] for e in evals])
            k = len(diffs)
            # SE over seeds when there are several; with one seed, the within-seed SE.
            se = float(diffs.std(ddof=1) / math.sqrt(k)) if k > 1 else float(ses[0])
            # Within-seed SEs combined (pushes are independent across seeds): a second,
            # usually tighter, view of the same difference.
            se_push = float(math.sqrt(np.nansum(ses ** 2)) / k)
            pooled[label][name] = dict(fall_rate=float(rates.mean()), diff_vs_paper=float(
                diffs.mean()), se_over_seeds=se, se_over_pushes=se_push)
    return pooled


def _winner(pooled: dict, methods: list[str]) -> str | None:
    """The method with the lowest pooled fall rate on the shifted set (held-out if none)."""
    label = "shifted" if "shifted" in pooled else "heldout"
    if label not in pooled:
        return None
    return min(methods, key=lambda m: pooled[label][m]["fall_rate"])


def compare_markdown(rec: dict) -> str:
    lines = [f"# tkujax tune: method comparison ({rec['name']})", "",
             f"Devices: {', '.join(rec['devices'])}. Batch {rec['batch']} pushes x "
             f"{rec['duration_s']} s; budget {rec['config']['budget_s']:g} s of wall clock per "
             f"method and seed (compile excluded); seeds {rec['seeds']}; tuned "
             f"{', '.join(rec['tuned'])}.", ""]
    for label, title in (("heldout", "Held-out pushes (training distribution, other seeds)"),
                         ("shifted", "Shifted held-out (model variations and heights never "
                                     "trained on)")):
        if label not in rec["pooled"]:
            continue
        lines += [f"## {title}", "", "| method | fall rate | paired diff. vs paper | SE (seeds) "
                  "| SE (pushes) | z (pushes) |", "|---|---|---|---|---|---|"]
        for name, v in rec["pooled"][label].items():
            z = (v["diff_vs_paper"] / v["se_over_pushes"] if v["se_over_pushes"] else float("nan"))
            lines.append(f"| {name} | {100 * v['fall_rate']:.1f} % | "
                         f"{100 * v['diff_vs_paper']:+.2f} pp | {100 * v['se_over_seeds']:.2f} | "
                         f"{100 * v['se_over_pushes']:.2f} | {z:+.1f} |")
        lines.append("")
    lines += ["## Runs", "", "| method | seed | iterations | compile (s) | best hard training loss "
              "| pushes simulated |", "|---|---|---|---|---|---|"]
    for r in rec["runs"]:
        lines.append(f"| {r['method']} | {r['seed']} | {r['iterations']} | {r['compile_s']} | "
                     f"{r['best_loss']:.4f} | {r['curve'][-1]['pushes']:,} |")
    lines += ["", f"Winner (lowest pooled fall rate, shifted set): **{rec['winner']}**.", ""]
    return "\n".join(lines)


def _plot_curves(path: Path, rec: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    colors = {m: f"C{i}" for i, m in enumerate(rec["methods"])}
    for r in rec["runs"]:
        t = [p["wall_s"] for p in r["curve"]]
        n = [p["pushes"] for p in r["curve"]]
        y = [p["best_loss"] for p in r["curve"]]
        label = r["method"] if r["seed"] == rec["seeds"][0] else None
        axes[0].step(t, y, where="post", color=colors[r["method"]], alpha=0.8, label=label)
        axes[1].step(n, y, where="post", color=colors[r["method"]], alpha=0.8, label=label)
    axes[0].set_xlabel("wall clock (s, compile excluded)")
    axes[1].set_xlabel("pushes simulated")
    axes[1].set_xscale("log")
    for ax in axes:
        ax.set_ylabel("best hard-gate training loss")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"convergence, {len(rec['seeds'])} seeds per method ({', '.join(rec['devices'])})",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _jsonable(x):
    return json.loads(json.dumps(x, default=json_default))


def json_default(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, tuple):
        return list(x)
    return str(x)


