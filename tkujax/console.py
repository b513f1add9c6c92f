"""The `tkujax` console script: the command line (`tkujax.cli.main`) loaded inside the Ctrl-C
handling, so that an interrupt while Python loads it exits as one during a command does (one
line, exit 130, no traceback). Importing this module loads nothing heavy: tkujax's submodules
load lazily (`tkujax/__init__.py`), and tkujax.cli only here, inside the handler."""

from __future__ import annotations

import sys

# tkujax.cli.errors.EXIT_INTERRUPTED (not imported: that would load the command line first;
# tests/test_hostile_interrupts.py checks that the two agree).
EXIT_INTERRUPTED = 130
INTERRUPTED = "tkujax: interrupted; rerun the same command to resume"


def main() -> int:
    """Load and run the command line; a Ctrl-C before a command starts is one line, 130."""
    try:
        from tkujax.cli import main as command_line

        return command_line()
    except KeyboardInterrupt:
        print(INTERRUPTED, file=sys.stderr)
        return EXIT_INTERRUPTED
