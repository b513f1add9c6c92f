"""MERGE: delete this module once tkujax.bench.cli exists (the benchmark's own package
registers `tkujax bench` through tkujax.bench.cli.add_bench_command). Until then it keeps the
command on this branch: the old registration, unchanged."""

from __future__ import annotations

import json
from pathlib import Path


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


def add_bench_command(sub) -> None:
    """MERGE: the old `bench` subcommand, over the module tkujax.bench."""
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
