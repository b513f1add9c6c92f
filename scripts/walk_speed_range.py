"""The forward speeds a robot holds walking 20 s on MuJoCo C (results/walking/speed_range_*.json).

    python scripts/walk_speed_range.py --out results/walking/speed_range_tkux_cpu.json
    python scripts/walk_speed_range.py --robot specs/robots/op3.toml \
        --out results/walking/speed_range_op3_cpu.json

One batch of walks (`tkujax.walking.walk.run_walk`, the robot's default gait: its controller's
T, a third of d_y of sway, a 4-step ramp, under the robot's gait (`Robot.gait`: a robot file's
defaults from its stand and its [walk] table); balance control on, recovery off) at speeds from
--min to --max in --step, for --seconds each. Per speed: fell (and when), the measured mean
speed, step length and period, heading drift. "held": the widest interval of tested speeds
around 0 (stepping in place) in which no walk fell; the robot file's name and sha256, the
machine (--machine, default "2-core CPU, MuJoCo C") and the wall time go in the file.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from tkujax.control.gait import WalkCommand
from tkujax.walking.walk import run_walk, walk_metrics, walker


def held_interval(speeds, fell) -> tuple[float, float] | None:
    """The widest run of consecutive tested speeds containing the one nearest 0 in which none
    fell, as (lowest, highest); None when stepping in place fell."""
    speeds, fell = np.asarray(speeds, float), np.asarray(fell, bool)
    order = np.argsort(speeds)
    speeds, fell = speeds[order], fell[order]
    k = int(np.argmin(np.abs(speeds)))
    if fell[k]:
        return None
    lo = hi = k
    while lo > 0 and not fell[lo - 1]:
        lo -= 1
    while hi < len(speeds) - 1 and not fell[hi + 1]:
        hi += 1
    return float(speeds[lo]), float(speeds[hi])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default=None, help="a robot file (default: TKU-X)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--min", type=float, default=-0.5)
    ap.add_argument("--max", type=float, default=0.5)
    ap.add_argument("--step", type=float, default=0.025)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--machine", default="2-core CPU, MuJoCo C")
    args = ap.parse_args(argv)
    if args.robot is not None and Path(args.out).resolve() == Path(args.robot).resolve():
        ap.error(f"--out {args.out} is the input")
    who = walker(args.robot)
    speeds = np.round(np.arange(args.min, args.max + 0.5 * args.step, args.step), 4)
    commands = [WalkCommand.for_params(who.gait_params, float(v), **who.gait) for v in speeds]
    t0 = time.perf_counter()
    series, _ = run_walk(who, commands, args.seconds, "mujoco")
    wall = time.perf_counter() - t0
    rows = [dict(speed_mps=float(v), **walk_metrics(series, i, c))
            for i, (v, c) in enumerate(zip(speeds, commands))]
    held = held_interval(speeds, [r["fell"] for r in rows])
    result = dict(robot=who.name, robot_file=args.robot,
                  robot_sha256=getattr(who.robot, "digest", None), machine=args.machine,
                  engine="mujoco", seconds=args.seconds, wall_s=round(wall, 1),
                  gait={k: float(getattr(commands[0], k)) for k in
                        ("step_period_s", "lift_m", "double_support_ratio", "sway_m",
                         "start_s", "ramp_steps", "com_shift_m")},
                  held_mps=held, rows=rows)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=1) + "\n")
    print(f"{who.name}: held {held} m/s for {args.seconds} s ({wall:.0f} s wall)", file=sys.stderr)


if __name__ == "__main__":
    main()
