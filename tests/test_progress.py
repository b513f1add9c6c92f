"""Progress of long commands: a tqdm bar with the time left on a terminal, nothing (or plain
log lines) elsewhere; the count is right either way."""

import io
from pathlib import Path

import pytest

from tkujax.sweeps.progress import PROGRESS_ENV, Progress, StatusLog, bar_wanted, track

TINY = str(Path(__file__).resolve().parents[1] / "specs" / "sweep" / "tiny.toml")


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture(autouse=True)
def _no_forced_bars(monkeypatch):
    monkeypatch.delenv(PROGRESS_ENV, raising=False)


def test_bar_only_on_a_terminal_unless_forced(monkeypatch):
    assert not bar_wanted(io.StringIO()) and bar_wanted(Terminal())
    monkeypatch.setenv(PROGRESS_ENV, "1")
    assert bar_wanted(io.StringIO())
    monkeypatch.setenv(PROGRESS_ENV, "0")
    assert not bar_wanted(Terminal())


def test_progress_counts_and_prints_nothing_off_a_terminal():
    stream = io.StringIO()
    p = Progress(10, 2, stream)
    p.note("compiling ...")
    for n in (3, 1):
        p.update(n)
    assert p.done == 6 and p.bar is None
    p.restart()
    assert p.rate == 0.0 and p.eta_s != p.eta_s           # nan until more is done
    p.update(4)
    assert p.done == 10 and p.rate > 0 and p.eta_s == 0.0
    p.close()
    assert stream.getvalue() == ""


def test_progress_bar_on_a_terminal_shows_count_and_time_left():
    stream = Terminal()
    with Progress(8, 0, stream) as p:
        p.note("compiling the rollout")
        p.update(4)
        p.restart()
        p.update(2)
        assert p.bar.n == p.done == 6
    text = stream.getvalue()
    assert "compiling the rollout" in text and "6/8 pushes" in text and "ETA" in text


def test_track_yields_every_item_and_counts():
    stream = Terminal()
    assert list(track(iter(range(5)), desc="stages ", unit="stage", stream=stream)) == [*range(5)]
    assert "5/5 stage" in stream.getvalue()
    quiet = io.StringIO()
    assert list(track([1, 2], stream=quiet)) == [1, 2] and quiet.getvalue() == ""


def test_status_log_plain_lines_off_a_terminal_and_a_budget_bar_on_one():
    plain = io.StringIO()
    log = StatusLog(stream=plain, budget_s=60, desc="calibrate ")
    log("generation 1")
    log("generation 2")
    assert plain.getvalue() == "generation 1\ngeneration 2\n" and log.bar is None
    silent = io.StringIO()
    StatusLog(quiet=True, stream=silent)("x")
    assert silent.getvalue() == ""
    term = Terminal()
    log = StatusLog(stream=term, budget_s=3600, desc="calibrate ")
    log("generation 1")
    log.close()
    text = term.getvalue()
    assert "generation 1" in text and "of 1:00:00 budget" in text and "left" in text
    term = Terminal()
    log = StatusLog(stream=term, budget_s=3600, desc="tune --robot ")
    log.add_budget(1800)                       # a retry the budget did not foresee
    log("retry")
    log.close()
    assert log.budget_s == 5400 and "of 1:30:00 budget" in term.getvalue()


def test_sweep_off_a_terminal_prints_no_bar(tmp_path, capsys):
    from tkujax.sweeps.sweep import run_sweep

    manifest = run_sweep(TINY, tmp_path / "tiny", backend="mujoco")
    assert manifest["complete"]
    err = capsys.readouterr().err
    assert "pushes" not in err and "\r" not in err and "%|" not in err
