"""A push sweep and its stability maps, on the MuJoCo C backend (no MJX compile).

    python examples/sweep_and_map.py            # specs/sweep/stability_map_cpu.toml, minutes
    python examples/sweep_and_map.py --small    # 16 pushes, seconds (CI)

Writes runs/examples/sweep_and_map/ (the sweep's chunks and manifest, maps/: PNG figures and
summary.md) and runs/examples/sweep_and_map.parquet, the records as one file that any Parquet
reader (DuckDB, polars, pandas) opens.
"""

import argparse
import os
from pathlib import Path

import tkujax
from tkujax.sweeps.table_export import export_records

ROOT = Path(__file__).resolve().parents[1]
SMALL_SPEC = """
[sweep]
name = "example_small"
seed = 0
chunk_size = 8
duration_s = 1.5
control = ["off", "on"]

[push.grid]
impulse_ns = [0.5, 1.5, 2.5, 3.5]
azimuth_deg = [0, 180]
onset_s = [0.3]
"""


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true",
                        default=os.environ.get("TKUJAX_EXAMPLES_SMALL") == "1",
                        help="CI size (also TKUJAX_EXAMPLES_SMALL=1)")
    parser.add_argument("--out", default=str(ROOT / "runs" / "examples" / "sweep_and_map"))
    args = parser.parse_args(argv)
    out = Path(args.out)
    if args.small:
        out.mkdir(parents=True, exist_ok=True)
        spec = out.parent / f"{out.name}.toml"
        spec.write_text(SMALL_SPEC)
    else:
        spec = ROOT / "specs" / "sweep" / "stability_map_cpu.toml"
    tkujax.run_sweep(spec, out, backend="mujoco")
    maps = tkujax.make_maps(out)
    records = tkujax.load(out)
    for control in (False, True):
        fell = records["fell"][records["control"] == control]
        state = "on " if control else "off"
        print(f"control {state}: {fell.mean():.1%} of {fell.size} pushes fell")
    parquet = export_records(out)                     # beside the folder: DIR.parquet
    print("\n".join(maps["files"]))
    print(parquet)
    return dict(records=records, maps=maps, parquet=parquet)


if __name__ == "__main__":
    main()
