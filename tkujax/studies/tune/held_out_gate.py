"""Hard-gate evaluation of tuned latents on held-out pushes and a grid, and the rule that
decides which set `tkujax tune` recommends (`recommend`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.studies.tune.loss import OFF_SURVIVED
from tkujax.studies.tune.methods import or_none
from tkujax.studies.tune.problem import TuneProblem, off_survived


def evaluate(problem: TuneProblem, latents: dict[str, np.ndarray], heldout: dict,
             grid: dict, batch: int, seed: int, harm: bool | None = None) -> dict:
    """Hard-controller (gate_temperature = 0) evaluation of each named latent.

    Returns {name: dict(heldout_fall_rate, heldout_mean_recovery_s, heldout_recovered,
    heldout_loss, grid_fall_rate, max_impulse {azimuth_deg: N s}, per_push arrays)}.
    The held-out loss is the one tuned: each push's loss times its harm weight when the
    problem's w_harm > 0. harm (default: when w_harm > 0, whose control-off pass is then
    compiled anyway): also run the held-out pushes once with control OFF and report
    heldout_off_fall_rate and heldout_harmed_rate, the fraction of held-out pushes that fall
    with control but not without (pushes diverged either way left out)."""
    from tkujax.analysis.maps import max_recoverable_impulse

    key = jax.random.PRNGKey(seed)
    k_held, k_grid = jax.random.split(key)
    keys_held = jax.random.split(k_held, max(len(heldout["impulse_ns"]), 1))
    keys_grid = jax.random.split(k_grid, max(len(grid["impulse_ns"]), 1))
    harm = problem.needs_off if harm is None else harm
    off = None
    if len(heldout["impulse_ns"]) and (harm or problem.needs_off):
        off = problem.control_off(heldout, keys_held, batch)      # once for every latent
        heldout = dict(heldout, **{OFF_SURVIVED: off_survived(off)})
    if len(grid["impulse_ns"]):
        grid = problem.with_off_survived(grid, keys_grid, batch)
    result = {}
    for name, z in latents.items():
        r: dict[str, Any] = {}
        if len(heldout["impulse_ns"]):
            aux = problem.forward_padded(z, 0.0, heldout, keys_held, batch)
            # Diverged pushes are counted apart, never as fell or survived.
            div = aux["outcomes"]["diverged"].astype(bool)
            fell = aux["outcomes"]["fell"].astype(bool)[~div]
            rec_t = aux["outcomes"]["recovery_time_s"][~div]
            loss = aux["terms"].get("weighted", aux["terms"]["total"])
            r.update(heldout_n=int(fell.size), heldout_diverged=int(div.sum()),
                     heldout_fall_rate=float(fell.mean()) if fell.size else None,
                     heldout_mean_recovery_s=or_none(np.nanmean(rec_t)) if np.isfinite(rec_t).any()
                     else None,
                     heldout_recovered=int(np.isfinite(rec_t).sum()),
                     heldout_loss=float(np.mean(loss[~div])) if fell.size else None,
                     heldout_push_loss=loss.tolist(),
                     heldout_push_diverged=div.tolist(),
                     heldout_fell=fell.tolist(),
                     heldout_terms={k: float(np.mean(aux["terms"][k]))
                                    for k in ("fall", "recovery", "step")})
            if off is not None:
                r.update(harm_rates(aux["outcomes"]["fell"], div, off["fell"], off["diverged"]))
        if len(grid["impulse_ns"]):
            aux = problem.forward_padded(z, 0.0, grid, keys_grid, batch)
            fell = aux["outcomes"]["fell"].astype(bool)
            div = aux["outcomes"]["diverged"].astype(bool)
            rec = dict(control=np.ones(fell.size, bool), azimuth_deg=grid["azimuth_deg"],
                       impulse_ns=grid["impulse_ns"], fell=fell, diverged=div)
            azs, jmax = max_recoverable_impulse(rec, True)
            r.update(grid_fall_rate=float(fell[~div].mean()) if (~div).any() else None,
                     grid_diverged=int(div.sum()),
                     max_impulse={f"{a:g}": float(j) for a, j in zip(azs, jmax)},
                     grid_fell=fell.tolist(),
                     grid_recovery_s=[or_none(x) for x in aux["outcomes"]["recovery_time_s"]])
        result[name] = r
    return result


def harm_rates(fell_on, diverged_on, fell_off, diverged_off) -> dict:
    """Over the pushes that diverged neither with nor without control: heldout_off_fall_rate
    (control off falls) and heldout_harmed_rate (falls with control, survives without), with
    heldout_harm_n, their number; per-push heldout_harmed (None where left out)."""
    fell_on, fell_off = np.asarray(fell_on, bool), np.asarray(fell_off, bool)
    ok = ~(np.asarray(diverged_on, bool) | np.asarray(diverged_off, bool))
    harmed = fell_on & ~fell_off
    n = int(ok.sum())
    return dict(heldout_harm_n=n,
                heldout_off_fall_rate=float(fell_off[ok].mean()) if n else None,
                heldout_harmed_rate=float(harmed[ok].mean()) if n else None,
                heldout_harmed=[bool(h) if k else None for h, k in zip(harmed, ok)])


def params_json(params: ControllerParams) -> dict[str, float]:
    """{field: value} (SI, radians) of the hard controller, as load_params_json reads."""
    d = {k: float(v) for k, v in dataclasses.asdict(params).items()}
    d["gate_temperature"] = 0.0
    return d


RULE = ("the tuned set is recommended only when, on the held-out pushes (hard controller), its "
        "fall rate is strictly below the starting set's AND its mean held-out loss (the tuned "
        "loss, harm weights included) is not worse "
        "than the starting set's by more than one standard error of the paired per-push loss "
        "difference; otherwise the starting set is kept")


def harmed_directions(evals: dict, sector, names, harm_pp: float = 2.0) -> list[dict]:
    """Direction sectors where the tuned set falls more often on the held-out pushes than the
    starting set by more than harm_pp points (sector: the held-out pushes' sector indices;
    names: their names). Reported with the recommendation, never a veto: per-direction counts
    of a small evaluation are noisy."""
    b, a = evals.get("before", {}), evals.get("after", {})
    if "heldout_fell" not in a or "heldout_fell" not in b:
        return []
    sector = np.asarray(sector)
    rates = {}
    for name, v in (("before", b), ("after", a)):
        div = np.asarray(v.get("heldout_push_diverged", np.zeros(sector.size, bool)), bool)
        if div.size != sector.size:
            return []
        fell = np.full(sector.size, np.nan)
        fell[~div] = np.asarray(v["heldout_fell"], float)
        rates[name] = fell
    out = []
    for k, name in enumerate(names):
        fb = rates["before"][(sector == k) & np.isfinite(rates["before"])]
        fa = rates["after"][(sector == k) & np.isfinite(rates["after"])]
        if fb.size and fa.size and 100 * (fa.mean() - fb.mean()) > harm_pp + 1e-9:
            out.append(dict(direction=name, before=float(fb.mean()), after=float(fa.mean()),
                            n=int(min(fb.size, fa.size))))
    return out


def recommend(evals: dict, harmed: list[dict] | None = None) -> dict:
    """Which set to recommend, "after" (the tuned one) or "before" (the starting one), by
    `RULE`, from `evaluate`'s result for both.

    Returns dict(recommended ("after" | "before"), verified (False when there was no held-out
    evaluation: the tuned set is then recommended unchecked), fall_before, fall_after,
    loss_diff (mean paired after - before over pushes that diverged in neither), loss_diff_se,
    n_paired, harmed_directions (`harmed_directions`, passed in: a warning added to the
    reason, not part of the rule), reason (a sentence), rule)."""
    harmed = list(harmed or [])
    warn = ("" if not harmed else "; WARNING: the tuned set falls more often on held-out "
            "pushes " + ", ".join(f"from {h['direction']} ({100 * h['before']:.1f} % -> "
                                  f"{100 * h['after']:.1f} % of {h['n']})" for h in harmed))
    b, a = evals.get("before", {}), evals.get("after", {})
    out = dict(rule=RULE, fall_before=b.get("heldout_fall_rate"),
               fall_after=a.get("heldout_fall_rate"), loss_diff=None, loss_diff_se=None,
               n_paired=0, harmed_directions=harmed)
    if out["fall_before"] is None or out["fall_after"] is None:
        return out | dict(recommended="after", verified=False,
                          reason="no held-out evaluation ran (--no-eval or evaluate.n = 0): "
                                 "the tuned set is recommended UNCHECKED; it may be worse than "
                                 "the starting set")
    la, lb = (np.asarray(x["heldout_push_loss"], float) for x in (a, b))
    ok = ~(np.asarray(a.get("heldout_push_diverged", np.zeros(la.size, bool)), bool)
           | np.asarray(b.get("heldout_push_diverged", np.zeros(lb.size, bool)), bool))
    d = (la - lb)[ok]
    mean = float(d.mean()) if d.size else math.nan
    se = float(d.std(ddof=1) / math.sqrt(d.size)) if d.size > 1 else 0.0
    out.update(loss_diff=mean, loss_diff_se=se, n_paired=int(d.size))
    fb, fa = out["fall_before"], out["fall_after"]
    pct = lambda v: f"{100 * v:.1f} %"  # noqa: E731
    if not fa < fb:
        return out | dict(recommended="before", verified=True, reason=(
            f"kept the starting set: the tuned set's held-out fall rate {pct(fa)} is not below "
            f"the starting set's {pct(fb)}"))
    if not (math.isfinite(mean) and mean <= se):
        return out | dict(recommended="before", verified=True, reason=(
            f"kept the starting set: the tuned set falls less on the held-out pushes "
            f"({pct(fa)} vs {pct(fb)}) but its held-out loss is worse by {mean:.4f} +- "
            f"{se:.4f} (paired, s.e.), more than one standard error"))
    return out | dict(recommended="after", verified=True, reason=(
        f"recommended the tuned set: held-out fall rate {pct(fa)} vs the starting set's "
        f"{pct(fb)}, held-out loss {mean:+.4f} +- {se:.4f} (paired, s.e.) against it{warn}"))
