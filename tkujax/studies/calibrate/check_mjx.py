"""Cross-check a calibrated set on the MJX closed loop (tkujax.sim.simulate, the backend of
`tkujax paper`) against the MuJoCo C numbers of the fit.

python -m tkujax.studies.calibrate.check_mjx results/calibration/calibration.json ALL
"""

from __future__ import annotations

import json
import sys

import numpy as np

from tkujax.studies.calibrate import evaluate as E
from tkujax.studies.calibrate import params as P


def main(argv=None):
    path, which = (argv or sys.argv[1:])[:2]
    summary = json.loads(open(path).read())
    x, reading = summary[which]["x"], summary[which]["reading"]
    mp = P.model_params(x)
    cp = P.controller_params(x, reading, mp)
    from tkujax.sim.rollout_mjx import simulate
    import jax
    push = E.pushes_for(x)
    pushes = jax.tree_util.tree_map(lambda a: np.concatenate([a, a]), push)
    enabled = np.array([0.0] * 4 + [1.0] * 4, np.float32)
    _, o = simulate(pushes, enabled, cp, model_params=mp)
    rows = {}
    for i in range(8):
        d, b = E.CASES[i % 4]
        c = "off" if i < 4 else "on"
        r = dict(fell=bool(o["fell"][i]), rec=float(o["recovery_time_s"][i]),
                 step_cm=100 * float(o["step_length_m"][i]))
        rows[f"{d}/{b}/{c}"] = r
        mj = summary[which]["rows"][f"{d}/{b}/{c}"]
        print(f"{d}/{b}/{c}: MJX {r}  MuJoCo C fell={mj['fell']} rec={mj['rec']:.2f} step={mj['step_cm']:.2f}")
    out = path.replace("calibration.json", f"check_mjx_{which}.json")
    open(out, "w").write(json.dumps(dict(device=str(jax.devices()[0]), rows=rows), indent=1))


if __name__ == "__main__":
    main()
