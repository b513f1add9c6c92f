"""Pushes while walking, recovery off against on, on MuJoCo C (results/walking/push_set_*.json).

    python scripts/walk_push_set.py --out results/walking/push_set_tkux_cpu.json

TKU-X (or --robot FILE) walking its default gait at each --speeds value; pushes of the chest
(`tkujax.walking.walk_push.push_at_gait_phase`: 20 ms half-sine at the default height) from 8
directions x 7 impulses (0.3-2.0 N s) x 8 gait phases (0 = the left foot's touchdown), in the
10th gait cycle, simulated 3 s past the onset. Each set runs with the footstep recovery off and
on (balance control on in both; `tkujax.control.walk_recovery`), for the robot's controller
and, with --lateral, the same controller with sideways steps (lateral_steps = 1). Falls per
run, direction, impulse and phase, of the sideways pushes per foot whose step they arrive in,
and the pushes that fall in one run only; the machine (--machine) and wall times go in the
file.

--azimuths, --impulses, --phases, --height-m and --duration-s set other pushes;
--forward-gain sets WalkCommand.recovery_forward_gain, --late-swing-gains and --hurries one
recovery-on run per value of WalkCommand.recovery_late_swing_gain and recovery_hurry (all
against the one recovery-off run),
e.g. OP3's sideways set (docs/walking.md):

    python scripts/walk_push_set.py --robot specs/robots/op3_fast.toml --out OUT.json \
        --azimuths 80,90,100,260,270,280 --impulses 1.2,1.35,1.5,1.65 --phases 12 \
        --height-m 0.275 --duration-s 0.03 --forward-gain 0 --late-swing-gains 1,0
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from tkujax.sim.push import DEFAULT_DURATION_S
from tkujax.walking.walk import walker
from tkujax.walking.walk_push import WalkPushSet, run_walk_pushes

AZIMUTHS = tuple(float(a) for a in range(0, 360, 45))
IMPULSES = (0.3, 0.5, 0.7, 0.9, 1.2, 1.5, 2.0)
PHASES = 8


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split(","))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default=None, help="a robot file (default: TKU-X)")
    ap.add_argument("--out", required=True)
    ap.add_argument("--speeds", default="0.1", help="comma-separated walking speeds (m/s)")
    ap.add_argument("--lateral", action="store_true",
                    help="also the controller with sideways steps (lateral_steps = 1)")
    ap.add_argument("--machine", default="2-core CPU, MuJoCo C")
    ap.add_argument("--azimuths", type=_floats, default=AZIMUTHS,
                    help="comma-separated push directions (deg, 0 = from behind, 90 = from the "
                         "right)")
    ap.add_argument("--impulses", type=_floats, default=IMPULSES,
                    help="comma-separated impulses (N s)")
    ap.add_argument("--phases", type=int, default=PHASES,
                    help="gait phases k / N, k = 0 .. N - 1 (default 8)")
    ap.add_argument("--height-m", type=float, default=None,
                    help="push height (m; default: TKU-X's chest)")
    ap.add_argument("--duration-s", type=float, default=DEFAULT_DURATION_S,
                    help="push duration (s)")
    ap.add_argument("--forward-gain", type=float, default=1.0,
                    help="WalkCommand.recovery_forward_gain of the recovery-on runs")
    ap.add_argument("--late-swing-gains", type=_floats, default=(1.0,),
                    help="comma-separated WalkCommand.recovery_late_swing_gain values, one "
                         "recovery-on run each")
    ap.add_argument("--hurries", type=_floats, default=(0.0,),
                    help="comma-separated WalkCommand.recovery_hurry values (the share of a "
                         "step's remaining time cut once it takes an offset), one recovery-on "
                         "run each with every late-swing gain")
    args = ap.parse_args(argv)
    if args.phases < 1:
        ap.error("--phases must be at least 1")
    if args.robot is not None and Path(args.out).resolve() == Path(args.robot).resolve():
        ap.error(f"--out {args.out} is the input")
    who = walker(args.robot)
    variants = {"controller": who}
    if args.lateral:
        variants["lateral_steps"] = dataclasses.replace(
            who, params=dataclasses.replace(who.params, lateral_steps=1.0))
    settings = {}
    for gain in args.late_swing_gains:
        for share in args.hurries:
            fields, name = {}, "recovery_on"
            if args.forward_gain != 1.0:
                fields["recovery_forward_gain"] = args.forward_gain
            if gain != 1.0:
                fields["recovery_late_swing_gain"] = gain
                name += f"_late_swing_gain_{gain:g}"
            if share != 0.0:
                fields["recovery_hurry"] = share
                name += f"_hurry_{share:g}"
            settings[name] = fields
    runs = []
    for speed in (float(v) for v in args.speeds.split(",")):
        push_set = WalkPushSet(speed_mps=speed, azimuths_deg=args.azimuths,
                               impulses_ns=args.impulses,
                               phases=tuple(k / args.phases for k in range(args.phases)),
                               height_m=args.height_m, duration_s=args.duration_s)
        for name, w in variants.items():
            result = run_walk_pushes(push_set, who=w, settings=settings)
            result["variant"] = name
            runs.append(result)
            ons = ", ".join(f"{s} {result[s]['falls']}" for s in settings)
            print(f"{who.name} {speed} m/s {name}: falls off {result['recovery_off']['falls']}, "
                  f"{ons} of {result['n']}", file=sys.stderr)
    out = dict(robot=who.name, robot_file=args.robot,
               robot_sha256=getattr(who.robot, "digest", None), machine=args.machine,
               engine="mujoco", runs=runs)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
