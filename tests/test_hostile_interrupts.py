"""Ctrl-C is never lost nor turned into a traceback: one landing where Python drops exceptions
(a __del__, a garbage-collection callback such as JAX's) is delivered again; one cutting an
extension module's import short (an ImportError from it) or arriving while JAX loads (its
import deferred over) ends the command as any other Ctrl-C: one line, exit 130."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tkujax.cli.errors import EXIT_INTERRUPTED, interrupts_deferred, run_command

ROOT = Path(__file__).resolve().parents[1]
SAID = "tkujax test: interrupted; rerun the same command to resume"


def _python(code: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, text=True,
                          capture_output=True, timeout=120)


def test_an_interrupt_dropped_in_a_finaliser_is_delivered_again():
    done = _python("""
        import sys, time
        from tkujax.cli.errors import run_command

        class Finalised:
            def __del__(self):
                raise KeyboardInterrupt        # what a Ctrl-C landing here looks like

        def command():
            Finalised()                        # dropped at once: Python prints and drops it
            time.sleep(30)
            print("ran on")
            return 0

        sys.exit(run_command("tkujax test", command))
    """)
    assert done.returncode == EXIT_INTERRUPTED, done.stderr
    assert done.stderr.strip() == SAID and "ran on" not in done.stdout


def test_an_import_cut_short_by_an_interrupt_is_an_interrupt(capsys):
    def command():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as err:      # as numpy's extension import reports it
            raise ImportError("numpy._core.multiarray failed to import") from err

    assert run_command("tkujax test", command) == EXIT_INTERRUPTED
    assert capsys.readouterr().err.strip() == SAID


def test_other_errors_are_still_errors(capsys):
    def bad():
        raise ImportError("a missing module")

    with pytest.raises(ImportError, match="a missing module"):
        run_command("tkujax test", bad)


def test_an_interrupt_while_deferred_takes_effect_at_the_end():
    reached = []
    with pytest.raises(KeyboardInterrupt):
        with interrupts_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            reached.append("the block ran to its end")
    assert reached == ["the block ran to its end"]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with interrupts_deferred():             # without a Ctrl-C: nothing raised
        reached.append("again")
    assert reached[-1] == "again"
