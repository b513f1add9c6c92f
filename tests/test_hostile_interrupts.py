"""Ctrl-C is never lost nor turned into a traceback: one landing where Python drops exceptions
(a __del__, a garbage-collection callback such as JAX's) is delivered again; one cutting an
extension module's import short (an ImportError from it) or arriving while JAX loads (its
import deferred over) ends the command as any other Ctrl-C: one line, exit 130. The line says
what a rerun does: a plain tune starts over, a [study] and `tune --robot` resume."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from tkujax.cli.errors import EXIT_INTERRUPTED, interrupts_deferred, run_command

ROOT = Path(__file__).resolve().parents[1]
SAID = "tkujax test: interrupted; rerun the same command to resume"


def _default_sigint() -> None:
    """Ctrl-C's default in the child, as at a terminal: a suite started in the background by a
    non-interactive shell inherits SIGINT ignored, and the Ctrl-C tests would send nothing."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture
def python_sigint():
    """Python's own Ctrl-C handler in this process for the test (see _default_sigint)."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def _python(code: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env, text=True,
                          capture_output=True, timeout=120, preexec_fn=_default_sigint)


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


def test_an_interrupt_while_deferred_takes_effect_at_the_end(python_sigint):
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


TUNE = """
[tune]
name = "interrupted_tune"
iterations = 2
batch = 4
popsize = 3
duration_s = 0.6

[push]
impulse_ns = {uniform = [0.2, 1.0]}
onset_s = 0.2
duration_s = 0.02

[evaluate]
n = 4
"""


def test_an_interrupted_tune_says_a_rerun_starts_it_over(capsys, monkeypatch, tmp_path):
    """A plain tune keeps nothing of its search in --out: Ctrl-C in the search leaves no
    record, and its line says that a rerun starts the tune over, which the rerun does (its
    search starts again at the start latent, with the full iteration count)."""
    from hostile_helpers import run

    from tkujax.cli.studies import TUNE_RESTARTS
    from tkujax.studies.tune import tune_command

    searches = []

    def search(method, problem, z0, train, keys, cfg, **kwargs):
        searches.append((np.asarray(z0).tolist(), cfg.max_iterations))
        raise KeyboardInterrupt                 # Ctrl-C in the middle of the search

    monkeypatch.setattr(tune_command, "make_problem", lambda *args, **kwargs: object())
    monkeypatch.setattr(tune_command, "run_search", search)
    spec, out = tmp_path / "t.toml", tmp_path / "out"
    spec.write_text(TUNE)
    for _ in range(2):
        code, _, err = run(capsys, "tune", spec, "--out", out, "--no-compare")
        assert code == EXIT_INTERRUPTED
        assert err.strip().splitlines()[-1] == f"tkujax tune: interrupted; {TUNE_RESTARTS}"
        assert "resume" not in err and list(out.iterdir()) == []
    assert len(searches) == 2 and searches[0] == searches[1]     # the rerun started over


def test_an_interrupted_study_or_robot_tune_says_it_resumes(capsys, monkeypatch, tmp_path):
    """A [study] spec keeps its finished runs and `tune --robot` its finished stages: their
    rerun resumes, and their line says so."""
    from hostile_helpers import run

    from tkujax.cli.studies import ROBOT_RESUMES, STUDY_RESUMES, TUNE_RESTARTS, tune_rerun
    from tkujax.studies import robot_tune

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(robot_tune, "tune_robot_controller", interrupted)
    code, _, err = run(capsys, "tune", "--robot", tmp_path / "r.toml", "--out", tmp_path / "o")
    assert code == EXIT_INTERRUPTED
    assert err.strip() == f"tkujax tune: interrupted; {ROBOT_RESUMES}"
    study = tmp_path / "study.toml"
    study.write_text(TUNE + "\n[study]\npolicies = [\"scalars\"]\n")
    assert tune_rerun(SimpleNamespace(spec=str(study))) == STUDY_RESUMES
    assert tune_rerun(SimpleNamespace(spec=str(tmp_path / "gone.toml"))) == TUNE_RESTARTS


def test_a_ctrl_c_while_the_command_line_loads_is_one_line(monkeypatch, capsys):
    """The console script (`tkujax.console.main`) loads tkujax.cli inside its handler: a
    KeyboardInterrupt while that import runs is one line and exit 130, as during a command."""
    import tomllib
    import types

    from tkujax import console

    class Loading(types.ModuleType):
        def __getattr__(self, name):
            raise KeyboardInterrupt

    monkeypatch.setitem(sys.modules, "tkujax.cli", Loading("tkujax.cli"))
    assert console.main() == EXIT_INTERRUPTED == console.EXIT_INTERRUPTED
    assert capsys.readouterr().err.strip() == console.INTERRUPTED
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert scripts["tkujax"] == "tkujax.console:main"


def test_the_console_module_loads_nothing_heavy():
    """Importing tkujax.console loads neither the command line nor JAX (a Ctrl-C before the
    handler is then only Python's own start)."""
    done = _python("""
        import sys
        import tkujax.console
        print(sorted(m for m in ("tkujax.cli", "jax", "mujoco") if m in sys.modules))
    """)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_an_interrupted_command_cancels_its_pending_redeliveries(monkeypatch, capsys):
    """A Ctrl-C dropped where Python ignores exceptions is sent again shortly after
    (`keep_interrupts`); once the command has ended as interrupted, that re-delivery is
    cancelled, so it cannot land while Python exits and end the process by SIGINT instead of
    exit 130 (seen once in the suite: exit -2 after the "interrupted" line)."""
    from tkujax.cli import errors

    monkeypatch.setattr(errors, "REDELIVER_S", 60.0)     # never fires within this test
    monkeypatch.setattr(sys, "unraisablehook", sys.unraisablehook)
    # An earlier test's command may have ended as interrupted in this process.
    monkeypatch.setattr(errors, "INTERRUPT_HANDLED", threading.Event())
    errors.keep_interrupts()
    sys.unraisablehook(SimpleNamespace(exc_type=KeyboardInterrupt, exc_value=KeyboardInterrupt(),
                                       exc_traceback=None, err_msg=None, object=None))
    pending = list(errors.PENDING_REDELIVERIES)
    assert len(pending) == 1 and pending[0].is_alive()

    def command():
        raise KeyboardInterrupt

    assert errors.run_command("tkujax sweep", command) == errors.EXIT_INTERRUPTED
    assert not errors.PENDING_REDELIVERIES
    pending[0].join(timeout=5)
    assert pending[0].finished.is_set() and not pending[0].is_alive()
    assert "interrupted" in capsys.readouterr().err
    # A Ctrl-C already on its way, dropped after the command ended, schedules none; the next
    # command re-arms the re-delivery.
    sys.unraisablehook(SimpleNamespace(exc_type=KeyboardInterrupt, exc_value=KeyboardInterrupt(),
                                       exc_traceback=None, err_msg=None, object=None))
    assert not errors.PENDING_REDELIVERIES
    assert errors.run_command("tkujax sweep", lambda: 0) == 0
    assert not errors.INTERRUPT_HANDLED.is_set()
