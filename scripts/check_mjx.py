"""Cross-check a calibrated set on the MJX closed loop (tkujax.sim.rollout_mjx.simulate, the
backend of `tkujax paper`) against the MuJoCo C numbers of the fit.

python scripts/check_mjx.py results/calibration/calibration.json ALL --out OUT.json
"""

from __future__ import annotations

import sys

import numpy as np

from _fit import check_out, fit_params, load_fit, parser, write_json


def main(argv=None):
    ap = parser(__doc__, "JSON of the MJX rows (device, rows)")
    a = ap.parse_args(argv)
    out = check_out(ap, [a.calibration], a.out)
    import jax

    from tkujax.sim.rollout_mjx import simulate
    from tkujax.studies.calibrate import paper_rows as E

    x, reading, mp, cp = fit_params(a.calibration, a.which)
    fit = load_fit(a.calibration, a.which)      # its MuJoCo C rows, compared below
    push = E.pushes_for(x)
    pushes = jax.tree_util.tree_map(lambda v: np.concatenate([v, v]), push)
    enabled = np.array([0.0] * 4 + [1.0] * 4, np.float32)
    _, o = simulate(pushes, enabled, cp, model_params=mp)
    rows = {}
    for i in range(8):
        d, b = E.CASES[i % 4]
        c = "off" if i < 4 else "on"
        r = dict(fell=bool(o["fell"][i]), rec=float(o["recovery_time_s"][i]),
                 step_cm=100 * float(o["step_length_m"][i]))
        rows[f"{d}/{b}/{c}"] = r
        mj = fit["rows"][f"{d}/{b}/{c}"]
        print(f"{d}/{b}/{c}: MJX {r}  MuJoCo C fell={mj['fell']} rec={mj['rec']:.2f} "
              f"step={mj['step_cm']:.2f}")
    write_json(out, dict(device=str(jax.devices()[0]), rows=rows))


if __name__ == "__main__":
    main(sys.argv[1:])
