"""1-D slices of the loss and the acceptance score through a calibrated set (the other
parameters held at the fit; a slice, not a re-optimised profile), for the parameters the
sensitivities flag as pinned.

python scripts/slices.py results/calibration/calibration.json ALL --out OUT.json
"""

from __future__ import annotations

import sys

import numpy as np

from _fit import check_out, load_fit, parser, write_json

SLICED = ("foot_forward_offset_m", "foot_length_m", "leg_kp", "impulse_factor")


def main(argv=None):
    ap = parser(__doc__, "JSON {parameter: [points sorted by value]}")
    a = ap.parse_args(argv)
    out = check_out(ap, [a.calibration], a.out)
    from tkujax.studies.calibrate import paper_rows as E
    from tkujax.studies.calibrate import fit_vector as P
    from tkujax.studies.calibrate import targets as T

    fit = load_fit(a.calibration, a.which)
    x0, reading = fit["x"], fit["reading"]
    rows = T.ROWS if a.which == "ALL" else T.TABLE4
    result = {}
    for name in SLICED:
        p = P.PARAMS[P.NAMES.index(name)]
        pts = []
        for v in np.linspace(p.lo, p.hi, 9).tolist() + [x0[name]]:
            x = dict(x0, **{name: v})
            res = E.evaluate(x, readings=(reading,))[reading]
            loss = T.table_loss(res, rows)[0] + E.stand_penalty(res)
            pts.append(dict(value=v, loss=loss, score=T.score(res, rows),
                            stand_deg=res[rows[0]]["stand_deg"]))
            print(name, f"{v:.4g}", f"{loss:.2f}", pts[-1]["score"],
                  f"lean {pts[-1]['stand_deg']:.2f}", flush=True)
        result[name] = sorted(pts, key=lambda d: d["value"])
    write_json(out, result)


if __name__ == "__main__":
    main(sys.argv[1:])
