"""The `tkujax` command line: thin wrappers over library functions.

Environment side effects (compilation cache, GL backend) happen here in main(), never on import.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path


def configure_runtime() -> None:
    """Persistent XLA compilation cache and a headless GL default (EGL, where present)."""
    # mujoco reads MUJOCO_GL at import and fails to import at all when the chosen library is
    # missing: default to EGL only where libEGL exists (headless rendering), else leave it.
    import ctypes.util

    if "MUJOCO_GL" not in os.environ and ctypes.util.find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"
    import jax

    cache = os.environ.get("TKUJAX_CACHE_DIR", str(Path.home() / ".cache" / "tkujax" / "jax"))
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)


def _cmd_stand(args) -> int:
    from tkujax.studies.stand import simulate_stand

    result = simulate_stand(seconds=args.seconds, batch=args.batch, engine=args.engine,
                            perturb_deg=args.perturb_deg, seed=args.seed)
    print(json.dumps(result, indent=2))
    return 1 if result["fell"] else 0


def _cmd_render(args) -> int:
    from tkujax import render
    from tkujax.sim import physics

    ok, why = render.rendering_available()
    if not ok:
        print(f"tkujax render: offscreen rendering is unavailable: {why}\n"
              "Install EGL (apt-get install libegl1 libgl1-mesa-dri) and set MUJOCO_GL=egl, or "
              "OSMesa (apt-get install libosmesa6) and MUJOCO_GL=osmesa.", file=sys.stderr)
        return 2
    if args.case is None:
        model = physics.host_model()
        data = physics.stand_data(model)
        frame = render.render_frames(model, data.qpos[None], args.width, args.height)[0]
        print(render.save_image(frame, args.out))
        return 0
    from tkujax.studies.paper import render_case

    print(render_case(args.case, args.control == "on", args.out, args.width, args.height,
                      impulse_scale=args.impulse_scale))
    return 0


def _model_params(items: list[str], variant: str = "calibrated"):
    """--model: a model_params.json file (tkujax calibrate output) and/or KEY=VALUE overrides,
    applied in order to the variant's model; None when none is given (the variant's default)."""
    import dataclasses

    from tkujax.model import ModelParams
    from tkujax.model.io import load_model_params_json

    if not items:
        return None
    mp = ModelParams.estimated() if variant == "estimated" else ModelParams()
    for item in items:
        if item.endswith(".json"):
            mp = load_model_params_json(item)
        else:
            over = ModelParams.from_overrides([item])      # validates the key and the number
            key = item.split("=", 1)[0].strip()
            mp = dataclasses.replace(mp, **{key: getattr(over, key)}).validate()
    return mp


def _cmd_paper(args) -> int:
    from tkujax.studies.paper import run_paper
    from tkujax.control.io import load_policy_json

    params, schedule = load_policy_json(args.params) if args.params else (None, None)
    summary = run_paper(Path(args.out), figures=not args.no_figures, params=params,
                        schedule=schedule,
                        impulse_scale=args.impulse_scale,
                        model_params=_model_params(args.model, args.variant),
                        phases=args.phases, variant=args.variant)
    print(summary)
    return 0


def _cmd_sweep(args) -> int:
    from tkujax.control.io import load_policy_json
    from tkujax.studies.sweep import run_sweep

    params, schedule = load_policy_json(args.params) if args.params else (None, None)
    manifest = run_sweep(args.spec, args.out, params=params, schedule=schedule,
                         model_params=_model_params([args.model] if args.model else []),
                         max_chunks=args.max_chunks,
                         process_id=args.process_id, num_processes=args.num_processes,
                         coordinator=args.coordinator, backend=args.backend)
    state = "complete" if manifest["complete"] else "incomplete (rerun the same command to resume)"
    print(f"{manifest['n_pushes']} pushes in {args.out} ({manifest['backend']} backend): "
          f"{state}; {manifest['n_diverged']} diverged (numerical blow-up: counted neither as "
          f"fell nor as survived); wall {manifest['wall_s']} s")
    return 0


def _cmd_replay(args) -> int:
    from tkujax.studies.replay import replay

    result = replay(args.run_dir, args.index)
    fmt = lambda d: ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"  # noqa: E731
                              for k, v in d.items())
    push = {k: result["stored"][k] for k in ("impulse_ns", "azimuth_deg", "height_m", "onset_s",
                                             "control") if k in result["stored"]}
    print(f"record {result['index']} (chunk {result['chunk']}, {result['backend']} backend): "
          f"{fmt(push)}")
    print(f"stored:   {fmt({k: result['stored'][k] for k in result['replayed']})}")
    print(f"replayed: {fmt(result['replayed'])}")
    if result["identical"]:
        print("replayed outcome equals the stored one (every column)")
    elif result["same_outcome"]:
        print("replayed outcome equals the stored one (fell, diverged); numbers differ beyond "
              f"rounding in {sorted(result['differences'])}")
    else:
        print(f"replayed outcome DIFFERS from the stored one: {result['differences']}")
    if result["fields_missing"]:
        print(f"note: an older tkujax wrote this sweep; its manifest lacks "
              f"{len(result['fields_missing'])} field(s) of today's model and controller, "
              f"replayed as {fmt(result['fields_missing'])} (a difference may be the code's "
              "change since, not the record's fault)")
    if args.out:
        from tkujax import render

        ok, why = render.rendering_available()
        if not ok:
            print(f"tkujax replay: no video written: offscreen rendering is unavailable: {why}. "
                  "Install EGL (apt-get install libegl1 libgl1-mesa-dri) and set MUJOCO_GL=egl, "
                  "or OSMesa (libosmesa6) and MUJOCO_GL=osmesa.", file=sys.stderr)
        else:
            from tkujax.sim import physics

            host = physics.host_model(result["model_params"])
            frames = render.render_frames(host, result["qpos"], args.width, args.height)
            print(render.save_gif(frames, args.out, fps=1.0 / result["control_period_s"]))
    return 0 if result["same_outcome"] else 1
def _cmd_capture(args) -> int:
    from tkujax.studies.capture import run_capture
    from tkujax.control.io import load_controller_params_json

    params = load_controller_params_json(args.params) if args.params else None
    res = run_capture(args.spec, args.out, params=params, optimise=args.optimise,
                      iterations=args.iterations, max_chunks=args.max_chunks,
                      process_id=args.process_id, num_processes=args.num_processes,
                      coordinator=args.coordinator, backend=args.backend)
    m = res["manifest"]
    if not res["complete"]:
        print(f"{m['n_pushes']} rollouts in {args.out}: incomplete (rerun the same command to "
              f"resume); wall {m['wall_s']} s")
        return 0
    print("\n".join(res["files"]))
    print(Path(res["summary"]).read_text())
    return 0


def _cmd_map(args) -> int:
    from tkujax.studies.maps import make_maps

    result = make_maps(args.dir)
    print("\n".join(result["files"]))
    print(Path(result["summary"]).read_text())
    return 0


def _cmd_compare(args) -> int:
    from tkujax.studies.compare import Bands, compare_runs

    edges = (tuple(float(x) for x in args.impulse_edges.split(",")) if args.impulse_edges
             else None)
    labels = args.labels.split(",") if args.labels else None
    res = compare_runs(args.runs, args.out, labels=labels,
                       bands=Bands(sectors=args.sectors, impulse_edges=edges,
                                   impulse_bands=args.impulse_bands,
                                   phase_bands=args.phase_bands),
                       min_pushes=args.min_pushes, harm_pp=args.harm_pp, subset=args.subset,
                       azimuth_bins=args.azimuth_bins, impulse_bins=args.impulse_bins,
                       min_map_count=args.min_map_count,
                       unpaired_robots=args.unpaired_robots)
    print("\n".join(res["files"]))
    print(Path(res["summary"]).read_text())
    return 0


def _cmd_fpga(args) -> int:
    from tkujax.control.io import load_controller_params_json
    from tkujax.studies.fpga import run_fpga, write_resources

    if args.resources:   # the EP3C120 estimate of the spec's [fpga] config (default: defaults)
        md, files = write_resources(args.spec, args.out)
        print("\n".join(str(f) for f in files) + ("\n" if files else "") + md)
        return 0
    if args.spec is None or args.out is None:
        raise ValueError("give SPEC and --out (or --resources)")
    params = load_controller_params_json(args.params) if args.params else None
    res = run_fpga(args.spec, args.out, params=params, backend=args.backend)
    print("\n".join(res["files"]))
    print(Path(res["summary"]).read_text())
    return 0


def _cmd_bench(args) -> int:
    from tkujax.bench import MODES, parse_grad_variants, run_bench, summary_markdown

    mode = "full" if args.full else "default"
    sizes = dict(MODES[mode])
    def ints(option: str, text: str) -> tuple[int, ...]:
        try:
            return tuple(int(b) for b in text.split(",") if b.strip())
        except ValueError:
            raise ValueError(f"{option}: a comma list of integers, got {text!r}") from None

    if args.batches is not None:
        sizes["batches"] = ints("--batches", args.batches)
    for key in ("repeats", "cpu_batch", "grad_batch", "compile_batch", "scaling_batch",
                "grad_compile_batch"):
        if getattr(args, key) is not None:
            sizes[key] = getattr(args, key)
    stages = tuple(x.strip() for x in args.stages.split(",") if x.strip()) if args.stages \
        else None
    profile_batches = ints("--profile-batches", args.profile_batches) if (args.profile or (
        stages and "profile" in stages)) else ()
    if args.profile and stages and "profile" not in stages:
        stages = stages + ("profile",)
    grad_variants = parse_grad_variants(args.grad_variants) if args.grad_variants else None
    unrolls = None
    if args.unroll_substeps:
        try:
            unrolls = ints("--unroll-substeps", args.unroll_substeps)
        except ValueError:
            unrolls = (0,)
        if not unrolls or min(unrolls) < 1:
            raise SystemExit(f"--unroll-substeps: a comma list of integers >= 1, got "
                             f"{args.unroll_substeps!r}")
    # A stage asked for by name (or gradient variants) whose size the mode leaves at 0: the
    # full mode's size.
    named = set(stages or ()) | ({"gradient_compile"} if grad_variants else set())
    for stage, key in (("compile", "compile_batch"), ("cpu_peer", "cpu_batch"),
                       ("gradient_step", "grad_batch"), ("multi_device", "scaling_batch"),
                       ("gradient_compile", "grad_compile_batch")):
        if stage in named and not sizes[key]:
            sizes[key] = MODES["full"][key]
    run_bench(args.out, batches=sizes["batches"], duration_s=args.duration,
              repeats=sizes["repeats"], raw_steps=args.raw_steps,
              cpu_batch=sizes["cpu_batch"] or None, grad_batch=sizes["grad_batch"] or None,
              compile_batch=sizes["compile_batch"], scaling_batch=sizes["scaling_batch"] or None,
              grad_compile_batch=sizes["grad_compile_batch"] or 0, mode=mode, stages=stages,
              profile_batches=profile_batches, profile_duration_s=args.profile_duration,
              profile_repeats=args.profile_repeats,
              profile_variants=tuple(v.strip() for v in args.profile_variants.split(";")
                                     if v.strip()) if args.profile_variants else None,
              compile_workers=args.compile_workers, trace_dir=args.trace,
              grad_variants=grad_variants, grad_cached=not args.grad_cold_only,
              budget_s=args.budget_s, unroll_substeps=unrolls, resume=args.resume)
    result = json.loads(Path(args.out).read_text())
    print(summary_markdown(result))
    return 0 if all(st["status"] != "failed" for st in result["stages"]) else 1


def _cmd_calibrate(args) -> int:
    from tkujax.studies.calibrate import run_calibrate
    from tkujax.studies.calibrate.spec import load_calibrate_spec

    spec = load_calibrate_spec(args.spec)
    over = {k: v for k, v in (("budget_s", args.budget_s), ("max_evals", args.max_evals),
                              ("workers", args.workers)) if v is not None}
    if over:
        from tkujax.studies.calibrate.spec import parse_calibrate_spec
        from tkujax.studies.spec import read_toml

        raw = read_toml(args.spec)
        raw.setdefault("search", {}).update(over)      # re-validated like the spec's own keys
        spec = parse_calibrate_spec(raw)
    summary = run_calibrate(spec, args.out)
    print("\n".join(summary["files"]))
    print(Path(args.out, "calibration.md").read_text())
    return 0


def _cmd_refine(args) -> int:
    from tkujax.studies.calibrate.refine import Refiner, refine

    model = _model_params(args.model or [])
    res = refine(args.out, iterations=args.iterations, lr=args.lr,
                 refiner=Refiner(model=model) if model is not None else None,
                 log=lambda m: print(m, flush=True))
    b = res["best"]
    print(f"best: iteration {b['iteration']}, loss {b['loss']:.4f} (start "
          f"{res['history'][0]['loss']:.4f}), {b['params']}; {Path(args.out, 'refine.json')}")
    return 0


def _cmd_tune(args) -> int:
    from tkujax.studies.tune import run_tune

    record = run_tune(args.spec, args.out, iterations=args.iterations,
                      compare=not args.no_compare, evaluation=not args.no_eval,
                      only=args.only, deadline_s=args.deadline_s)
    if "summary" in record and "left" in record:          # a [study] spec
        print(Path(args.out, "study.md").read_text())
        print(f"study: {len(record['left'])} run(s) left"
              + (f"; stopped before {record['stopped']}" if record["stopped"] else ""))
        return 0
    print(Path(args.out, "summary.md").read_text())
    print(f"recommendation: {record['recommendation']['reason']} "
          f"({Path(args.out, 'params_after.json')})")
    return 0


def _cmd_converge(args) -> int:
    from tkujax.studies.converge import load_spec, run_converge

    spec = load_spec(args.spec)
    only = tuple(x.strip() for x in (args.only or "").split(",") if x.strip())
    run_converge(spec, args.out, only=only, log=lambda m: print(m, flush=True),
                 run=not args.no_run, reference=args.reference)
    return 0


def _cmd_islands(args) -> int:
    from tkujax.studies.calibrate import islands

    argv = ["--out", args.out, "--points", str(args.points), "--refine", str(args.refine),
            "--slice-phases", str(args.slice_phases), "--phases", str(args.phases),
            "--window", str(args.window)]
    if args.params is not None:
        argv += ["--params", args.params]
    return islands.main(argv)


def _add_parallel(p: argparse.ArgumentParser) -> None:
    """--backend and the multi-process options of the sweep-running commands."""
    p.add_argument("--backend", choices=["auto", "mjx", "mujoco"], default="auto",
                   help="auto: MJX on a GPU, MuJoCo C on a CPU when the spec allows it")
    p.add_argument("--process-id", type=int, default=None, help="multi-process: this process")
    p.add_argument("--num-processes", type=int, default=None, help="multi-process: how many")
    p.add_argument("--coordinator", default=None, help="multi-process: HOST:PORT of process 0")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tkujax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    _add_robot_commands(sub)
    _add_sweep_commands(sub)
    _add_study_commands(sub)
    return parser


def _add_robot_commands(sub) -> None:
    """stand, render, paper."""
    p = sub.add_parser("stand", help="simulate the robot standing and print what was measured")
    p.add_argument("--seconds", type=float, default=5.0)
    p.add_argument("--batch", type=int, default=8, help="robots simulated at once")
    p.add_argument("--engine", choices=["mjx", "mujoco"], default="mjx")
    p.add_argument("--perturb-deg", type=float, default=1.0,
                   help="initial joint perturbation, uniform +- this many degrees")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_stand)

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


def _add_sweep_commands(sub) -> None:
    """sweep, replay, capture, map, fpga."""
    p = sub.add_parser("sweep", help="run (or resume) a push sweep from a TOML spec")
    p.add_argument("spec", help="sweep spec, e.g. specs/sweep/stability_map_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (npz chunks + manifest.json)")
    p.add_argument("--params", default=None,
                   help="controller parameters JSON (tkujax tune output), a scheduled "
                        "policy file (policy_after.json of tkujax tune, best_policy.json of "
                        "its [study]), or 'recommended': the recommended recovery policy")
    p.add_argument("--model", default=None, metavar="FILE.json",
                   help="model parameters JSON (tkujax calibrate's model_params.json)")
    p.add_argument("--max-chunks", type=int, default=None, help="stop after this many new chunks")
    _add_parallel(p)
    p.set_defaults(func=_cmd_sweep)

    p = sub.add_parser("replay", help="re-simulate one record of a sweep, check its outcome "
                                      "against the stored one, and render it")
    p.add_argument("run_dir", help="a sweep output folder")
    p.add_argument("--index", type=int, required=True, help="the record's push_id")
    p.add_argument("--out", default=None, help="GIF to write (needs EGL or OSMesa)")
    p.add_argument("--width", type=int, default=480)
    p.add_argument("--height", type=int, default=400)
    p.set_defaults(func=_cmd_replay)

    p = sub.add_parser("capture", help="capture regions: a [step] sweep, its regions, theory "
                                       "overlays, J_1 (and J_2 with steps = 2), gradient-optimal "
                                       "steps")
    p.add_argument("spec", help="spec with [step.grid], e.g. specs/capture/capture_region_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (sweep chunks + capture/)")
    p.add_argument("--params", default=None, help="controller parameters JSON (tkujax tune output)")
    p.add_argument("--optimise", type=int, default=4,
                   help="pushes given a gradient-optimal step through MJX (0 skips)")
    p.add_argument("--iterations", type=int, default=15, help="Adam iterations per optimisation")
    p.add_argument("--max-chunks", type=int, default=None, help="stop after this many new chunks")
    _add_parallel(p)
    p.set_defaults(func=_cmd_capture)

    p = sub.add_parser("map", help="stability maps and capturability checks of a sweep folder")
    p.add_argument("dir")
    p.set_defaults(func=_cmd_map)

    p = sub.add_parser("compare", help="where controllers help or hurt: difference maps, fall "
                                       "rate by direction x impulse x phase, a no-harm verdict")
    p.add_argument("runs", nargs="+", metavar="RUN",
                   help="sweep output folders of one spec, each DIR, DIR:on or DIR:off (the "
                        "control setting to take; default on when present); the first is the "
                        "reference")
    p.add_argument("--out", required=True, help="output folder (difference_maps.png, "
                                                 "table.csv/.md, verdict.json, summary.md)")
    p.add_argument("--labels", default=None, help="comma-separated names, one per run")
    p.add_argument("--sectors", type=int, choices=[4, 8], default=4,
                   help="direction sectors (4: behind/right/front/left)")
    p.add_argument("--impulse-bands", type=int, default=4,
                   help="equal impulse bands from the smallest impulse to the largest (1-50)")
    p.add_argument("--impulse-edges", default=None, metavar="E0,E1,...",
                   help="impulse band edges in N·s instead (must cover every impulse)")
    p.add_argument("--phase-bands", type=int, default=3,
                   help="equal bands of the onset phase in the control period (1-30)")
    p.add_argument("--min-pushes", type=int, default=100,
                   help="no-harm check: only cells with at least this many pushes")
    p.add_argument("--harm-pp", type=float, default=2.0,
                   help="no-harm check: a cell is harmed above this many percentage points")
    p.add_argument("--subset", choices=["all", "grid", "random"], default="all",
                   help="which records: all, the spec's grid, or its random samples")
    p.add_argument("--azimuth-bins", type=int, default=24, help="difference maps: at most "
                                                                "this many azimuth cells")
    p.add_argument("--impulse-bins", type=int, default=12, help="difference maps: at most "
                                                                "this many impulse cells")
    p.add_argument("--min-map-count", type=int, default=10,
                   help="difference maps: leave cells with fewer pushes blank")
    p.add_argument("--unpaired-robots", action="store_true",
                   help="accept runs whose robot randomisation draws differ (unpaired s.e.)")
    p.set_defaults(func=_cmd_compare)

    p = sub.add_parser("fpga", help="fixed-point FPGA controller: word lengths, CORDIC "
                                    "iterations, latency vs the float controller's outcomes")
    p.add_argument("spec", nargs="?", default=None,
                   help="spec with controller.arithmetic=\"fixed\", e.g. specs/fpga/fpga_cpu.toml")
    p.add_argument("--out", default=None, help="output folder (sweep/, float/, fpga/); with "
                                               "--resources: where resources.md/.json go")
    p.add_argument("--resources", action="store_true",
                   help="only the EP3C120 resource estimate (multipliers, CORDIC, registers, "
                        "ROM, latency) of the spec's [fpga] config, or of the defaults")
    p.add_argument("--params", default=None, help="controller parameters JSON (tkujax tune output)")
    p.add_argument("--backend", choices=["auto", "mjx", "mujoco"], default="auto",
                   help="auto: MJX on a GPU, MuJoCo C on a CPU")
    p.set_defaults(func=_cmd_fpga)


def _add_study_commands(sub) -> None:
    """bench, tune, calibrate, refine."""
    p = sub.add_parser("bench", help="throughput: raw MJX vs closed loop vs MuJoCo C, compile, "
                                     "profile of the closed loop, gradient compile")
    p.add_argument("--out", default="results/bench/bench.json",
                   help="the JSON (rewritten after every stage) and a .md beside it")
    p.add_argument("--full", action="store_true",
                   help="the long version: batches 1024,4096,16384,65536, 3 repeats, the "
                        "gradient step and its compile, multi-device scaling (the default: "
                        "batches 1024,65536, 2 repeats, compile of the closed loop, CPU peer)")
    p.add_argument("--stages", default=None,
                   help="comma list of stages to run instead of the mode's: compile, "
                        "throughput, multi_device, cpu_peer, profile, gradient_step, "
                        "gradient_compile")
    p.add_argument("--batches", default=None, help="closed-loop / raw batches (mode default)")
    p.add_argument("--duration", type=float, default=1.5, help="simulated seconds per push")
    p.add_argument("--raw-steps", type=int, default=300)
    p.add_argument("--repeats", type=int, default=None, help="timed runs per figure (median)")
    p.add_argument("--cpu-batch", type=int, default=None, help="0 skips the MuJoCo C peer")
    p.add_argument("--grad-batch", type=int, default=None, help="0 skips the gradient step")
    p.add_argument("--compile-batch", type=int, default=None,
                   help="0 skips the closed loop's compile timing")
    p.add_argument("--scaling-batch", type=int, default=None,
                   help="global batch for the 1-vs-all-local-devices scaling run (0 skips)")
    p.add_argument("--grad-compile-batch", type=int, default=None,
                   help="batch of the cold/cached tuning-gradient compile timing (0 skips)")
    p.add_argument("--grad-variants", default=None,
                   help="gradient compile variants, ';'-separated, each a ','-list of "
                        "remat=none|tick|tick_nocse|tick_dots|substep|nested, unroll_ticks=K, "
                        "unroll_substeps=K, tree_passes=mjx|compact, autotune=LEVEL, llvm=0, "
                        "ptxas=0 (the last three "
                        "GPU only; they also time the step); e.g. "
                        "'remat=tick;remat=tick_nocse;remat=nested'")
    p.add_argument("--grad-cold-only", action="store_true",
                   help="gradient compile: the cold compile only (not the cached one)")
    p.add_argument("--profile", action="store_true",
                   help="add the closed-loop profile (ablations and controller parts)")
    p.add_argument("--profile-batches", default="1024,65536")
    p.add_argument("--profile-duration", type=float, default=0.3,
                   help="simulated seconds per push in the profile")
    p.add_argument("--profile-repeats", type=int, default=1)
    p.add_argument("--profile-variants", default=None,
                   help="';'-list (default: all of tkujax.bench_profile.DEFAULT_VARIANTS); also "
                        "unroll_substeps=K, unroll_ticks=K")
    p.add_argument("--compile-workers", type=int, default=None,
                   help="threads compiling the profile's variants in parallel (default: "
                        "min(8, CPU cores))")
    p.add_argument("--trace", default=None,
                   help="folder for a jax.profiler trace of the full loop (profile stage)")
    p.add_argument("--budget-s", type=float, default=None,
                   help="skip the stages that would start after this many seconds")
    p.add_argument("--resume", action="store_true",
                   help="go on with the run in --out (same options, device kind and versions): "
                        "its finished stages are kept, the others run; total_wall_s adds up")
    p.add_argument("--unroll-substeps", default=None,
                   help="closed loop's loop structures to compile and time, a comma list of "
                        "substep-scan unrollings (1: rolled; 15: the whole 30 ms tick at 2 ms), "
                        "e.g. 1,15 (default: the sweeps' own)")
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser("tune", help="tune T, gamma, H_Sup, eps_1, eps_2 (...) by CMA-ES, "
                                    "gradients through MJX or their alpha-order mix; evaluate "
                                    "on held-out and shifted pushes")
    p.add_argument("spec", help="tune spec, e.g. specs/tune/tune_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (history.json, params_*.json, "
                                                 "loss_curve.png, summary.md)")
    p.add_argument("--iterations", type=int, default=None, help="override tune.iterations")
    p.add_argument("--no-compare", action="store_true",
                   help="skip the spec's [compare] study (methods x seeds at one budget)")
    p.add_argument("--no-eval", action="store_true", help="skip the held-out evaluation")
    p.add_argument("--only", action="append", default=None, metavar="KEY=V1[,V2]",
                   help="[study] specs: run only these runs (KEY: policy, method or seed; "
                        "repeat for AND), e.g. --only policy=mlp --only seed=0,1")
    p.add_argument("--deadline-s", type=float, default=None,
                   help="[study] specs: start no run that would end after this many seconds "
                        "(finished runs are kept; rerun to resume)")
    p.set_defaults(func=_cmd_tune)

    p = sub.add_parser("calibrate", help="fit the model's unknown parameters to the paper's "
                                         "Tables 4-5 (CMA-ES with restarts; resumable)")
    p.add_argument("spec", help="calibrate spec, e.g. specs/calibrate/calibrate_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (archive.jsonl, best.json, "
                                                 "calibration.md, search_trace.png, "
                                                 "model_params.json, controller_params.json)")
    p.add_argument("--budget-s", type=float, default=None, help="override search.budget_s")
    p.add_argument("--max-evals", type=int, default=None, help="override search.max_evals")
    p.add_argument("--workers", type=int, default=None, help="override search.workers")
    p.set_defaults(func=_cmd_calibrate)

    p = sub.add_parser("refine", help="gradient refinement of the calibration through MJX: "
                                      "leg stiffness and damping, ball impulse, chest CoM")
    p.add_argument("--out", required=True, help="output folder (refine.json)")
    p.add_argument("--iterations", type=int, default=10, help="Adam iterations (1-500)")
    p.add_argument("--lr", type=float, default=0.01, help="Adam step per parameter (scales, cm)")
    p.add_argument("--model", action="append", metavar="FILE.json|KEY=VALUE",
                   help="start from this model (default: the calibrated ModelParams())")
    p.set_defaults(func=_cmd_refine)

    p = sub.add_parser("converge", help="fall outcomes at several timesteps / solver "
                                        "iterations against the finest (resumable)")
    p.add_argument("spec", help="converge spec, e.g. specs/converge/convergence_cpu.toml")
    p.add_argument("--out", required=True, help="output folder (spec.json, outcomes_*.npz, "
                                                 "agreement.json, agreement.md)")
    p.add_argument("--only", default=None, help="comma-separated setting names to run now")
    p.add_argument("--no-run", action="store_true",
                   help="run nothing: write the agreement from the settings in --out")
    p.add_argument("--reference", default=None, help="compare against this setting instead of "
                                                     "the spec's (writes agreement_vs_NAME.*)")
    p.set_defaults(func=_cmd_converge)

    p = sub.add_parser("islands", help="island widths of the fitted parameters (1-D slices "
                                       "through the default robot) and its paper rows over "
                                       "the hit phase (MuJoCo C)")
    p.add_argument("--out", required=True, help="output folder (islands.*, "
                                                 "phase_expectation.*)")
    p.add_argument("--points", type=int, default=41, help="grid values per slice (3-1000)")
    p.add_argument("--refine", type=int, default=4, help="bisections per island edge (0-20)")
    p.add_argument("--params", default=None, help="comma-separated parameters (default all)")
    p.add_argument("--slice-phases", type=int, default=1,
                   help="hit phases per slice value (1: the fit's 0 ms)")
    p.add_argument("--phases", type=int, default=15,
                   help="phases of the default robot's expectation table (0 skips it)")
    p.add_argument("--window", type=float, default=1.0,
                   help="fraction of each parameter's bounds a slice spans, centred on the "
                        "default (default 1: the whole bounds)")
    p.set_defaults(func=_cmd_islands)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_runtime()
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as err:   # bad input, a missing file: one line
        print(f"tkujax {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
