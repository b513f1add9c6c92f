"""Commands about the robot itself: stand, walk, render, paper."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from tkujax.cli.errors import bounded_float, bounded_int
from tkujax.cli.shared_options import RENDER_HELP, model_params_from_options, policy_from_option
from tkujax.cli.walk_command import add_walk_command


def _cmd_stand(args) -> int:
    if args.robot is not None:
        from tkujax.robot.file_summary import robot_stand_summary

        summary = robot_stand_summary(args.robot, seconds=args.seconds)
        print(json.dumps(summary, indent=2))
        return 1 if summary["fell"] else 0
    from tkujax.robot.stand_report import simulate_stand

    result = simulate_stand(seconds=args.seconds, batch=args.batch, engine=args.engine,
                            perturb_deg=args.perturb_deg, seed=args.seed)
    print(json.dumps(result, indent=2))
    return 1 if result["fell"] else 0


def _cmd_render(args) -> int:
    from tkujax import render
    from tkujax.sim import physics

    ok, why = render.rendering_available()
    if not ok:
        print(f"tkujax render: offscreen rendering is unavailable: {why}\n{RENDER_HELP}",
              file=sys.stderr)
        return 2
    if args.case is None:
        model = physics.host_model()
        data = physics.stand_data(model)
        frame = render.render_frames(model, data.qpos[None], args.width, args.height)[0]
        print(render.save_image(frame, args.out))
        return 0
    print(render.render_case(args.case, args.control == "on", args.out, args.width, args.height,
                      impulse_scale=args.impulse_scale))
    return 0


def _cmd_paper(args) -> int:
    from tkujax.studies.paper import run_paper

    params, schedule = policy_from_option(args.params)
    summary = run_paper(Path(args.out), figures=not args.no_figures, params=params,
                        schedule=schedule, impulse_scale=args.impulse_scale,
                        model_params=model_params_from_options(args.model, args.variant),
                        phases=args.phases, variant=args.variant)
    print(summary)
    return 0


def add_robot_commands(sub) -> None:
    """stand, walk, render, paper."""
    _add_stand(sub)
    add_walk_command(sub)
    _add_render(sub)
    _add_paper(sub)


def _add_stand(sub) -> None:
    p = sub.add_parser("stand", help="simulate the robot standing and print what was measured")
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--batch", type=int, default=8, help="robots simulated at once")
    p.add_argument("--engine", choices=["mjx", "mujoco"], default="mjx")
    p.add_argument("--perturb-deg", type=bounded_float(0.0, 45.0), default=1.0,
                   help="initial joint perturbation, uniform +- this many degrees")
    p.add_argument("--seed", type=bounded_int(0, (1 << 32) - 1), default=0)
    p.add_argument("--robot", default=None, metavar="FILE.toml",
                   help="a robot file (docs/robots.md): check it, make its stand and hold it "
                        "--seconds in MuJoCo C (--batch, --engine, --perturb-deg are TKU-X's)")
    p.set_defaults(func=_cmd_stand)


def _add_render(sub) -> None:
    p = sub.add_parser("render", help="offscreen picture (stand) or video (--case) of TKU-X")
    p.add_argument("--out", required=True, help=".png for a still, .gif for a --case video")
    p.add_argument("--case", default=None,
                   help="paper case, e.g. volleyball-back (ball-direction); omit for the stand "
                        "pose")
    p.add_argument("--control", choices=["on", "off"], default="on")
    p.add_argument("--impulse-scale", type=float, default=1.0,
                   help="multiply the ball's momentum (1 = the paper's rig)")
    p.add_argument("--width", type=int, default=480)
    p.add_argument("--height", type=int, default=400)
    p.set_defaults(func=_cmd_render)


def _add_paper(sub) -> None:
    p = sub.add_parser("paper", help="reproduce the paper's Tables 4-5 and Figs. 13-16")
    p.add_argument("--out", default="results/paper")
    p.add_argument("--no-figures", action="store_true")
    p.add_argument("--impulse-scale", type=float, default=1.0,
                   help="multiply both balls' momenta (1 = the paper's rig)")
    p.add_argument("--model", action="append", default=[], metavar="KEY=VALUE|FILE.json",
                   help="override a ModelParams field, e.g. foot_forward_offset_m=-0.03, or "
                        "load a model_params.json (tkujax calibrate output); repeatable, applied "
                        "in order (the controller's geometry follows the model)")
    p.add_argument("--params", default=None,
                   help="controller parameters JSON (tkujax tune or calibrate output), a "
                        "scheduled policy file, or 'recommended': the recommended recovery "
                        "policy")
    p.add_argument("--variant", choices=["calibrated", "estimated"], default="calibrated",
                   help="calibrated (default): the robot, ball contact and Kalman noises fitted "
                        "to the paper (tkujax calibrate); estimated: the values before")
    p.add_argument("--phases", type=int, default=15,
                   help="also replay the cases at this many onsets across the 30 ms control "
                        "period (phase.csv, phase.md; 0 skips)")
    p.set_defaults(func=_cmd_paper)
