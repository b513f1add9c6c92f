"""Pushes while walking, recovery off against on, on MuJoCo C (results/walking/push_set_*.json).

    python scripts/walk_push_set.py --out results/walking/push_set_tkux_cpu.json

TKU-X (or --robot FILE) walking its default gait at each --speeds value; pushes of the chest
(`tkujax.walking.walk_push.push_at_gait_phase`: 20 ms half-sine at the default height) from 8
directions x 7 impulses (0.3-2.0 N s) x 8 gait phases (0 = the left foot's touchdown), in the
10th gait cycle, simulated 3 s past the onset. Each set runs with the footstep recovery off and
on (balance control on in both; `tkujax.control.walk_recovery`), for the robot's controller
and, with --lateral, the same controller with sideways steps (lateral_steps = 1). Falls per
run, direction, impulse and phase, and the pushes that fall in one run only; the machine
(--machine) and wall times go in the file.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from tkujax.walking.walk import walker
from tkujax.walking.walk_push import WalkPushSet, run_walk_pushes

AZIMUTHS = tuple(float(a) for a in range(0, 360, 45))
IMPULSES = (0.3, 0.5, 0.7, 0.9, 1.2, 1.5, 2.0)
PHASES = tuple(k / 8 for k in range(8))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default=None, help="a robot file (default: TKU-X)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--speeds", default="0.1", help="comma-separated walking speeds (m/s)")
    ap.add_argument("--lateral", action="store_true",
                    help="also the controller with sideways steps (lateral_steps = 1)")
    ap.add_argument("--machine", default="2-core CPU, MuJoCo C")
    args = ap.parse_args(argv)
    if args.robot is not None and Path(args.out).resolve() == Path(args.robot).resolve():
        ap.error(f"--out {args.out} is the input")
    who = walker(args.robot)
    variants = {"controller": who}
    if args.lateral:
        variants["lateral_steps"] = dataclasses.replace(
            who, params=dataclasses.replace(who.params, lateral_steps=1.0))
    runs = []
    for speed in (float(v) for v in args.speeds.split(",")):
        push_set = WalkPushSet(speed_mps=speed, azimuths_deg=AZIMUTHS, impulses_ns=IMPULSES,
                               phases=PHASES)
        for name, w in variants.items():
            result = run_walk_pushes(push_set, who=w)
            result["variant"] = name
            runs.append(result)
            print(f"{who.name} {speed} m/s {name}: falls off {result['recovery_off']['falls']}, "
                  f"on {result['recovery_on']['falls']} of {result['n']}", file=sys.stderr)
    out = dict(robot=who.name, robot_file=args.robot,
               robot_sha256=getattr(who.robot, "digest", None), machine=args.machine,
               engine="mujoco", runs=runs)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
