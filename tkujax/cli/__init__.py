"""The `tkujax` command line: thin wrappers over library functions.

One module per group of commands (robot, sweeps, analysis, studies; the benchmark registers its
own); environment side effects (compilation cache, GL backend) happen in main(), never on
import.
"""

from __future__ import annotations

import argparse
import sys

from tkujax.cli.analysis import add_analysis_commands
from tkujax.cli.export import add_export_command
from tkujax.cli.robot import add_robot_commands
from tkujax.cli.runtime import configure_runtime
from tkujax.cli.studies import add_study_commands
from tkujax.cli.sweeps import add_sweep_commands

from tkujax.bench.cli import add_bench_command

__all__ = ["build_parser", "configure_runtime", "main"]

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tkujax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    add_robot_commands(sub)
    add_sweep_commands(sub)
    add_analysis_commands(sub)
    add_bench_command(sub)
    add_study_commands(sub)
    add_export_command(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_runtime()
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as err:   # bad input, a missing file: one line
        print(f"tkujax {args.command}: error: {err}", file=sys.stderr)
        return 2
