"""The `tkujax` command line: thin wrappers over library functions.

One module per group of commands (robot, sweeps, analysis, studies; the benchmark registers its
own); environment side effects (compilation cache, GL backend) happen in main(), never on
import.
"""

from __future__ import annotations

import argparse

from tkujax.cli.analysis import add_analysis_commands
from tkujax.cli.errors import OneLineParser, run_command
from tkujax.cli.export import add_export_command
from tkujax.cli.robot_commands import add_robot_commands
from tkujax.cli.runtime import configure_runtime
from tkujax.cli.studies import add_study_commands
from tkujax.cli.sweeps import add_sweep_commands
from tkujax.cli.view import add_view_command

from tkujax.bench.cli import add_bench_command

__all__ = ["build_parser", "configure_runtime", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="tkujax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    add_robot_commands(sub)
    add_sweep_commands(sub)
    add_analysis_commands(sub)
    add_bench_command(sub)
    add_study_commands(sub)
    add_export_command(sub)
    add_view_command(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one command: bad input or an OS error is one line on stderr and exit 2, Ctrl-C
    exit 130 (`tkujax.cli.errors`)."""
    args = build_parser().parse_args(argv)

    def command() -> int:
        configure_runtime()
        return args.func(args)

    rerun = getattr(args, "rerun", None)      # a command's own account of its rerun
    return run_command(f"tkujax {args.command}", command,
                       rerun=None if rerun is None else (lambda: rerun(args)))
