"""One-at-a-time sensitivities of the paper rows to each fitted parameter (bounds lo/hi).

python scripts/sensitivity.py [--center JSON] --out results/calibration/sensitivity.json
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from _fit import check_out, write_json

KEYS = [("back", "volleyball", "off"), ("back", "baseball", "off"), ("front", "volleyball", "off"),
        ("front", "baseball", "off")]


def summary(res: dict) -> dict:
    """The per-row numbers a sensitivity compares: fell, peak, recovery, Kalman angle past the
    threshold (tag: first letters of direction and ball), and the stand lean."""
    s = {}
    for k in KEYS:
        r = res[k]
        tag = f"{k[0][0]}{k[1][0]}"
        s[f"{tag}_fell"] = int(r["fell"])
        s[f"{tag}_peak"] = round(r["peak_deg"], 2)
        s[f"{tag}_rec"] = None if not math.isfinite(r["rec"]) else round(r["rec"], 2)
        s[f"{tag}_phi_past"] = round(r["phi_peak_deg"], 2)
    s["stand"] = round(res[KEYS[0]]["stand_deg"], 2)
    return s


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--center", type=Path, default=None,
                    help="JSON {name: value} (default: today's model)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    out = check_out(ap, [a.center], a.out)
    import numpy as np

    from tkujax.studies.calibrate import paper_rows as E
    from tkujax.studies.calibrate import fit_vector as P

    x0 = P.DEFAULT.copy()
    if a.center:
        d = json.loads(a.center.read_text())
        d = d.get("x", d)
        x0 = np.array([d[n] for n in P.NAMES])
    result = {"center": P.as_dict(x0),
              "base": summary(E.evaluate(x0, readings=("deviation/latched",))
                              ["deviation/latched"])}
    print("base", result["base"], flush=True)
    for i, p in enumerate(P.PARAMS):
        for side, val in (("lo", p.lo), ("hi", p.hi)):
            x = x0.copy()
            x[i] = val
            try:
                s = summary(E.evaluate(x, readings=("deviation/latched",))["deviation/latched"])
            except Exception as err:   # noqa: BLE001  (an invalid model: recorded, not a crash)
                s = {"error": repr(err)}
            result[f"{p.name}={side}"] = s
            print(p.name, side, val, s, flush=True)
    write_json(out, result)


if __name__ == "__main__":
    main(sys.argv[1:])
