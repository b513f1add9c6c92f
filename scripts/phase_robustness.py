"""Per-row outcomes of a calibrated set over the hit's phase relative to the 30 ms IMU/control
sampling (0-27 ms, the paper does not give it; each of its rows is one trial), control off and
on: the fraction of phases at which each row matches the paper (fall outcome; step ±30 %).

python scripts/phase_robustness.py results/calibration/calibration.json ALL --out OUT.json
"""

from __future__ import annotations

import sys

import numpy as np

from _fit import check_out, fit_params, parser, write_json


def main(argv=None):
    ap = parser(__doc__, "JSON {phases_ms, rows: per-row tallies}")
    a = ap.parse_args(argv)
    out = check_out(ap, [a.calibration], a.out)
    from tkujax.sim import push as push_lib
    from tkujax.studies.calibrate import paper_rows as E
    from tkujax.studies.calibrate import targets as T

    x, reading, mp, cp = fit_params(a.calibration, a.which)
    phases = np.arange(0.0, 0.030, 0.003)
    tally = {}
    for ph in phases:
        pushes = push_lib.stack_pushes([
            push_lib.make_push(x["impulse_factor"] * push_lib.ball_momentum_ns(b),
                               push_lib.DIRECTIONS[d], height_m=x["push_height_m"],
                               onset_s=0.75 + float(ph)) for d, b in E.CASES])
        res = {}
        for c, en in (("off", 0.0), ("on", 1.0)):
            s, o = E.simulate_cases(pushes, np.full(4, en, np.float32), cp, mp)
            res.update(E.case_rows(s, o, c, cp))
        for k in T.ROWS:
            rec_p, step_p = T.PAPER_TABLE[k]
            r = res[k]
            fall_ok = r["fell"] == (rec_p is None)
            step_ok = step_p is None or (not r["fell"] and (r["step_cm"] > 0) == (k[0] == "back")
                                         and abs(abs(r["step_cm"]) - step_p) <= T.STEP_TOL * step_p)
            t = tally.setdefault("/".join(k), dict(fall_ok=0, step_ok=0, n=0, steps=[]))
            t["fall_ok"] += int(fall_ok)
            t["step_ok"] += int(step_ok)
            t["n"] += 1
            t["steps"].append(round(r["step_cm"], 2) if not r["fell"] else "fell")
        row = {"/".join(k): ("F" if res[k]["fell"] else round(res[k]["step_cm"], 1))
               for k in T.ROWS}
        print(f"phase {1e3 * ph:4.1f} ms:", row, flush=True)
    for k, t in tally.items():
        print(k, f"fall as paper {t['fall_ok']}/{t['n']}", f"step ok {t['step_ok']}/{t['n']}")
    write_json(out, dict(phases_ms=(1e3 * phases).tolist(), rows=tally))


if __name__ == "__main__":
    main(sys.argv[1:])
