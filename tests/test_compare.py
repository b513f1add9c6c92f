"""`tkujax compare`: runs of one spec against a reference, on synthetic records written with the
sweep's own chunk writer; cell rates and the no-harm verdict checked against hand counts."""

import json

import numpy as np
import pytest

from tkujax.sweeps import chunks
from tkujax.analysis.compare import (Bands, compare_runs, difference_cells, load_run,
                                     sector_index)
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.sweep import record_inputs


def _write(out, rec, chunk=64, complete=True):
    """Records as a sweep folder: chunks through chunks.write_chunk, a manifest."""
    out.mkdir(parents=True, exist_ok=True)
    n = len(rec["fell"])
    for i in range(0, n, chunk):
        chunks.write_chunk(out, i // chunk, {k: v[i:i + chunk] for k, v in rec.items()})
    chunks.update_manifest(out, lambda m: {**m, "complete": complete, "n_pushes": n})
    return out


# Cells (azimuth, impulse, phase) -> (pushes, reference falls, run falls), by hand.
#   behind, low J, phase band 0: 100 pushes, 50 vs 53 falls: +3 pp  -> harmed
#   front,  low J, phase band 0: 100 pushes, 20 vs 22 falls: +2 pp  -> not harmed (not > 2)
#   right, high J, phase band 1: 120 pushes, 60 vs 30 falls: -25 pp -> helped
#   left,  high J, phase band 1:  50 pushes, 10 vs 40 falls: +60 pp -> too few pushes to judge
CELLS = [((0.0, 0.5, 0.1), 100, 50, 53), ((180.0, 0.5, 0.1), 100, 20, 22),
         ((90.0, 1.5, 0.6), 120, 60, 30), ((270.0, 1.5, 0.6), 50, 10, 40)]


def _records(which: int) -> dict:
    cols = {k: [] for k in ("azimuth_deg", "impulse_ns", "onset_phase", "fell")}
    for (az, j, ph), n, f_ref, f_run in CELLS:
        falls = (f_ref, f_run)[which]
        # Spread the fallen pushes differently in the two runs (paired differences exist).
        fell = np.zeros(n, bool)
        fell[(np.arange(falls) * 7 + which) % n] = True
        cols["azimuth_deg"].append(np.full(n, az) + np.linspace(-10, 10, n))
        cols["impulse_ns"].append(np.full(n, j) + np.linspace(-0.2, 0.2, n))
        cols["onset_phase"].append(np.full(n, ph))
        cols["fell"].append(fell)
    rec = {k: np.concatenate(v) for k, v in cols.items()}
    n = len(rec["fell"])
    rec.update(height_m=np.full(n, 0.36), duration_s=np.full(n, 0.02),
               onset_s=0.75 + 0.03 * rec["onset_phase"], control=np.full(n, which == 1),
               diverged=np.zeros(n, bool), push_id=np.arange(n),
               from_grid=np.zeros(n, bool), recovery_time_s=np.full(n, np.nan))
    return rec


@pytest.fixture
def two_runs(tmp_path):
    return (_write(tmp_path / "off", _records(0)), _write(tmp_path / "on", _records(1)))


def test_sectors_follow_the_push_convention():
    # 0 deg = pushed from behind; 90 = from the right; sector edges at +-45 deg.
    az = np.array([0, 44.9, 45.1, 90, 180, 270, 315.1, 359, -30])
    assert sector_index(az, 4).tolist() == [0, 0, 1, 1, 2, 3, 0, 0, 0]
    assert sector_index(np.array([0, 45, 90, 135, 180, 225, 270, 315]), 8).tolist() == list(
        range(8))


def test_cell_rates_and_verdict_by_hand(two_runs, tmp_path):
    off, on = two_runs
    res = compare_runs([str(off), str(on)], tmp_path / "cmp", labels=["off", "on"],
                       bands=Bands(sectors=4, impulse_edges=(0.0, 1.0, 2.0), phase_bands=2),
                       min_map_count=1)
    rows = {(r["sector"], r["impulse_lo"], r["phase"]): r["runs"] for r in res["table"]["rows"]}
    behind = rows[("behind", 0.0, "0.00-0.50")]
    assert (behind["off"]["n"], behind["off"]["falls"], behind["on"]["falls"]) == (100, 50, 53)
    assert behind["on"]["diff_pp"] == pytest.approx(3.0)
    right = rows[("right", 1.0, "0.50-1.00")]
    assert right["off"]["rate"] == pytest.approx(0.5) and right["on"]["rate"] == pytest.approx(
        0.25)
    assert right["on"]["diff_pp"] == pytest.approx(-25.0)
    # Phases pooled: each sector holds one phase here, so the same counts.
    assert rows[("left", 1.0, "all")]["on"]["falls"] == 40
    # Cells that hold no push are not rows.
    assert ("behind", 1.0, "all") not in rows
    v = res["verdict"]["runs"]["on"]
    # Checked: behind/front (phase and pooled: 4) and right (2); left has 50 < 100 pushes.
    assert v["cells_checked"] == 6
    harmed = {(h["sector"], h["phase"]) for h in v["harmed_cells"]}
    assert harmed == {("behind", "0.00-0.50"), ("behind", "all")}
    assert not v["no_harm"]
    # Overall: reference 140/370, run 145/370.
    assert v["reference_fall_rate"] == pytest.approx(140 / 370)
    assert v["fall_rate"] == pytest.approx(145 / 370)
    assert v["ratio_to_reference"] == pytest.approx(145 / 140)
    # Paired standard error of the behind cell: d = on - off per push, by hand.
    ref, run = _records(0), _records(1)
    d = (run["fell"].astype(float) - ref["fell"].astype(float))[:100]
    assert behind["on"]["se_pp"] == pytest.approx(100 * d.std(ddof=1) / 10)
    on_disk = json.loads((tmp_path / "cmp" / "verdict.json").read_text())
    assert on_disk["runs"]["on"]["harmed_cells"][0]["diff_pp"] == pytest.approx(3.0)
    csv = (tmp_path / "cmp" / "table.csv").read_text().splitlines()
    assert csv[0].startswith("sector,impulse_lo_ns") and len(csv) == 1 + len(res["table"]["rows"])
    for f in res["files"]:
        assert (tmp_path / "cmp" / f.split("/")[-1]).stat().st_size > 0
    # A looser threshold or a smaller minimum changes the verdict as counted by hand.
    v3 = compare_runs([str(off), str(on)], tmp_path / "cmp3", labels=["off", "on"],
                      bands=Bands(impulse_edges=(0.0, 1.0, 2.0), phase_bands=2),
                      harm_pp=3.0, min_pushes=50)["verdict"]["runs"]["on"]
    assert {(h["sector"], h["phase"]) for h in v3["harmed_cells"]} == {
        ("left", "0.50-1.00"), ("left", "all")}


def test_difference_map_cells(two_runs):
    runs = [load_run(str(two_runs[0]), "off"), load_run(str(two_runs[1]), "on")]
    cells = difference_cells(runs, azimuth_bins=4, impulse_bins=2, phase_bands=2)
    title, per = cells["bands"][0]
    assert title == "all phases"
    a = int(np.argmin(np.abs(cells["azimuths"] - 90)))
    j = int(np.argmax(cells["impulses"]))
    assert per["off"][1][a, j] == 120
    assert per["on"][0][a, j] - per["off"][0][a, j] == pytest.approx(-0.25)
    # Phase band 0 holds no push from the right.
    assert per["off"][1][a, j] == cells["bands"][2][1]["off"][1][a, j]
    assert cells["bands"][1][1]["off"][1][a, j] == 0


def test_refuses_runs_of_other_pushes(two_runs, tmp_path):
    off, _ = two_runs
    other = _records(1)
    other["impulse_ns"] = other["impulse_ns"].copy()
    other["impulse_ns"][5] += 0.1
    _write(tmp_path / "other", other)
    with pytest.raises(SpecError, match=r"column 'impulse_ns' differs in 1 of 370 records "
                                        r"\(first: record 5"):
        compare_runs([str(off), str(tmp_path / "other")], tmp_path / "x")
    short = {k: v[:300] for k, v in _records(1).items()}
    _write(tmp_path / "short", short, complete=False)
    with pytest.raises(SpecError, match="short is an incomplete sweep"):
        compare_runs([str(off), str(tmp_path / "short")], tmp_path / "x")
    with pytest.raises(SpecError, match="300 records with control on.*370.*incomplete"):
        compare_runs([str(off), str(tmp_path / "short")], tmp_path / "x",
                     allow_incomplete=True)
    with pytest.raises(SpecError, match="no records with control on"):
        compare_runs([str(off) + ":on", str(off)], tmp_path / "x")
    with pytest.raises(SpecError, match="2 or more runs"):
        compare_runs([str(off)], tmp_path / "x")
    with pytest.raises(SpecError, match="sectors must be one of"):
        compare_runs([str(off), str(off)], tmp_path / "x", bands=Bands(sectors=5))
    with pytest.raises(SpecError, match="impulse_edges .* must cover every impulse"):
        compare_runs([str(off), str(off)], tmp_path / "x", bands=Bands(impulse_edges=(0.5, 1.0)))


def test_one_sweep_folder_gives_reference_and_controller(tmp_path):
    """A spec with control off and on: DIR:off is the reference, DIR:on the controller; the
    records' inputs come from the sweep's own expansion (record_inputs)."""
    spec = parse_spec({"sweep": {"name": "t", "chunk_size": 16, "control": ["off", "on"]},
                       "push": {"random": {"n": 40, "impulse_ns": {"uniform": [0.2, 1.8]},
                                           "azimuth_deg": {"uniform": [0, 360]}}}})
    rec = record_inputs(spec)
    n = len(rec["push_id"])
    on = rec["control"].astype(bool)
    fell = (rec["impulse_ns"] > 1.0) & ~(on & (rec["impulse_ns"] < 1.4))   # control helps
    rec |= dict(fell=fell, diverged=np.zeros(n, bool), recovery_time_s=np.zeros(n))
    d = _write(tmp_path / "sweep", rec, chunk=16)
    res = compare_runs([f"{d}:off", f"{d}:on", f"{d}:on"], tmp_path / "cmp", min_pushes=1)
    v = res["verdict"]
    labels = list(v["runs"])
    assert v["reference"]["label"] == "sweep (off)" and labels == ["sweep (on)", "sweep (on) #3"]
    half = rec["impulse_ns"][:40]
    assert v["reference"]["fall_rate"] == pytest.approx(np.mean(half > 1.0))
    assert v["runs"]["sweep (on)"]["fall_rate"] == pytest.approx(np.mean(half >= 1.4))
    assert v["runs"]["sweep (on)"]["no_harm"]


def test_unpaired_robots_accepts_other_draws_and_uses_independent_errors(tmp_path):
    """Two runs of one push set whose robot draws differ: refused by default, accepted with
    unpaired_robots, with the standard error of a difference of two independent rates."""
    import numpy as np
    from tkujax.analysis.compare import Run, check_same_pushes, fall_difference
    from tkujax.dialects.sweep_spec import SpecError

    n = 200
    base = dict(impulse_ns=np.full(n, 1.0), azimuth_deg=np.zeros(n), onset_phase=np.zeros(n))
    ref = Run("a", "a", "off", base | dict(link_mass_scale=np.full(n, 1.0)),
              np.arange(n) < 50, np.zeros(n, bool), True)
    run = Run("b", "b", "on", base | dict(link_mass_scale=np.full(n, 1.02)),
              np.arange(n) < 80, np.zeros(n, bool), True)
    with pytest.raises(SpecError, match="link_mass_scale"):
        check_same_pushes(ref, run)
    check_same_pushes(ref, run, frozenset({"link_mass_scale"}))
    d, se = fall_difference(np.zeros(n, int), 1, ref, run, unpaired=True)
    assert d[0] == pytest.approx(0.4 - 0.25)
    assert se[0] == pytest.approx(np.sqrt(0.25 * 0.75 / n + 0.4 * 0.6 / n))
