"""The `tkujax` command line: thin wrappers over library functions.

One module per group of commands (robot, sweeps, analysis, studies; the benchmark registers its
own); environment side effects (compilation cache, GL backend) happen in main(), never on
import.
"""

from __future__ import annotations

import argparse
import sys

from tkujax.cli.analysis import add_analysis_commands
from tkujax.cli.options import model_params_from_options
from tkujax.cli.robot import add_robot_commands
from tkujax.cli.runtime import configure_runtime
from tkujax.cli.studies import add_study_commands
from tkujax.cli.sweeps import add_sweep_commands

try:
    from tkujax.bench.cli import add_bench_command
except ImportError:   # MERGE: remove this fallback (and cli/bench_fallback.py) after the merge
    from tkujax.cli.bench_fallback import add_bench_command

__all__ = ["build_parser", "configure_runtime", "main"]

# MERGE: tests/test_calibrate.py imports this old name; switch it to
# tkujax.cli.options.model_params_from_options, then delete the alias.
_model_params = model_params_from_options


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="tkujax", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    add_robot_commands(sub)
    add_sweep_commands(sub)
    add_analysis_commands(sub)
    add_bench_command(sub)
    add_study_commands(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    configure_runtime()
    try:
        return args.func(args)
    except (ValueError, FileNotFoundError) as err:   # bad input, a missing file: one line
        print(f"tkujax {args.command}: error: {err}", file=sys.stderr)
        return 2
