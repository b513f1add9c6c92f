"""One-at-a-time sensitivities of the paper rows to each fitted parameter (bounds lo/hi).

python -m tkujax.studies.calibrate.sensitivity [--center JSON] --out results/calibration/sensitivity.json
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from tkujax.studies.calibrate import evaluate as E
from tkujax.studies.calibrate import params as P
from tkujax.studies.calibrate import targets as T

KEYS = [("back", "volleyball", "off"), ("back", "baseball", "off"), ("front", "volleyball", "off"),
        ("front", "baseball", "off")]


def summary(res: dict) -> dict:
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
    ap = argparse.ArgumentParser()
    ap.add_argument("--center", default=None, help="JSON {name: value} (default: today's model)")
    ap.add_argument("--out", default="results/calibration/sensitivity.json")
    a = ap.parse_args(argv)
    x0 = P.DEFAULT.copy()
    if a.center:
        d = json.loads(Path(a.center).read_text())
        d = d.get("x", d)
        x0 = np.array([d[n] for n in P.NAMES])
    out = {"center": P.as_dict(x0),
           "base": summary(E.evaluate(x0, readings=("deviation/latched",))["deviation/latched"])}
    print("base", out["base"], flush=True)
    for i, p in enumerate(P.PARAMS):
        for side, val in (("lo", p.lo), ("hi", p.hi)):
            x = x0.copy()
            x[i] = val
            try:
                s = summary(E.evaluate(x, readings=("deviation/latched",))["deviation/latched"])
            except Exception as err:   # noqa: BLE001
                s = {"error": repr(err)}
            out[f"{p.name}={side}"] = s
            print(p.name, side, val, s, flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
