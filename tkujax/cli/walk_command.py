"""`tkujax walk`: the robot walks from its controller's CPG; prints what was measured (JSON)."""

from __future__ import annotations

import json

from tkujax.cli.errors import bounded_float


def _cmd_walk(args) -> int:
    from tkujax.walking.walk import walk_once

    draw = args.gif is not None or args.png is not None
    if draw:
        from tkujax import render
        render.check_rendering()          # before the walk, not after it
    result, series, who, command = walk_once(
        args.robot, speed_mps=args.speed_mps, lateral_mps=args.lateral_mps,
        seconds=args.seconds, engine=args.engine, step_period_s=args.step_period_s,
        enabled=args.control == "on", lift_m=args.lift_m, sway_m=args.sway_m)
    if draw:
        result["figures"] = render.walk_figures(result, series, who, command, args.gif, args.png)
    print(json.dumps(result, indent=2))
    return 1 if result["fell"] else 0


def add_walk_command(sub) -> None:
    """walk."""
    p = sub.add_parser("walk", help="walk the robot with its controller's CPG gait and print "
                                    "what was measured (docs/walking.md)")
    p.add_argument("--robot", default=None, metavar="FILE.toml",
                   help="a robot file (docs/robots.md); default: TKU-X")
    p.add_argument("--speed-mps", type=bounded_float(-1.0, 1.0), default=0.1,
                   help="forward speed (negative: backward; 0: stepping in place)")
    p.add_argument("--lateral-mps", type=bounded_float(-0.5, 0.5), default=0.0,
                   help="sideways speed (positive: to the left)")
    p.add_argument("--step-period-s", type=bounded_float(0.1, 2.0), default=None,
                   help="the step period T (default: the robot file's [walk], else the "
                        "robot's controller's T)")
    p.add_argument("--lift-m", type=bounded_float(0.0, 0.1), default=None,
                   help="the swing foot's lift (default: the robot file's [walk], else the "
                        "controller's H_Sup)")
    p.add_argument("--sway-m", type=bounded_float(-0.25, 0.25), default=None,
                   help="the waist's sway toward the support foot (default: the robot file's "
                        "[walk], else a third of the hip offset d_y)")
    p.add_argument("--seconds", type=bounded_float(0.1, 600.0), default=20.0)
    p.add_argument("--engine", choices=["mujoco", "mjx"], default="mujoco")
    p.add_argument("--control", choices=["on", "off"], default="on",
                   help="the balance controller's stance feedback while walking")
    p.add_argument("--gif", default=None, metavar="F.gif",
                   help="also write the walk as a video (needs EGL or OSMesa)")
    p.add_argument("--png", default=None, metavar="F.png",
                   help="also write a picture: six frames over the last gait cycle")
    p.set_defaults(func=_cmd_walk)
