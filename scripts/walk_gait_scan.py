"""A robot's CPG gait over sway, double support, lift and step period, walking on MuJoCo C
(results/walking/heavy_gait_scan_cpu.json holds G1, H1 and T1):

    python scripts/walk_gait_scan.py --robot specs/robots/g1.toml --speed-mps 0 --seconds 10 \
        --out runs/g1_gait_scan.json

The robot's scaled gait without a robot file's defaults from its stand (`Robot.gait`: the
shift that centres the CoM, the lift's cap), as the committed scans were run before them.
One batch of walks (`tkujax.walking.walk.run_walk`, balance control on, recovery off) over
every combination of --sway-frac (the sway as a fraction of the hip offset d_y), --dsr (the
double support ratio), --lift-m and --period-x (the step period as a multiple of the robot's
scaled T). Per walk: fell, when, and the CoM's travel forward and sideways. The robot and the
counts go in the file, whose "runs" list it appends to when it exists.
"""

from __future__ import annotations

import argparse
import itertools
import json
import re
from pathlib import Path

from tkujax.control.gait import WalkCommand
from tkujax.walking.walk import run_walk, walk_metrics, walker

COLUMNS = ["sway_frac_of_dy", "double_support_ratio", "lift_m", "step_period_x", "fell",
           "fall_s", "forward_m", "lateral_m"]


def scan(robot_file: str, speed_mps: float, seconds: float, sway_frac, dsr, lift_m,
         period_x) -> dict:
    """One run of the scan: every combination walked once, as the file's "runs" entry."""
    who = walker(robot_file)
    d_y, period = float(who.gait_params.hip_offset_y), float(who.gait_params.step_period)
    grid = list(itertools.product(sway_frac, dsr, lift_m, period_x))
    commands = [WalkCommand.for_params(who.gait_params, speed_mps, 0.0, sway_m=s * d_y,
                                       double_support_ratio=g, lift_m=h,
                                       step_period_s=x * period).validate()
                for s, g, h, x in grid]
    series, _ = run_walk(who, commands, seconds, "mujoco", 1.0)
    rows = []
    for i, (cell, command) in enumerate(zip(grid, commands)):
        m = walk_metrics(series, i, command)
        fall = m["fall_s"] if m["fell"] else None
        rows.append(list(cell) + [bool(m["fell"]), None if fall is None else round(fall, 2),
                                  round(m["forward_m"], 3), round(m["lateral_m"], 3)])
    return {"robot": who.name, "speed_mps": speed_mps, "seconds": seconds, "columns": COLUMNS,
            "rows": rows, "stood": sum(not r[4] for r in rows), "of": len(rows)}


def _dumps(record: dict) -> str:
    """The record as JSON with one walk (row) per line."""
    text = json.dumps(record, indent=1)
    return re.sub(r"\[\s+([^\[\]{}]*?)\s+\]",
                  lambda m: "[" + " ".join(m.group(1).split()) + "]", text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", required=True, metavar="FILE.toml")
    ap.add_argument("--speed-mps", type=float, default=0.0)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--sway-frac", type=float, nargs="+", default=[0.4, 0.55, 0.7])
    ap.add_argument("--dsr", type=float, nargs="+", default=[0.2, 0.35])
    ap.add_argument("--lift-m", type=float, nargs="+", default=[0.02, 0.03, 0.04])
    ap.add_argument("--period-x", type=float, nargs="+", default=[1.0, 1.3])
    ap.add_argument("--out", required=True, type=Path)
    args = ap.parse_args(argv)
    run = scan(args.robot, args.speed_mps, args.seconds, args.sway_frac, args.dsr,
               args.lift_m, args.period_x)
    record = (json.loads(args.out.read_text()) if args.out.is_file()
              else {"device": "cpu (MuJoCo C)", "runs": []})
    record["runs"].append(run)
    args.out.write_text(_dumps(record) + "\n")
    print(f"{run['robot']} at {run['speed_mps']} m/s: {run['stood']} of {run['of']} stood")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
