"""Print the control-rate trace of one paper row at a calibrated parameter set (stdout only:
it writes no file).

python scripts/trace.py results/calibration/calibration.json ALL back volleyball on
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from _fit import fit_params


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("calibration", type=Path)
    ap.add_argument("which")
    ap.add_argument("direction", choices=("back", "front"))
    ap.add_argument("ball", choices=("baseball", "volleyball"))
    ap.add_argument("control", choices=("off", "on"))
    a = ap.parse_args(argv)
    from tkujax.studies.calibrate import paper_rows as E

    x, reading, mp, cp = fit_params(a.calibration, a.which)
    i = E.CASES.index((a.direction, a.ball))
    enabled = np.full(4, 1.0 if a.control == "on" else 0.0, np.float32)
    s, o = E.simulate_cases(E.pushes_for(x), enabled, cp, mp)
    print("t_s pitch_deg kalman_phi_deg x_sup_cm l_ankle_x_cm r_ankle_x_cm zmp_x_cm")
    for j in range(0, len(s["t"][i])):
        if s["t"][i][j] < 0.6:
            continue
        print(f"{s['t'][i][j]:.2f} {np.degrees(s['pitch'][i][j]):6.2f} "
              f"{np.degrees(s['pitch_est'][i][j]):6.2f} "
              f"{100 * s['x_sup'][i][j]:6.2f} {100 * s['l_ankle'][i][j][0]:6.2f} "
              f"{100 * s['r_ankle'][i][j][0]:6.2f} {100 * s['zmp'][i][j][0]:6.2f}")
    print({k: float(np.asarray(v)[i]) for k, v in o.items()})


if __name__ == "__main__":
    main(sys.argv[1:])
