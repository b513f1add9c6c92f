"""Commands that compare controllers over sweeps: compare, fpga."""

from __future__ import annotations

from pathlib import Path

from tkujax.cli.shared_options import add_robot_check_option, controller_params_from_option


def _cmd_compare(args) -> int:
    from tkujax.studies.robot_inputs import sweep_robot
    from tkujax.analysis.compare import Bands, compare_runs, parse_run

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
                       unpaired_robots=args.unpaired_robots,
                       robot=sweep_robot(parse_run(args.runs[0])[0], args.robot),
                       allow_incomplete=args.allow_incomplete)
    print("\n".join(res["files"]))
    print(Path(res["summary"]).read_text())
    return 0


def _cmd_fpga(args) -> int:
    from tkujax.studies.fpga import run_fpga, write_resources

    if args.resources:   # the EP3C120 estimate of the spec's [fpga] config (default: defaults)
        md, files = write_resources(args.spec, args.out)
        print("\n".join(str(f) for f in files) + ("\n" if files else "") + md)
        return 0
    if args.spec is None or args.out is None:
        raise ValueError("give SPEC and --out (or --resources)")
    res = run_fpga(args.spec, args.out, params=controller_params_from_option(args.params),
                   backend=args.backend)
    print("\n".join(res["files"]))
    print(Path(res["summary"]).read_text())
    return 0


def add_analysis_commands(sub) -> None:
    """compare, fpga."""
    _add_compare(sub)
    _add_fpga(sub)


def _add_compare(sub) -> None:
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
                   help="impulse band edges in N·s instead (a kick sweep's: m/s; "
                        "must cover every push)")
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
    p.add_argument("--allow-incomplete", action="store_true",
                   help="compare incomplete sweeps (their records must still match), the "
                        "summary and verdict.json marked 'incomplete: k of n chunks' (default: "
                        "refused)")
    add_robot_check_option(p)
    p.set_defaults(func=_cmd_compare)


def _add_fpga(sub) -> None:
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
