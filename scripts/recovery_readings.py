"""Research: the two recovery readings (hypot(pitch, roll) vs pitch only) on the default robot's
8 paper rows at 15 hit phases, and what each does to the calibration loss (targets.table_loss,
the fit's objective). MuJoCo C, noise-free, the default controller
(results/calibration/recovery_readings).

PYTHONPATH=. python scripts/recovery_readings.py results/calibration/recovery_readings
Writes recovery_readings.json and recovery_readings.md into the given folder.
"""

import json
import math
import sys
from pathlib import Path

import numpy as np

from tkujax.studies.calibrate import paper_rows as E
from tkujax.studies.calibrate import islands as I
from tkujax.studies.calibrate import fit_vector as P
from tkujax.studies.calibrate import targets as T


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    x = P.base_vector()
    reading = I.default_reading()
    phases = I.phases_ms(15)
    mp = P.model_params(x)
    pushes = E.pushes_for(x, phases)
    n = len(E.CASES) * len(phases)
    cp = P.controller_params(x, reading, mp)
    res = {"hypot": {}, "pitch": {}}
    for control, en in (("off", 0.0), ("on", 1.0)):
        s, o = E.simulate_cases(pushes, np.full(n, en, np.float32), cp, mp)
        for name, key in (("hypot", "recovery_time_s"), ("pitch", "recovery_time_pitch_s")):
            oo = {k: o[k] for k in o.keys()}
            oo["recovery_time_s"] = o[key]
            for k, ph in enumerate(phases):
                res[name].setdefault(ph, {}).update(
                    E.case_rows(s, oo, control, cp, len(E.CASES) * k))
    summary = {}
    for name in res:
        losses = [T.table_loss(res[name][ph])[0] for ph in phases]
        summary[name] = dict(loss_phase0=losses[0], loss_mean=float(np.mean(losses)),
                             score_phase0=T.score(res[name][0.0]))
    rows = {}
    for key in T.ROWS:
        rows["/".join(key)] = {name: [None if math.isnan(res[name][ph][key]["rec"]) else
                                      round(res[name][ph][key]["rec"], 3) for ph in phases]
                               for name in res} | {"fell": [res["hypot"][ph][key]["fell"]
                                                            for ph in phases]}
    (out / "recovery_readings.json").write_text(json.dumps(
        dict(phases_ms=list(phases), reading=reading, summary=summary, rows=rows), indent=1))
    fmt = lambda v: "not settled" if v is None else f"{v:.2f}"  # noqa: E731
    md = ["| row | paper | hypot, phase 0 | pitch only, phase 0 | hypot settles at (of 15 "
          "phases; median s) | pitch only settles at (of 15; median s) |",
          "|---|---|---|---|---|---|"]
    for key in T.ROWS:
        r = rows["/".join(key)]
        up = [not f for f in r["fell"]]
        cells = []
        for name in ("hypot", "pitch"):
            v = [t for t, u in zip(r[name], up) if u and t is not None]
            cells.append(f"{len(v)}/15" + (f"; {np.median(v):.2f}" if v else ""))
        p0 = "falls" if r["fell"][0] else None
        md.append(f"| {' '.join(key)} | {T.PAPER_TABLE[key][0] or 'falls'} | "
                  f"{p0 or fmt(r['hypot'][0])} | {p0 or fmt(r['pitch'][0])} | {cells[0]} | "
                  f"{cells[1]} |")
    md += ["", "Calibration loss (targets.table_loss, all 8 rows) of the default robot with each "
           "reading: " + "; ".join(
               f"{name}: {v['loss_phase0']:.2f} at phase 0, {v['loss_mean']:.2f} mean over the "
               f"15 phases, score at phase 0 {v['score_phase0']}" for name, v in summary.items())]
    (out / "recovery_readings.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
