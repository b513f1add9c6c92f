"""Island widths of the calibrated robot and its paper outcomes in expectation over the hit phase
(calibration in expectation).

island_slices(): for each fitted parameter (params.PARAMS: the ModelParams fields, the ball
contact and the Kalman noises), a one-parameter slice through the default robot (the others held
at their default, `params.base_vector()`): `points` values evenly over the parameter's bounds
plus the default, each scored on the 8 paper rows (MuJoCo C physics, noise-free, the default
controller). A row "holds" when its fall outcome is the paper's; the island is the contiguous run
of grid values around the default where all 8 hold (at every hit phase scored, by default the
fit's 0 ms). Its two edges are then bisected `refine` times between the last value inside and
the first outside, so the reported width is resolved to (grid step) / 2**refine. Outside the
island the run may hold again (a second island): the slice lists every value's score.

phase_expectation(): the default robot's 8 rows at `n` hit phases spread over the 30 ms control
period (the 15 phases of `tkujax paper`'s phase table): per row the fraction of phases with the
paper's fall outcome, and, for the rows where the paper steps, the fraction of phases with a step
(>= 5 mm, robot standing) the paper's way: forward after a push from behind, backward after one
from the front.

python -m tkujax.studies.calibrate.islands --out results/calibration/islands [--points 41]
(also `tkujax islands`). Writes islands.json, islands.md, phase_expectation.json,
phase_expectation.md into --out (nothing else; it reads no file).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from pathlib import Path

import numpy as np

from tkujax.studies.calibrate import paper_rows as E
from tkujax.studies.calibrate import fit_vector as P
from tkujax.studies.calibrate.targets import PAPER_TABLE, ROWS

PERIOD_MS = 30.0
# The default controller's reading of Algorithm 1 (ControllerParams(): cp_excess = 0,
# cp_update_window = 0); checked against ControllerParams.paper() by default_reading().
DEFAULT_READING = "deviation/latched"


def default_reading() -> str:
    """The READINGS key whose controller equals ControllerParams.paper() of the default model
    (raises if none does: the slices must go through the default robot)."""
    from tkujax.control.controller_params import ControllerParams
    from tkujax.model import ModelParams

    x0 = P.base_vector()
    want = ControllerParams.paper(ModelParams())
    for r in (DEFAULT_READING, *P.READINGS):
        got = P.controller_params(x0, r, P.model_params(x0))
        if all(math.isclose(float(getattr(got, f.name)), float(getattr(want, f.name)),
                            rel_tol=1e-6, abs_tol=1e-9)
               for f in dataclasses.fields(want) if isinstance(getattr(want, f.name), float)):
            return r
    raise RuntimeError("no reading of params.READINGS reproduces ControllerParams.paper()")


def phases_ms(n: int) -> tuple[float, ...]:
    """n hit phases evenly over the control period: k / n * 30 ms (as `tkujax paper`)."""
    return tuple(PERIOD_MS * k / n for k in range(n))


def _row_ok(key, sim: dict) -> tuple[bool, bool | None]:
    """(fall outcome as the paper's, step the paper's way or None where the paper takes none)."""
    rec_p, step_p = PAPER_TABLE[key]
    fall_ok = sim["fell"] == (rec_p is None)
    if step_p is None:
        return fall_ok, None
    want = 1.0 if key[0] == "back" else -1.0
    return fall_ok, (not sim["fell"]) and sim["step_cm"] * want >= 0.5


def score(x, reading: str, hit_phases: tuple[float, ...]) -> dict:
    """The 8 rows of parameter vector x at the hit phases (ms): per row the fractions of phases
    with the paper's fall outcome and (stepping rows) a step the paper's way, and `all_hold`:
    every row's fall outcome as the paper's at every phase."""
    res = E.evaluate_phases(x, (reading,), hit_phases)
    rows = {}
    for key in ROWS:
        oks = [_row_ok(key, res[ph][reading][key]) for ph in hit_phases]
        steps = [res[ph][reading][key]["step_cm"] for ph in hit_phases]
        rows["/".join(key)] = dict(
            fall_ok=float(np.mean([o[0] for o in oks])),
            step_ok=None if oks[0][1] is None else float(np.mean([o[1] for o in oks])),
            fell_at_ms=[ph for ph in hit_phases if res[ph][reading][key]["fell"]],
            step_cm=[round(s, 3) for s in steps])
    n_ok = sum(r["fall_ok"] == 1.0 for r in rows.values())
    return dict(rows=rows, n_rows_hold=n_ok, all_hold=n_ok == len(ROWS),
                stand_deg=float(res[hit_phases[0]][reading][ROWS[0]]["stand_deg"]))


def island(values: list[float], holds: list[bool], i0: int) -> tuple[int, int] | None:
    """Indices (first, last) of the run of True around index i0 (None if holds[i0] is False)."""
    if not holds[i0]:
        return None
    lo = hi = i0
    while lo > 0 and holds[lo - 1]:
        lo -= 1
    while hi < len(values) - 1 and holds[hi + 1]:
        hi += 1
    return lo, hi


def island_slices(names=P.DEFAULT_FIT, points: int = 41, refine: int = 4,
                  hit_phases: tuple[float, ...] = (0.0,), log=print,
                  window: float = 1.0) -> dict:
    """{name: slice and island} for each parameter (see the module docstring). window: the
    slice spans this fraction of the parameter's bounds, centred on the default and clipped to
    the bounds (1 = the whole bounds)."""
    _check_int("points", points, 3, 1000)
    _check_int("refine", refine, 0, 20)
    if not (isinstance(window, (int, float)) and 0.0 < window <= 1.0):
        raise ValueError(f"window must be a number in (0, 1], got {window!r}")
    unknown = [n for n in names if n not in P.NAMES]
    if unknown:
        raise ValueError(f"names: unknown parameter(s) {unknown}; allowed: {list(P.NAMES)}")
    reading = default_reading()
    x0 = P.as_dict(P.base_vector())
    out = {}
    for name in names:
        p = P.PARAMS[P.NAMES.index(name)]
        t0 = time.perf_counter()
        half = 0.5 * window * (p.hi - p.lo)
        a_lo = p.lo if window == 1.0 else max(p.lo, x0[name] - half)
        a_hi = p.hi if window == 1.0 else min(p.hi, x0[name] + half)
        grid = sorted(set(np.linspace(a_lo, a_hi, points).tolist()) | {x0[name]})
        cache = {}

        def run(v, cache=cache, name=name):
            if v not in cache:
                cache[v] = score(dict(x0, **{name: v}), reading, hit_phases)
            return cache[v]

        pts = [dict(value=v, **{k: run(v)[k] for k in ("n_rows_hold", "all_hold", "stand_deg")},
                    failing=[k for k, r in run(v)["rows"].items() if r["fall_ok"] < 1.0],
                    fall_ok={k: r["fall_ok"] for k, r in run(v)["rows"].items()},
                    step_ok={k: r["step_ok"] for k, r in run(v)["rows"].items()
                             if r["step_ok"] is not None})
               for v in grid]
        i0 = grid.index(x0[name])
        isl = island(grid, [q["all_hold"] for q in pts], i0)
        entry = dict(lo=p.lo, hi=p.hi, default=x0[name], log10=p.log, points=pts,
                     grid_step=(a_hi - a_lo) / (points - 1), reading=reading, window=window,
                     hit_phases_ms=list(hit_phases))
        if isl is None:
            entry.update(island=None)
        else:
            a, b = isl
            edges = []
            for inside, outside in ((a, a - 1), (b, b + 1)):
                if outside < 0 or outside >= len(grid):     # the island reaches the slice end
                    edges.append(dict(value=grid[inside], open=True, resolution=0.0))
                    continue
                vin, vout = grid[inside], grid[outside]
                for _ in range(refine):
                    mid = 0.5 * (vin + vout)
                    if run(mid)["all_hold"]:
                        vin = mid
                    else:
                        vout = mid
                edges.append(dict(value=vin, first_out=vout, open=False,
                                  resolution=abs(vout - vin)))
            lo_e, hi_e = edges
            width = hi_e["value"] - lo_e["value"]
            entry.update(island=dict(
                grid_lo=grid[a], grid_hi=grid[b], lo=lo_e, hi=hi_e, width=width,
                width_frac_of_bounds=width / (p.hi - p.lo),
                default_position=(x0[name] - lo_e["value"]) / width if width > 0 else 0.5,
                margin_below=x0[name] - lo_e["value"], margin_above=hi_e["value"] - x0[name]))
        entry["evaluations"] = len(cache)
        entry["wall_s"] = round(time.perf_counter() - t0, 1)
        out[name] = entry
        isl_s = ("none (the default itself fails)" if entry["island"] is None else
                 f"[{entry['island']['lo']['value']:.5g}, {entry['island']['hi']['value']:.5g}]"
                 f" width {entry['island']['width']:.4g}")
        log(f"{name}: default {x0[name]:.5g}, island {isl_s}, {len(cache)} evaluations, "
            f"{entry['wall_s']} s")
    return out


def phase_expectation(n: int = 15) -> dict:
    """The default robot's 8 rows at n hit phases (see the module docstring)."""
    _check_int("n", n, 1, 100)
    reading = default_reading()
    ph = phases_ms(n)
    s = score(P.base_vector(), reading, ph)
    return dict(phases_ms=list(ph), reading=reading, **s)


def _check_int(key, v, lo, hi):
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise ValueError(f"{key} must be an integer in [{lo}, {hi}], got {v!r}")


def _fmt(v: float, name: str) -> str:
    if name.endswith("_m"):
        return f"{1000 * v:.2f} mm"
    return f"{v:.4g}"


def islands_markdown(sl: dict) -> str:
    lines = ["| parameter | bounds | default | island (8/8 fall outcomes) | width | width / bounds "
             "| default's place in the island (0 = low edge, 1 = high) | edge resolution | "
             "evaluations |", "|---|---|---|---|---|---|---|---|---|"]
    for name, e in sl.items():
        b = f"{_fmt(e['lo'], name)} .. {_fmt(e['hi'], name)}"
        if e["island"] is None:
            lines.append(f"| {name} | {b} | {_fmt(e['default'], name)} | none | | | | | "
                         f"{e['evaluations']} |")
            continue
        i = e["island"]
        end = "(bound)" if e.get("window", 1.0) == 1.0 else "(slice end)"
        lo = (f"{end} " if i["lo"]["open"] else "") + _fmt(i["lo"]["value"], name)
        hi = _fmt(i["hi"]["value"], name) + (f" {end}" if i["hi"]["open"] else "")
        res = max(i["lo"]["resolution"], i["hi"]["resolution"])
        lines.append(f"| {name} | {b} | {_fmt(e['default'], name)} | {lo} .. {hi} | "
                     f"{_fmt(i['width'], name)} | {i['width_frac_of_bounds']:.3f} | "
                     f"{i['default_position']:.2f} | {_fmt(res, name)} | {e['evaluations']} |")
    lines += ["", "Values where fewer than 8 rows hold, per parameter (grid points only; the "
              "failing rows in islands.json):", ""]
    for name, e in sl.items():
        bad = [(q["value"], q["n_rows_hold"]) for q in e["points"] if not q["all_hold"]]
        lines.append(f"- {name}: " + (", ".join(f"{_fmt(v, name)} ({k}/8)" for v, k in bad)
                                       if bad else "none"))
    return "\n".join(lines) + "\n"


def expectation_markdown(sl: dict) -> str:
    """Slices scored over several hit phases: per parameter, the fraction of phases at which each
    row shows the paper's fall outcome, worst row (min) and mean over the 8, at the default and
    at the value with the best worst row; and the values where every row reaches 0.8."""
    lines = ["| parameter | phases | default: worst row / mean | best value | best: worst row / "
             "mean | values with every row >= 0.8 |", "|---|---|---|---|---|---|"]
    for name, e in sl.items():
        pts = e["points"]
        mn = [min(q["fall_ok"].values()) for q in pts]
        mean = [float(np.mean(list(q["fall_ok"].values()))) for q in pts]
        i0 = [q["value"] for q in pts].index(e["default"])
        ib = max(range(len(pts)), key=lambda i: (mn[i], mean[i], -abs(i - i0)))
        ok = [q["value"] for q, m in zip(pts, mn) if m >= 0.8]
        lines.append(f"| {name} | {len(e['hit_phases_ms'])} | {mn[i0]:.2f} / {mean[i0]:.2f} | "
                     f"{_fmt(pts[ib]['value'], name)} | {mn[ib]:.2f} / {mean[ib]:.2f} | "
                     f"{', '.join(_fmt(v, name) for v in ok) or 'none'} |")
    return "\n".join(lines) + "\n"


def phase_markdown(pe: dict) -> str:
    n = len(pe["phases_ms"])
    lines = [f"The default robot at {n} hit phases (0 .. {pe['phases_ms'][-1]:g} ms after the "
             f"controller tick at 0.75 s), reading {pe['reading']}.", "",
             "| row | paper | fall outcome as the paper's (fraction of phases) | falls at (ms) | "
             "step the paper's way (fraction) | steps (cm) |", "|---|---|---|---|---|---|"]
    for key in ROWS:
        r = pe["rows"]["/".join(key)]
        rec_p, step_p = PAPER_TABLE[key]
        paper = ("falls" if rec_p is None else f"{rec_p} s") + (
            "" if step_p is None else f", {step_p} cm")
        steps = sorted(s for s in r["step_cm"] if s != 0.0)
        step_ok = "-" if r["step_ok"] is None else f"{r['step_ok']:.2f}"
        lines.append(
            f"| {' '.join(key)} | {paper} | {r['fall_ok']:.2f} | "
            f"{' '.join(f'{v:g}' for v in r['fell_at_ms']) or '-'} | "
            f"{step_ok} | "
            f"{(f'{steps[0]:.2f} .. {steps[-1]:.2f}' if steps else 'X')} |")
    return "\n".join(lines) + "\n"


def run_islands(out: str | Path, *, params=None, points: int = 41, refine: int = 4,
                slice_phases: int = 1, phases: int = 15, window: float = 1.0,
                log=lambda s: print(s, flush=True)) -> dict:
    """`tkujax islands`: into `out` (created), the default robot's phase expectation over
    `phases` hit phases (phase_expectation.json/.md; 0 skips it) and the island slices of
    `params` (default params.DEFAULT_FIT; names, blanks ignored) at `points` values with
    `refine` bisections per edge, `slice_phases` hit phases per value and `window` of each
    parameter's bounds (islands.json/.md, with the expectation table when slice_phases > 1).
    Each table's Markdown and the wall time go to `log`. Returns {"phase_expectation",
    "islands"}, each None when skipped."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    result = {"phase_expectation": None, "islands": None}
    if phases:
        pe = result["phase_expectation"] = phase_expectation(phases)
        (out / "phase_expectation.json").write_text(json.dumps(pe, indent=1))
        (out / "phase_expectation.md").write_text(phase_markdown(pe))
        log(phase_markdown(pe))
    names = P.DEFAULT_FIT if params is None else tuple(s.strip() for s in params if s.strip())
    if names:
        sl = result["islands"] = island_slices(names, points, refine, phases_ms(slice_phases),
                                               log=log, window=window)
        (out / "islands.json").write_text(json.dumps(sl, indent=1))
        md = islands_markdown(sl)
        if slice_phases > 1:
            md += "\n" + expectation_markdown(sl)
        (out / "islands.md").write_text(md)
        log(md)
    log(f"wall {time.perf_counter() - t0:.0f} s")
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="tkujax islands", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output folder (only islands.* and "
                    "phase_expectation.* are written)")
    ap.add_argument("--points", type=int, default=41, help="grid values per slice over the "
                    "bounds (default 41; the default value is added)")
    ap.add_argument("--refine", type=int, default=4, help="bisections of each island edge")
    ap.add_argument("--params", default=",".join(P.DEFAULT_FIT),
                    help="comma-separated parameters")
    ap.add_argument("--slice-phases", type=int, default=1, help="hit phases per slice value "
                    "(1: the fit's 0 ms; n: k/n * 30 ms and all must hold)")
    ap.add_argument("--phases", type=int, default=15, help="phases of the default robot's "
                    "expectation table (0 skips it)")
    ap.add_argument("--window", type=float, default=1.0, help="fraction of each parameter's "
                    "bounds the slice spans, centred on the default (default 1: all)")
    a = ap.parse_args(argv)
    run_islands(a.out, params=a.params.split(","), points=a.points, refine=a.refine,
                slice_phases=a.slice_phases, phases=a.phases, window=a.window)
    return 0

if __name__ == "__main__":
    raise SystemExit(main())
