"""From a calibration's archive to an ensemble of plausible robots, a default robot in the middle
of them, and each fitted parameter's island width in expectation.

- The ensemble: every archived candidate whose expected loss (the mean over the samples of hit
  phase x contact time) is within `tolerance` of the best, at the best's reading, distinct in
  the fitted parameters; the lowest `max_members` of them.
- The default member: the ensemble's medoid in the unit cube of the fitted bounds (the member
  with the smallest mean distance to the others): the middle of the island, not its edge,
  which the best-loss candidate often is.
- Island widths: one-parameter slices through the default member, `points` values evenly over
  each fitted bound, scored in expectation. The island is the contiguous run of values around
  the member whose loss is within the tolerance of the best; its width (last minus first
  holding value) is a lower bound resolved to the grid step (bound range / (points - 1)).
  A second criterion reports the run where every paper row
  keeps the paper's fall outcome in >= 80 % of the samples.
"""

from __future__ import annotations

import math

import numpy as np

from tkujax.studies.calibrate import fit_vector as P

ROW_P_MIN = 0.8        # each row's paper outcome at >= 80 % of the phases


def record_loss(rec: dict, objective: str, reading: str) -> float:
    return rec["loss"][objective][reading] if "rows" in rec else math.inf


def select(recs: list[dict], objective: str, reading: str, tolerance: float,
           max_members: int, names: tuple[str, ...], bounds: dict) -> list[dict]:
    """The ensemble's records, best first (see the module doc)."""
    ok = sorted((r for r in recs if "rows" in r), key=lambda r: record_loss(r, objective, reading))
    if not ok:
        return []
    best = record_loss(ok[0], objective, reading)
    members, seen = [], set()
    for r in ok:
        if record_loss(r, objective, reading) > best + tolerance or len(members) >= max_members:
            break
        key = tuple(round((r["x"][n] - bounds[n][0]) / (bounds[n][1] - bounds[n][0]), 6)
                    for n in names)
        if key not in seen:
            seen.add(key)
            members.append(r)
    return members


def unit(x: dict, names, bounds) -> np.ndarray:
    return np.array([(x[n] - bounds[n][0]) / (bounds[n][1] - bounds[n][0]) for n in names])


def medoid(members: list[dict], names, bounds) -> int:
    """Index of the member with the smallest mean unit-cube distance to the others."""
    u = np.array([unit(m["x"], names, bounds) for m in members])
    d = np.sqrt(((u[:, None, :] - u[None, :, :]) ** 2).sum(-1))
    return int(np.argmin(d.mean(1)))


def slice_points(x: dict, names, bounds, points: int) -> list[tuple[str, float, dict]]:
    """(name, value, candidate) for each fitted name's `points` values over its bound, plus
    the member's own value (so the slice goes through it)."""
    out = []
    for n in names:
        lo, hi = bounds[n]
        for v in sorted(set(np.linspace(lo, hi, points).tolist()) | {float(x[n])}):
            xx = dict(x)
            xx[n] = float(v)
            out.append((n, float(v), xx))
    return out


def _run_around(values: np.ndarray, holds: np.ndarray, v0: float) -> tuple[float, float] | None:
    """The contiguous run of holding grid values around v0 (the grid value nearest it: v0
    itself in slice_points' slices)."""
    from tkujax.studies.calibrate.islands import island

    run = island(list(values), list(holds), int(np.argmin(np.abs(values - v0))))
    if run is None:
        return None
    lo, hi = run
    return float(values[lo]), float(values[hi])


def islands(x: dict, scored: list[tuple[str, float, dict]], objective: str, reading: str,
            best_loss: float, tolerance: float, names, bounds) -> dict:
    """Per fitted name: the slice (value, loss, min row probability) and its two islands."""
    out = {}
    for n in names:
        pts = [(v, rec) for name, v, rec in scored if name == n]
        values = np.array([v for v, _ in pts])
        loss = np.array([record_loss(r, objective, reading) for _, r in pts])
        pmin = np.array([min(e["p_paper"] for e in r["expected"][reading].values())
                         if "expected" in r else 0.0 for _, r in pts])
        lo, hi = bounds[n]
        step = (hi - lo) / max(len(values) - 2, 1)        # the even grid's (v0 added)
        isl_loss = _run_around(values, loss <= best_loss + tolerance, x[n])
        isl_rows = _run_around(values, pmin >= ROW_P_MIN, x[n])
        out[n] = dict(value=x[n], grid_step=step, values=values.tolist(), loss=loss.tolist(),
                      min_row_p_paper=pmin.tolist(),
                      island_loss=isl_loss, width_loss=(None if isl_loss is None
                                                        else isl_loss[1] - isl_loss[0]),
                      island_rows80=isl_rows, width_rows80=(None if isl_rows is None
                                                            else isl_rows[1] - isl_rows[0]),
                      log=P.PARAMS[P.NAMES.index(n)].log)
    return out


def islands_md(isl: dict, tolerance: float) -> str:
    lines = ["| parameter | default member | grid step | island, loss within "
             f"{tolerance:g} of the best | width | island, every row's paper outcome in >= "
             f"{ROW_P_MIN:.0%} of samples | width |", "|---|---|---|---|---|---|---|"]

    def fmt(v):
        return "-" if v is None else f"{v:.4g}"

    for n, s in isl.items():
        il, ir = s["island_loss"], s["island_rows80"]
        lines.append(f"| {n}{' (log10)' if s['log'] else ''} | {s['value']:.4g} | "
                     f"{s['grid_step']:.3g} | "
                     f"{'none' if il is None else f'[{il[0]:.4g}, {il[1]:.4g}]'} | "
                     f"{fmt(s['width_loss'])} | "
                     f"{'none' if ir is None else f'[{ir[0]:.4g}, {ir[1]:.4g}]'} | "
                     f"{fmt(s['width_rows80'])} |")
    return "\n".join(lines) + "\n"
