"""Island widths and the phase expectation: the helpers on hand-made input,
and the default robot's 8 rows at the fit's phase through MuJoCo C (~5 s on a CPU)."""

import pytest

from tkujax.studies.calibrate import islands as I
from tkujax.studies.calibrate import fit_vector as P


def test_island_is_the_run_around_the_default():
    holds = [True, False, True, True, True, False, True]
    assert I.island(list(range(7)), holds, 3) == (2, 4)
    assert I.island(list(range(7)), holds, 0) == (0, 0)
    assert I.island(list(range(7)), holds, 1) is None
    assert I.island(list(range(3)), [True] * 3, 1) == (0, 2)


def test_row_ok_fall_and_step_direction():
    up = dict(fell=False, step_cm=0.0)
    assert I._row_ok(("back", "baseball", "off"), up) == (True, None)
    assert I._row_ok(("back", "volleyball", "off"), up) == (False, None)
    assert I._row_ok(("back", "volleyball", "on"), dict(fell=False, step_cm=3.5)) == (True, True)
    assert I._row_ok(("back", "volleyball", "on"), dict(fell=False, step_cm=-3.5))[1] is False
    assert I._row_ok(("front", "volleyball", "on"), dict(fell=False, step_cm=-3.5))[1] is True
    assert I._row_ok(("front", "baseball", "on"), dict(fell=False, step_cm=0.0))[1] is False


def test_phases_are_tkujax_papers():
    assert I.phases_ms(15) == tuple(2.0 * k for k in range(15))
    assert I.phases_ms(1) == (0.0,)


def test_argument_checks_name_the_key():
    with pytest.raises(ValueError, match=r"points must be an integer in \[3, 1000\]"):
        I.island_slices(points=2)
    with pytest.raises(ValueError, match="unknown parameter"):
        I.island_slices(names=("foot_size",))


def test_default_reading_is_the_default_controller():
    assert I.default_reading() == "deviation/latched"


def test_default_robot_holds_8_of_8_at_the_fit_phase():
    """MuJoCo C on the default robot at 0 ms: the paper's 8 fall outcomes, as the MJX table."""
    s = I.score(P.base_vector(), I.default_reading(), (0.0,))
    assert s["all_hold"], s["rows"]
    assert 6.0 <= s["stand_deg"] <= 8.0


def test_expectation_markdown_picks_the_best_worst_row():
    rows = lambda a, b: {"r1": a, "r2": b}  # noqa: E731
    sl = {"leg_kp": dict(default=16.8, hit_phases_ms=[0.0, 2.0], points=[
        dict(value=10.0, fall_ok=rows(0.2, 1.0)), dict(value=16.8, fall_ok=rows(0.6, 1.0)),
        dict(value=20.0, fall_ok=rows(0.9, 0.8)), dict(value=25.0, fall_ok=rows(0.9, 0.7))])}
    line = I.expectation_markdown(sl).splitlines()[2]
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells == ["leg_kp", "2", "0.60 / 0.80", "20", "0.80 / 0.85", "20"]


def test_run_islands_with_nothing_to_do_writes_nothing(tmp_path):
    logged = []
    res = I.run_islands(tmp_path / "out", params=[" ", ""], phases=0, log=logged.append)
    assert res == {"phase_expectation": None, "islands": None}
    assert list((tmp_path / "out").iterdir()) == [] and logged[-1].startswith("wall ")


@pytest.mark.parametrize("entry", ["cli", "module"])
def test_cli_and_module_both_call_run_islands(entry, tmp_path, monkeypatch):
    """`tkujax islands` and `python -m tkujax.studies.calibrate.islands` are one library call."""
    calls = []
    monkeypatch.setattr(I, "run_islands", lambda out, **kw: calls.append((str(out), kw)) or {})
    argv = ["--out", str(tmp_path), "--params", "leg_kp,ankle_kp", "--points", "5",
            "--refine", "1", "--slice-phases", "2", "--phases", "0", "--window", "0.5"]
    if entry == "cli":
        from tkujax.cli import main
        assert main(["islands", *argv]) == 0
    else:
        assert I.main(argv) == 0
    out, kw = calls[0]
    assert out == str(tmp_path)
    assert [s.strip() for s in kw.pop("params")] == ["leg_kp", "ankle_kp"]
    assert kw == dict(points=5, refine=1, slice_phases=2, phases=0, window=0.5)
