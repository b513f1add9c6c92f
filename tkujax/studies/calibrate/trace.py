"""Print the control-rate trace of one paper row at a calibrated parameter set.

python -m tkujax.studies.calibrate.trace results/calibration/calibration.json ALL back volleyball on
"""

from __future__ import annotations

import sys

import json

import numpy as np

from tkujax.studies.calibrate import evaluate as E
from tkujax.studies.calibrate import params as P


def main(argv=None):
    path, which, direction, ball, control = (argv or sys.argv[1:])[:5]
    summary = json.loads(open(path).read())
    x, reading = summary[which]["x"], summary[which]["reading"]
    mp = P.model_params(x)
    cp = P.controller_params(x, reading, mp)
    i = E.CASES.index((direction, ball))
    s, o = E._simulate(E.pushes_for(x), np.full(4, 1.0 if control == "on" else 0.0, np.float32), cp, mp)
    print("t_s pitch_deg kalman_phi_deg x_sup_cm l_ankle_x_cm r_ankle_x_cm zmp_x_cm")
    for j in range(0, len(s["t"][i])):
        if s["t"][i][j] < 0.6:
            continue
        print(f"{s['t'][i][j]:.2f} {np.degrees(s['pitch'][i][j]):6.2f} {np.degrees(s['pitch_est'][i][j]):6.2f} "
              f"{100 * s['x_sup'][i][j]:6.2f} {100 * s['l_ankle'][i][j][0]:6.2f} "
              f"{100 * s['r_ankle'][i][j][0]:6.2f} {100 * s['zmp'][i][j][0]:6.2f}")
    print({k: float(np.asarray(v)[i]) for k, v in o.items()})


if __name__ == "__main__":
    main()
