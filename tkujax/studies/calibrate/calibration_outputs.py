"""The report of a calibration (`run_calibrate`'s last step): best.json, calibration.md,
search_trace.png, model_params.json and controller_params.json of the best fit, with the
finite-difference sensitivities and the ensemble of near-best fits."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from tkujax.control.params_files import save_controller_params_json
from tkujax.studies.calibrate import fit_vector as P
from tkujax.studies.calibrate import calibration_tables as R
from tkujax.studies.calibrate import targets as T
from tkujax.studies.calibrate.scoring import OBJECTIVE_ROWS, Evaluator, phase_key, row_key, score
from tkujax.studies.calibrate.calibrate_spec import CalibrateSpec

def _best(recs, objective: str, readings, reading: str | None = None):
    """(loss, record, reading) minimising `objective` over readings (or at one reading)."""
    best = (math.inf, None, None)
    for rec in recs:
        for rd in readings:
            f = rec["loss"][objective][rd]
            if (reading is None or rd == reading) and f < best[0]:
                best = (f, rec, rd)
    return best


def _rows(rec: dict, phase: str, reading: str) -> dict:
    return {tuple(k.split("/")): v for k, v in rec["rows"][phase][reading].items()}


def _x_array(x: dict) -> np.ndarray:
    return np.array([float(x[n]) for n in P.NAMES])


def _params_md(x: dict, spec: CalibrateSpec) -> str:
    lines = ["| parameter | value | fitted within | held / start | why this bound (params.py) |",
             "|---|---|---|---|---|"]
    for p in P.PARAMS:
        fmt = (lambda z: f"{10 ** z:.3g} (log10 {z:.2f})") if p.log else (lambda z: f"{z:.4g}")
        lo, hi = spec.bounds[p.name]
        fitted = p.name in spec.params
        at_bound = fitted and min(x[p.name] - lo, hi - x[p.name]) < 0.01 * (hi - lo)
        lines.append(f"| {p.name} | {fmt(x[p.name])}{' **at bound**' if at_bound else ''} | "
                     f"{f'[{fmt(lo)}, {fmt(hi)}]' if fitted else 'held'} | "
                     f"{fmt(spec.start[p.name])} | {p.why} |")
    return "\n".join(lines) + "\n"


def score_many(spec: CalibrateSpec, xs: list[dict], readings, evaluator: Evaluator | None
                ) -> list[dict]:
    """score() of every x: one MJX batch on the mjx backend, else one at a time."""
    if spec.backend == "mjx" and evaluator is None:
        from tkujax.studies.calibrate import evaluate_mjx
        results = evaluate_mjx.evaluate_many(xs, tuple(readings), spec.samples, spec.params,
                                             spec.robots_per_call)
        return [score(x, readings, spec.samples, results=r,
                      criterion_weight=spec.criterion_weight) for x, r in zip(xs, results)]
    return [score(x, readings, spec.samples, evaluator, criterion_weight=spec.criterion_weight)
            for x in xs]


def _sensitivities(spec: CalibrateSpec, x: dict, reading: str, objective: str,
                   evaluator: Evaluator | None, h: float = 0.05) -> list[dict]:
    """Central differences of the sample-averaged loss, step h of each fitted bound's range.

    curvature (per range²) large: the data pin the parameter; slope and curvature ~ 0: free."""
    points = [dict(x)]
    for n in spec.params:
        lo, hi = spec.bounds[n]
        for s in (-1, 1):
            xx = dict(x)
            xx[n] = float(np.clip(x[n] + s * h * (hi - lo), lo, hi))
            points.append(xx)

    def loss(rec):
        return (rec["loss"][objective][reading],
                T.score(_rows(rec, phase_key(spec.samples[0]), reading),
                        OBJECTIVE_ROWS[objective]) if "rows" in rec else None)

    scored = [loss(r) for r in score_many(spec, points, (reading,), evaluator)]
    f0, s0 = scored[0]
    out = []
    for k, n in enumerate(spec.params):
        fs, flips = [], []
        for j, s in enumerate((-1, 1)):
            f, sc = scored[1 + 2 * k + j]
            fs.append(f)
            if sc is not None and s0 is not None and sc["falls"] != s0["falls"]:
                flips.append(f"{'-' if s < 0 else '+'}: falls {sc['falls']}")
        out.append(dict(name=n, f_minus=fs[0], f0=f0, f_plus=fs[1],
                        slope=(fs[1] - fs[0]) / (2 * h),
                        curvature=(fs[0] - 2 * f0 + fs[1]) / (h * h), fall_flips=flips))
    return out


def _plot(recs, objectives, readings, out: Path) -> Path:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(objectives), figsize=(5.5 * len(objectives), 4), squeeze=False)
    for obj, ax in zip(objectives, axes[0]):
        for rd in readings:
            ys = np.array([r["loss"][obj][rd] for r in recs])
            ax.plot(np.minimum.accumulate(ys), label=rd)
        ax.set_yscale("log")
        ax.set_title(f"best-so-far loss, objective {obj}")
        ax.set_xlabel("candidate # (archive order)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = out / "search_trace.png"
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def _objective_section(spec: CalibrateSpec, ok: list[dict], obj: str, phases: list[str]
                       ) -> tuple[dict, list[str]]:
    """The best fit of one objective: its best.json entry and its calibration.md section."""
    f, rec, rd = _best(ok, obj, spec.readings)
    entry = dict(loss=f, reading=rd, x=rec["x"],
                 fitted={n: rec["x"][n] for n in spec.params},
                 score={ph: T.score(_rows(rec, ph, rd), OBJECTIVE_ROWS[obj]) for ph in phases},
                 rows={ph: rec["rows"][ph][rd] for ph in phases})
    title = ("Fit on all 8 rows" if obj == "ALL"
             else "Fit on Table 4 (pushes from behind) only; Table 5 predicted")
    md = [f"## {title}", "", f"Loss {f:.3f} (mean over the samples), reading **{rd}**.", "",
          _params_md(rec["x"], spec)]
    if "expected" in rec:
        entry["expected"] = rec["expected"][rd]
        md += [f"In expectation over the {len(phases)} samples (each a trial at an unknown hit "
               "phase and contact time):", "", _expected_md(rec["expected"][rd]), ""]
    shown = phases if len(phases) <= 3 else phases[:1]
    if len(shown) < len(phases):
        md += [f"Per-sample tables: the first sample below; all {len(phases)} in best.json "
               "(rows).", ""]
    for ph in shown:
        res = _rows(rec, ph, rd)
        if obj == "ALL":
            md.append(R.table_md(res, T.ROWS, f"All 8 rows, hit phase {ph} ms"))
        else:
            md.append(R.table_md(res, T.TABLE4, f"Table 4 (fitted), hit phase {ph} ms"))
            md.append(R.table_md(res, T.TABLE5, f"Table 5 (held out: predicted, not fitted), "
                                                f"hit phase {ph} ms"))
    if obj == "T4":
        entry["heldout_T5"] = {ph: dict(score=T.score(_rows(rec, ph, rd), T.TABLE5),
                                        loss=T.table_loss(_rows(rec, ph, rd), T.TABLE5)[0])
                               for ph in phases}
    return entry, md


def _expected_md(exp: dict) -> str:
    lines = ["| row | paper | P(paper's fall outcome) | mean step, standing trials (cm) | "
             "P(step the paper's way) |", "|---|---|---|---|---|"]
    for key, (rec_p, step_p) in T.PAPER_TABLE.items():
        e = exp[row_key(key)]
        paper = "falls" if rec_p is None else (f"stands, step {step_p:g} cm" if step_p
                                               else "stands")
        step = f"{e['step_mean_cm']:+.2f}" if "step_mean_cm" in e else "-"
        way = f"{e['p_step_paper_way']:.2f}" if "p_step_paper_way" in e else "-"
        lines.append(f"| {' '.join(key)} | {paper} | {e['p_paper']:.2f} | {step} | {way} |")
    return "\n".join(lines) + "\n"


def _selection_section(spec: CalibrateSpec, ok: list[dict], phases: list[str]
                       ) -> tuple[dict, list[str]]:
    """Model selection: the best loss per reading of Algorithm 1 (best.json and markdown)."""
    md = ["## Model selection: best loss per reading of Algorithm 1", "",
          "Every candidate is simulated at every reading, so each reading's best is over the "
          "whole archive (lower is better).", "",
          "| reading | best loss, Table 4 only | best loss, all 8 rows | score of the all-rows "
          f"best (hit phase {phases[0]} ms) |", "|---|---|---|---|"]
    sel = {}
    for rd in spec.readings:
        f4 = _best(ok, "T4", spec.readings, rd)[0]
        fa, ra, _ = _best(ok, "ALL", spec.readings, rd)
        sel[rd] = dict(T4=f4, ALL=fa, score_all=T.score(_rows(ra, phases[0], rd)))
        md.append(f"| {rd} | {f4:.3f} | {fa:.3f} | {sel[rd]['score_all']} |")
    md.append("")
    return sel, md


def _sensitivity_md(sens: list[dict], primary: str) -> list[str]:
    md = [f"## Identifiability: finite-difference sensitivities at the {primary} best", "",
          "Central differences, step 5 % of each fitted bound's range, phase-averaged loss. "
          "A large curvature: the data pin the parameter; slope and curvature near 0: the "
          "data leave it free. 'fall flips': the fall-outcome count changes within ±5 %.", "",
          "| parameter | loss −5% | loss | loss +5% | slope /range | curvature /range² | "
          "fall flips |", "|---|---|---|---|---|---|---|"]
    for s in sens:
        md.append(f"| {s['name']} | {s['f_minus']:.3f} | {s['f0']:.3f} | {s['f_plus']:.3f} | "
                  f"{s['slope']:.2f} | {s['curvature']:.1f} | {'; '.join(s['fall_flips'])} |")
    md.append("")
    return md


def _ensemble_section(spec: CalibrateSpec, ok: list[dict], best: dict, objective: str,
                      out: Path, evaluator: Evaluator | None) -> tuple[dict, list[str]]:
    """ensemble.json, the default member's files, island widths (ensemble.py)."""
    from tkujax.model.ensemble import save_ensemble
    from tkujax.model.params_json import save_model_params_json
    from tkujax.studies.calibrate import ensemble_build as ENS

    rd, tol = best["reading"], spec.ensemble_tolerance
    members = ENS.select(ok, objective, rd, tol, spec.ensemble_max, spec.params, spec.bounds)
    k = ENS.medoid(members, spec.params, spec.bounds)
    dflt = members[k]
    losses = [ENS.record_loss(m, objective, rd) for m in members]
    save_ensemble(out / "ensemble.json",
                  [dict(model_params=P.model_params(m["x"]), x=m["x"], loss=f,
                        expected=m.get("expected", {}).get(rd)) for m, f in zip(members, losses)],
                  k, objective=objective, reading=rd, tolerance=tol, best_loss=losses[0],
                  samples=[phase_key(s) for s in spec.samples], source=spec.name)
    save_model_params_json(P.model_params(dflt["x"]), out / "default_model_params.json")
    save_controller_params_json(P.controller_params(dflt["x"], rd), out /
                                "default_controller_params.json")
    entry = dict(n_members=len(members), tolerance=tol, default_member=k,
                 default_loss=losses[k], best_loss=losses[0], default_x=dflt["x"])
    md = ["## Ensemble of plausible robots (ensemble.json)", "",
          f"{len(members)} distinct candidates within {tol:g} of the best expected loss "
          f"({losses[0]:.3f}, objective {objective}, reading {rd}), at most {spec.ensemble_max}."
          f" Default member: #{k}, the medoid in the unit cube of the fitted bounds (the middle "
          f"of the island), loss {losses[k]:.3f}; its files: default_model_params.json, "
          "default_controller_params.json.", "",
          "| parameter | min | median | max | default member |", "|---|---|---|---|---|"]
    for n in spec.params:
        v = np.array([m["x"][n] for m in members])
        md.append(f"| {n} | {v.min():.4g} | {np.median(v):.4g} | {v.max():.4g} | "
                  f"{dflt['x'][n]:.4g} |")
    md.append("")
    if "expected" in dflt:
        md += ["The default member in expectation:", "", _expected_md(dflt["expected"][rd]), ""]
    if spec.island_points:
        pts = ENS.slice_points(dflt["x"], spec.params, spec.bounds, spec.island_points)
        recs = score_many(spec, [p[2] for p in pts], (rd,), evaluator)
        isl = ENS.islands(dflt["x"], [(n, v, r) for (n, v, _), r in zip(pts, recs)], objective,
                          rd, losses[0], tol, spec.params, spec.bounds)
        entry["islands"] = isl
        md += ["### Island widths around the default member", "",
               f"One-parameter slices, {spec.island_points} points over each fitted bound, "
               "scored in expectation over every sample:", "", ENS.islands_md(isl, tol), ""]
    return entry, md


def write_report(spec: CalibrateSpec, out: Path, recs: list[dict], start_rec: dict,
                 search: dict, evaluator: Evaluator | None = None) -> dict:
    """best.json, calibration.md, search_trace.png, model_params.json, controller_params.json."""
    from tkujax.model.params_json import save_model_params_json

    ok = [r for r in recs if "rows" in r]
    if not ok:
        raise RuntimeError(f"no candidate could be simulated (see the errors in "
                           f"{out / 'archive.jsonl'})")
    phases = [phase_key(ph) for ph in spec.samples]
    summary = dict(name=spec.name, n_candidates=len(recs), n_failed=len(recs) - len(ok),
                   fitted=list(spec.params), readings=list(spec.readings),
                   hit_phases_ms=list(spec.hit_phases_ms),
                   contact_times_ms=list(spec.contact_times_ms), backend=spec.backend,
                   objectives=list(spec.objectives),
                   search=search, spec_digest=spec.fit_digest())
    if "rows" in start_rec:
        summary["start"] = dict(loss={o: min(start_rec["loss"][o].values())
                                      for o in spec.objectives}, x=start_rec["x"])
    md = [f"# Calibration `{spec.name}` (`tkujax calibrate`)", "",
          f"{len(recs)} candidates in the archive ({summary['n_failed']} refused by the model), "
          f"each simulated on the paper's 8 rows "
          f"({'MJX, a generation per call' if spec.backend == 'mjx' else 'MuJoCo C'} backend, "
          f"noise-free), {len(spec.readings)} reading(s) of Algorithm 1, samples (hit phase "
          f"ms after the controller tick, @contact time when not 20 ms) {', '.join(phases)} "
          f"(the loss is the mean over the samples: an expected loss). "
          f"This run: {search['candidates_this_run']} candidates "
          f"({search['simulated_this_run']} simulated, the rest read back from the archive), "
          f"{search['wall_s']} s wall, {search['cpu_count']} CPU(s), workers {search['workers']}, "
          f"stopped by {search['stopped_by']}.", "",
          "Background, and which rows resist and why: `results/calibration/FINDINGS.md`.", ""]
    if "start" in summary:
        md += ["Start point loss: " + ", ".join(f"{o} {f:.3f}" for o, f in
                                                 summary["start"]["loss"].items()) + ".", ""]

    for obj in spec.objectives:
        summary[obj], lines = _objective_section(spec, ok, obj, phases)
        md += lines
    summary["model_selection"], lines = _selection_section(spec, ok, phases)
    md += lines

    primary = spec.objectives[0]
    best = summary[primary]
    if spec.sensitivity:
        sens = _sensitivities(spec, best["x"], best["reading"], primary, evaluator)
        summary["sensitivity"] = sens
        md += _sensitivity_md(sens, primary)

    if spec.ensemble_tolerance is not None:
        summary["ensemble"], lines = _ensemble_section(spec, ok, best, primary, out, evaluator)
        md += lines

    x = best["x"]
    mp = P.model_params(x)
    save_model_params_json(mp, out / "model_params.json")
    cp = P.controller_params(x, best["reading"], mp)
    save_controller_params_json(cp, out / "controller_params.json")
    md += ["## Using the fit", "",
           f"`model_params.json` and `controller_params.json` hold the {primary} best "
           f"(reading {best['reading']}); other commands load them:", "",
           f"    tkujax paper --out DIR --model {out}/model_params.json "
           f"--params {out}/controller_params.json",
           f"    tkujax sweep SPEC --out DIR --model {out}/model_params.json "
           f"--params {out}/controller_params.json", "",
           "The push-side parameters (push_height_m, impulse_factor) describe the paper's ball "
           "rig, not the robot: they are in best.json, not in these files.", ""]
    summary["files"] = [str(out / f) for f in ("archive.jsonl", "best.json", "calibration.md",
                                               "search_trace.png", "model_params.json",
                                               "controller_params.json")]
    (out / "calibration.md").write_text("\n".join(md))
    _plot(recs, spec.objectives, spec.readings, out)
    (out / "best.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    return summary
