"""Probe: how much the Kalman angle excursion (and so the step trigger) depends on the ball's
contact time and on the hit's phase relative to the 30 ms IMU sampling, at a given candidate.

python scripts/probe_sampling.py results/calibration/calibration.json ALL --out OUT.json
"""

from __future__ import annotations

import sys

import numpy as np

from _fit import check_out, fit_params, parser, write_json


def main(argv=None):
    ap = parser(__doc__, "JSON list of the probed rows")
    a = ap.parse_args(argv)
    out = check_out(ap, [a.calibration], a.out)
    from tkujax.sim import push as push_lib
    from tkujax.studies.calibrate import paper_rows as E

    x, reading, mp, cp = fit_params(a.calibration, a.which)
    rows = []
    for dur in (0.010, 0.020, 0.030, 0.040):
        for phase in (0.0, 0.010, 0.020):
            pushes = push_lib.stack_pushes([
                push_lib.make_push(x["impulse_factor"] * push_lib.ball_momentum_ns(b),
                                   push_lib.DIRECTIONS[d], height_m=x["push_height_m"],
                                   duration_s=dur, onset_s=0.75 + phase)
                for d, b in E.CASES])
            s, o = E.simulate_cases(pushes, np.ones(4, np.float32), cp, mp)
            phi = np.degrees(np.asarray(s["pitch_est"], float))
            row = dict(duration_ms=1e3 * dur, phase_ms=1e3 * phase)
            for i, (d, b) in enumerate(E.CASES):
                row[f"{d}-{b}"] = dict(phi_max=round(float(phi[i].max()), 2),
                                       phi_min=round(float(phi[i].min()), 2),
                                       fell=bool(o["fell"][i]),
                                       step_cm=round(100 * float(o["step_length_m"][i]), 2))
            print(row, flush=True)
            rows.append(row)
    write_json(out, rows)


if __name__ == "__main__":
    main(sys.argv[1:])
