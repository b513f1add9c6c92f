"""50 %-fall impulse per push direction from the grid part of a sweep (control off and on).

For each azimuth of the grid, `tkujax.analysis.map_cells.half_fall_impulse`: the impulse
where the fall rate over the grid's other axes first reaches 50 %, linear between impulses.
Prints one JSON object per sweep folder.

    python scripts/j50_by_direction.py SWEEP_DIR [SWEEP_DIR ...]
"""

from __future__ import annotations

import json
import sys

from tkujax.analysis.map_cells import half_fall_impulse
from tkujax.sweeps.sweep import load


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__)
        return 2
    for path in argv:
        rec = load(path)
        (azs, off), (_, on) = half_fall_impulse(rec, False), half_fall_impulse(rec, True)
        row = {f"{az:g}": {"off": round(float(a), 3), "on": round(float(b), 3)}
               for az, a, b in zip(azs, off, on)}
        print(json.dumps({"sweep": path, "j50_ns": row}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
