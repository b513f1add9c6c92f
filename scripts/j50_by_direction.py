"""50 %-fall impulse per push direction from the grid part of a sweep (control off and on).

For each azimuth of the grid, the fall rate over the grid's other axes (hit phases, robot
draws) is taken per impulse, and the impulse where it first reaches 50 % is interpolated
linearly between the grid impulses. Prints one JSON object per sweep folder.

    python scripts/j50_by_direction.py SWEEP_DIR [SWEEP_DIR ...]
"""

from __future__ import annotations

import json
import sys

import numpy as np

from tkujax.sweeps.sweep import load


def j50(rec: dict, control: int, azimuth_deg: float) -> float:
    """Impulse (N s) at which the fall rate first reaches 0.5 (inf if it never does)."""
    near = np.abs((rec["azimuth_deg"] - azimuth_deg + 180.0) % 360.0 - 180.0) < 1e-3
    m = rec["from_grid"].astype(bool) & (rec["control"] == control) & near
    impulse, fell = rec["impulse_ns"][m], rec["fell"][m].astype(float)
    js = np.unique(impulse)
    rate = np.array([fell[impulse == j].mean() for j in js])
    above = np.flatnonzero(rate >= 0.5)
    if len(above) == 0:
        return float("inf")
    k = int(above[0])
    if k == 0:
        return float(js[0])
    return float(js[k - 1] + (0.5 - rate[k - 1]) / (rate[k] - rate[k - 1]) * (js[k] - js[k - 1]))


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__)
        return 2
    for path in argv:
        rec = load(path)
        azs = np.unique(np.round(rec["azimuth_deg"][rec["from_grid"].astype(bool)], 6))
        row = {f"{az:g}": {"off": round(j50(rec, 0, az), 3), "on": round(j50(rec, 1, az), 3)}
               for az in azs}
        print(json.dumps({"sweep": path, "j50_ns": row}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
