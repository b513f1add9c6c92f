"""1-D slices of the loss and the 'done when' score through a calibrated set (the other
parameters held at the fit; a slice, not a re-optimised profile), for the parameters the
sensitivities flag as pinned.

python -m tkujax.studies.calibrate.slices results/calibration/calibration.json ALL
"""

from __future__ import annotations

import json
import sys

import numpy as np

from tkujax.studies.calibrate import evaluate as E
from tkujax.studies.calibrate import params as P
from tkujax.studies.calibrate import targets as T

SLICED = ("foot_forward_offset_m", "foot_length_m", "leg_kp", "impulse_factor")


def main(argv=None):
    path, which = (argv or sys.argv[1:])[:2]
    summary = json.loads(open(path).read())
    x0, reading = summary[which]["x"], summary[which]["reading"]
    rows = T.ROWS if which == "ALL" else T.TABLE4
    out = {}
    for name in SLICED:
        p = P.PARAMS[P.NAMES.index(name)]
        pts = []
        for v in np.linspace(p.lo, p.hi, 9).tolist() + [x0[name]]:
            x = dict(x0, **{name: v})
            res = E.evaluate(x, readings=(reading,))[reading]
            loss = T.table_loss(res, rows)[0] + E.stand_penalty(res)
            pts.append(dict(value=v, loss=loss, score=T.score(res, rows),
                            stand_deg=res[rows[0]]["stand_deg"]))
            print(name, f"{v:.4g}", f"{loss:.2f}", pts[-1]["score"], f"lean {pts[-1]['stand_deg']:.2f}", flush=True)
        out[name] = sorted(pts, key=lambda d: d["value"])
    open(path.replace("calibration.json", f"slices_{which}.json"), "w").write(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
