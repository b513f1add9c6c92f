"""Tune the controller's step period, double-support ratio and capture-point gain by CMA-ES
through MJX on a small batch of sagittal pushes, then keep the tuned set only if it is better
on held-out pushes.

    python examples/tune_tiny.py            # specs/tune/tune_cpu.toml (~7 min on 2 CPU cores)
    python examples/tune_tiny.py --small    # 4 pushes, 2 generations, no held-out check (CI;
                                            # the MJX compile takes most of its minutes)

Writes runs/examples/tune/: params_after.json (use it with `tkujax sweep --params`),
history.json, summary.md and the figures.
"""

import argparse
import os
from pathlib import Path

import tkujax

ROOT = Path(__file__).resolve().parents[1]
SMALL_SPEC = {
    "tune": {"name": "tune_example_small", "method": "cma", "popsize": 3, "iterations": 2,
             "batch": 4, "duration_s": 1.0,
             "params": ["step_period", "double_support_ratio", "cp_gain"], "remat": False},
    "push": {"impulse_ns": {"uniform": [0.4, 1.4]}, "azimuth_deg": [0, 180], "onset_s": 0.3},
}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true",
                        default=os.environ.get("TKUJAX_EXAMPLES_SMALL") == "1",
                        help="CI size (also TKUJAX_EXAMPLES_SMALL=1)")
    parser.add_argument("--out", default=str(ROOT / "runs" / "examples" / "tune"))
    args = parser.parse_args(argv)
    if args.small:
        record = tkujax.run_tune(SMALL_SPEC, args.out, evaluation=False, compare=False)
    else:
        record = tkujax.run_tune(ROOT / "specs" / "tune" / "tune_cpu.toml", args.out)
    print(f"{record['method']}: {record['iterations']} iterations, best training loss "
          f"{record['run']['best_loss']:.4f}")
    for name, values in record["params_user"].items():
        print(name, {k: round(v, 4) for k, v in values.items()})
    print(Path(args.out, "summary.md"))
    return record


if __name__ == "__main__":
    main()
