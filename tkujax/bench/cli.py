"""The `tkujax bench` command: `add_bench_command(subparsers)` registers it.

Everyday options: --out, --full, --stages, --batches, --duration, --repeats, --profile,
--budget-s, --resume. Every other BenchConfig field (the research variants: gradient compile
variants, loop structures, profile variants, stage sizes, ...) goes through `--variant
KEY=VALUE`, repeatable, KEY a VARIANT_KEYS name.
"""

from __future__ import annotations

import json
from pathlib import Path


def _ints(option: str, text: str) -> tuple[int, ...]:
    try:
        return tuple(int(b) for b in text.split(",") if b.strip())
    except ValueError:
        raise ValueError(f"{option}: a comma list of integers, got {text!r}") from None


def _one_int(option: str, text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"{option}: an integer, got {text!r}") from None


def _grad_variants(option: str, text: str) -> list[dict]:
    from tkujax.bench.stages import parse_grad_variants

    return parse_grad_variants(text)


def _names(option: str, text: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in text.split(";") if v.strip())


def _flag(option: str, text: str) -> bool:
    if text not in ("0", "1"):
        raise ValueError(f"{option}: 0 or 1, got {text!r}")
    return text == "1"


# --variant KEY=VALUE: the BenchConfig field KEY, parsed from VALUE.
VARIANT_KEYS = {
    "raw_steps": _one_int, "cpu_batch": _one_int, "grad_batch": _one_int,
    "compile_batch": _one_int, "scaling_batch": _one_int, "grad_compile_batch": _one_int,
    "profile_repeats": _one_int, "compile_workers": _one_int,
    "profile_batches": _ints, "unroll_substeps": _ints,
    "profile_duration_s": lambda option, text: float(text),
    "profile_variants": _names, "grad_variants": _grad_variants, "grad_cached": _flag,
    "trace_dir": lambda option, text: text,
}
VARIANT_HELP = (
    "a research option, KEY=VALUE, repeatable: raw_steps=N, cpu_batch=N, grad_batch=N, "
    "compile_batch=N, scaling_batch=N, grad_compile_batch=N (0 skips the stage); "
    "unroll_substeps=1,15 (the closed loop's substep-scan unrollings to time); "
    "grad_variants='remat=tick;remat=nested,unroll_substeps=3;tree_passes=compact;autotune=0;"
    "llvm=0,ptxas=0' (gradient compile variants); grad_cached=0 (cold compile only); "
    "profile_batches=2,4, profile_duration_s=S, profile_repeats=N, profile_variants='full;"
    "no_records;loop=nested', compile_workers=N, trace_dir=DIR (a jax.profiler trace)")


def _variants(items: list[str]) -> dict:
    """{BenchConfig field: value} of the --variant items."""
    fields = {}
    for item in items:
        key, eq, val = item.partition("=")
        if not eq or key not in VARIANT_KEYS:
            raise ValueError(f"--variant {item!r}: expected KEY=VALUE with KEY one of "
                             f"{sorted(VARIANT_KEYS)}")
        fields[key] = VARIANT_KEYS[key](f"--variant {key}", val)
    return fields


def bench_config(args):
    """The BenchConfig of parsed `tkujax bench` arguments."""
    from tkujax.bench.runner import MODES, BenchConfig

    mode = "full" if args.full else "default"
    fields = dict(MODES[mode], mode=mode, duration_s=args.duration, budget_s=args.budget_s)
    if args.batches is not None:
        fields["batches"] = _ints("--batches", args.batches)
    if args.repeats is not None:
        fields["repeats"] = args.repeats
    stages = tuple(x.strip() for x in args.stages.split(",") if x.strip()) if args.stages \
        else None
    if args.profile and stages and "profile" not in stages:
        stages = stages + ("profile",)
    if args.profile or (stages and "profile" in stages):
        fields["profile_batches"] = (1024, 65536)
    fields.update(_variants(args.variant or []), stages=stages)
    # A stage asked for by name (or gradient variants) whose size the mode leaves at 0: the
    # full mode's size.
    named = set(stages or ()) | ({"gradient_compile"} if fields.get("grad_variants") else set())
    for stage, key in (("compile", "compile_batch"), ("cpu_peer", "cpu_batch"),
                       ("gradient_step", "grad_batch"), ("multi_device", "scaling_batch"),
                       ("gradient_compile", "grad_compile_batch")):
        if stage in named and not fields[key]:
            fields[key] = MODES["full"][key]
    for key in ("cpu_batch", "grad_batch", "scaling_batch"):     # 0: skipped
        fields[key] = fields[key] or None
    return BenchConfig(**fields)


def run_command(args) -> int:
    """The `tkujax bench` handler: run, print the summary; 1 when a stage failed."""
    from tkujax.bench import runner
    from tkujax.bench.bench_summary import summary_markdown

    runner.run_bench(args.out, bench_config(args), resume=args.resume)
    result = json.loads(Path(args.out).read_text())
    print(summary_markdown(result))
    return 0 if all(st["status"] != "failed" for st in result["stages"]) else 1


def add_bench_command(subparsers) -> None:
    """Register `bench` (its options and handler) on an argparse subparsers object."""
    p = subparsers.add_parser("bench", help="throughput: raw MJX vs closed loop vs MuJoCo C, "
                                            "compile, profile of the closed loop")
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
    p.add_argument("--repeats", type=int, default=None, help="timed runs per figure (median)")
    p.add_argument("--profile", action="store_true",
                   help="add the closed-loop profile (ablations and controller parts) at "
                        "batches 1024,65536 (--variant profile_batches=... for others)")
    p.add_argument("--budget-s", type=float, default=None,
                   help="skip the stages that would start after this many seconds")
    p.add_argument("--resume", action="store_true",
                   help="go on with the run in --out (same options, device kind and versions): "
                        "its finished stages are kept, the others run; total_wall_s adds up")
    p.add_argument("--variant", action="append", metavar="KEY=VALUE", help=VARIANT_HELP)
    p.set_defaults(func=run_command)
