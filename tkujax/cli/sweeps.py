"""Commands that run or read push sweeps: sweep, replay, capture, map."""

from __future__ import annotations

import sys
from pathlib import Path

from tkujax.cli.errors import bounded_int
from tkujax.cli.shared_options import (MAX_CHUNKS, RENDER_HELP, add_parallel_options,
                                       add_robot_check_option, controller_params_from_option,
                                       model_params_from_options, parallel_kwargs,
                                       policy_from_option)


def _cmd_sweep(args) -> int:
    from tkujax.sweeps.sweep import run_sweep

    params, schedule = policy_from_option(args.params)
    robot = _robot_option(args)
    model = robot or model_params_from_options([args.model] if args.model else [])
    manifest = run_sweep(args.spec, args.out, params=params, schedule=schedule,
                         model_params=model, max_chunks=args.max_chunks,
                         decisions=args.decisions, **parallel_kwargs(args))
    state = "complete" if manifest["complete"] else "incomplete (rerun the same command to resume)"
    print(f"{manifest['n_pushes']} pushes in {args.out} ({manifest['this_run']['backend']} "
          "backend): "
          f"{state}; {manifest['n_diverged']} diverged (numerical blow-up: counted neither as "
          f"fell nor as survived); wall {manifest['wall_s']} s")
    return 0


def _robot_option(args):
    """The Robot of --robot FILE, else of the spec's [robot] file, else None."""
    from tkujax.robot import robot_from_file
    from tkujax.dialects.sweep_spec import load_spec

    path = args.robot or load_spec(args.spec).robot_file
    if path is None:
        return None
    if args.model:
        raise ValueError("--model: give --robot (or a spec's [robot] file) or --model, not both")
    robot = robot_from_file(path)
    if getattr(args, "params", None) is None:
        print(f"{robot.name}: controller: {robot.controller}", file=sys.stderr)
    return robot


def _numbers(d: dict) -> str:
    return ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in d.items())


def _print_replay(result: dict) -> None:
    """What `tkujax replay` found: the record's push, its stored and replayed outcomes."""
    push = {k: result["stored"][k] for k in ("impulse_ns", "azimuth_deg", "height_m", "onset_s",
                                             "control") if k in result["stored"]}
    print(f"record {result['index']} (chunk {result['chunk']}, {result['backend']} backend): "
          f"{_numbers(push)}")
    print(f"stored:   {_numbers({k: result['stored'][k] for k in result['replayed']})}")
    print(f"replayed: {_numbers(result['replayed'])}")
    if result["identical"] and result.get("exact"):
        print("replayed outcome equals the stored one bit for bit (every column; the sweep's "
              "own program)")
    elif result["identical"]:
        print("replayed outcome equals the stored one (every column)")
    elif result["same_outcome"]:
        print("replayed outcome equals the stored one (fell, diverged); numbers differ beyond "
              f"rounding in {sorted(result['differences'])}")
    else:
        print(f"replayed outcome DIFFERS from the stored one: {result['differences']}")
    if result["fields_missing"]:
        print(f"note: an older tkujax wrote this sweep; its manifest lacks "
              f"{len(result['fields_missing'])} field(s) of today's model and controller, "
              f"replayed as {_numbers(result['fields_missing'])} (a difference may be the code's "
              "change since, not the record's fault)")


def _write_replay_video(result: dict, args) -> None:
    from tkujax import render

    ok, why = render.rendering_available()
    if not ok:
        print(f"tkujax replay: no video written: offscreen rendering is unavailable: {why}. "
              f"{RENDER_HELP}", file=sys.stderr)
        return
    from tkujax.sim.robot import as_robot

    host = as_robot(result["model_params"]).host_model
    frames = render.render_frames(host, result["qpos"], args.width, args.height)
    print(render.save_gif(frames, args.out, fps=1.0 / result["control_period_s"]))


def _cmd_replay(args) -> int:
    from tkujax.sweeps.replay import replay

    from tkujax.studies.robot_inputs import sweep_robot

    result = replay(args.run_dir, args.index, robot=sweep_robot(args.run_dir, args.robot),
                    exact=args.exact)
    _print_replay(result)
    if args.out:
        _write_replay_video(result, args)
    ok = result["identical"] if result["exact"] else result["same_outcome"]
    return 0 if ok else 1


def _cmd_capture(args) -> int:
    from tkujax.studies.capture import run_capture

    from tkujax.studies.robot_inputs import capture_robot

    robot, feet = capture_robot(args.spec, args.robot)
    res = run_capture(args.spec, args.out, params=controller_params_from_option(args.params),
                      optimise=args.optimise, iterations=args.iterations, robot=robot, feet=feet,
                      max_chunks=args.max_chunks, allow_incomplete=args.allow_incomplete,
                      **parallel_kwargs(args))
    m = res["manifest"]
    if not res["complete"]:
        print(f"{m['n_pushes']} rollouts in {args.out}: {res['incomplete']} (rerun the same "
              f"command to resume, or pass --allow-incomplete to analyse it marked); wall "
              f"{m['wall_s']} s")
        return 0
    print("\n".join(res["files"]))
    print(Path(res["summary"]).read_text())
    return 0


def _cmd_map(args) -> int:
    from tkujax.analysis.maps import make_maps

    from tkujax.studies.robot_inputs import robot_lip, sweep_robot

    robot = sweep_robot(args.dir, args.robot)
    result = make_maps(args.dir, robot=robot, lip=None if robot is None else robot_lip(robot),
                       allow_incomplete=args.allow_incomplete)
    print("\n".join(result["files"]))
    print(Path(result["summary"]).read_text())
    return 0


def add_sweep_commands(sub) -> None:
    """sweep, replay, capture, map."""
    _add_sweep(sub)
    _add_replay(sub)
    _add_capture(sub)
    p = sub.add_parser("map", help="stability maps and capturability checks of a sweep folder")
    p.add_argument("dir")
    p.add_argument("--allow-incomplete", action="store_true",
                   help="draw an incomplete sweep's records, every figure and the summary "
                        "marked 'incomplete: k of n chunks' (default: refused)")
    add_robot_check_option(p)
    p.set_defaults(func=_cmd_map)


def _add_sweep(sub) -> None:
    p = sub.add_parser("sweep", help="run (or resume) a push sweep from a TOML spec")
    p.add_argument("spec", help="sweep spec, e.g. specs/sweep/stability_map_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (npz chunks + manifest.json)")
    p.add_argument("--params", default=None,
                   help="controller parameters JSON (tkujax tune output), a scheduled "
                        "policy file (policy_after.json of tkujax tune, best_policy.json of "
                        "its [study]), or 'recommended': the recommended recovery policy")
    p.add_argument("--model", default=None, metavar="FILE.json",
                   help="model parameters JSON (tkujax calibrate's model_params.json)")
    p.add_argument("--robot", default=None, metavar="FILE.toml",
                   help="a robot file (docs/robots.md): the sweep runs on that robot with "
                        "the controller scaled to it (default: the spec's [robot] file)")
    p.add_argument("--max-chunks", type=bounded_int(1, MAX_CHUNKS), default=None,
                   help="stop after this many new chunks")
    p.add_argument("--decisions", choices=["full", "early"], default=None,
                   help="full: every push runs the spec's duration_s; early: a push leaves its "
                        "lane once fallen or settled and the next push takes it (MJX; default: "
                        "the spec's [sweep] decisions, else full)")
    add_parallel_options(p)
    p.set_defaults(func=_cmd_sweep)


def _add_replay(sub) -> None:
    p = sub.add_parser("replay", help="re-simulate one record of a sweep, check its outcome "
                                      "against the stored one, and render it")
    p.add_argument("run_dir", help="a sweep output folder")
    p.add_argument("--index", type=int, required=True, help="the record's push_id")
    p.add_argument("--out", default=None, help="GIF to write (needs EGL or OSMesa)")
    p.add_argument("--width", type=int, default=480)
    p.add_argument("--height", type=int, default=400)
    p.add_argument("--exact", action="store_true",
                   help="MJX: also re-run the record by the sweep's own program at its batch "
                        "shape and compare bit for bit (exit 1 unless identical; costs a chunk)")
    add_robot_check_option(p)
    p.set_defaults(func=_cmd_replay)


def _add_capture(sub) -> None:
    p = sub.add_parser("capture", help="capture regions: a [step] sweep, its regions, theory "
                                       "overlays, J_1 (and J_2 with steps = 2), gradient-optimal "
                                       "steps")
    p.add_argument("spec", help="spec with [step.grid], e.g. specs/capture/capture_region_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (sweep chunks + capture/)")
    p.add_argument("--params", default=None, help="controller parameters JSON (tkujax tune output)")
    p.add_argument("--optimise", type=int, default=4,
                   help="pushes given a gradient-optimal step through MJX (0 skips)")
    p.add_argument("--iterations", type=int, default=15, help="Adam iterations per optimisation")
    p.add_argument("--robot", default=None, metavar="FILE.toml",
                   help="a robot file (docs/robots.md; default: the spec's [robot] file): its "
                        "measured geometry gives the theory and the reach (no --optimise)")
    p.add_argument("--max-chunks", type=bounded_int(1, MAX_CHUNKS), default=None,
                   help="stop after this many new chunks")
    p.add_argument("--allow-incomplete", action="store_true",
                   help="analyse the sweep's chunks done when it is left incomplete, every "
                        "output marked 'incomplete: k of n chunks' (default: not analysed)")
    add_parallel_options(p)
    p.set_defaults(func=_cmd_capture)
