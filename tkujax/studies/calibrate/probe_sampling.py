"""Probe: how much the Kalman angle excursion (and so the step trigger) depends on the ball's
contact time and on the hit's phase relative to the 30 ms IMU sampling, at a given candidate.

python -m tkujax.studies.calibrate.probe_sampling results/calibration/calibration.json [ALL|T4]
"""

from __future__ import annotations

import json
import sys

import numpy as np

from tkujax.sim import push as push_lib
from tkujax.studies.calibrate import evaluate as E
from tkujax.studies.calibrate import params as P


def main(argv=None):
    argv = argv or sys.argv[1:]
    summary = json.loads(open(argv[0]).read())
    which = argv[1] if len(argv) > 1 else "ALL"
    x, reading = summary[which]["x"], summary[which]["reading"]
    mp = P.model_params(x)
    cp = P.controller_params(x, reading, mp)
    rows = []
    for dur in (0.010, 0.020, 0.030, 0.040):
        for phase in (0.0, 0.010, 0.020):
            pushes = push_lib.stack_pushes([
                push_lib.make_push(x["impulse_factor"] * push_lib.ball_momentum_ns(b),
                                   push_lib.DIRECTIONS[d], height_m=x["push_height_m"],
                                   duration_s=dur, onset_s=0.75 + phase)
                for d, b in E.CASES])
            s, o = E._simulate(pushes, np.ones(4, np.float32), cp, mp)
            phi = np.degrees(np.asarray(s["pitch_est"], float))
            row = dict(duration_ms=1e3 * dur, phase_ms=1e3 * phase)
            for i, (d, b) in enumerate(E.CASES):
                row[f"{d}-{b}"] = dict(phi_max=round(float(phi[i].max()), 2),
                                       phi_min=round(float(phi[i].min()), 2),
                                       fell=bool(o["fell"][i]),
                                       step_cm=round(100 * float(o["step_length_m"][i]), 2))
            print(row, flush=True)
            rows.append(row)
    out = argv[0].replace("calibration.json", f"probe_sampling_{which}.json")
    open(out, "w").write(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
