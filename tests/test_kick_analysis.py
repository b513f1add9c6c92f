"""Velocity-kick sweeps ([push] kind = "velocity_kick") in `tkujax compare` and the standing
`tkujax map`: both band and map along kick_mps (tkujax.analysis.map_cells.push_size), on
synthetic sweep folders written with the sweep's own chunk writer; the fall rates per band
against a numpy count, the harmed cells naming a kick_mps band."""

import json
from pathlib import Path

import numpy as np

from tkujax.analysis.compare import Bands, compare_runs
from tkujax.analysis.map_cells import push_size
from tkujax.analysis.maps import make_maps
from tkujax.sweeps import chunks

KICKS = (0.1, 0.2, 0.3, 0.4, 0.5)
AZIMUTHS = (0.0, 90.0, 180.0, 270.0)        # behind, right, front, left
SECTORS = ("behind", "right", "front", "left")
REPEATS = 12
SPEC = {"sweep": {"name": "kicks", "duration_s": 1.5, "control": ["off", "on"]},
        "push": {"kind": "velocity_kick",
                 "grid": {"kick_mps": list(KICKS), "azimuth_deg": list(AZIMUTHS),
                          "onset_s": [0.33]}}}


def _inputs() -> dict:
    kick, az = (a.ravel() for a in np.meshgrid(np.repeat(KICKS, REPEATS), AZIMUTHS,
                                               indexing="ij"))
    n = len(kick)
    return dict(kick_mps=kick, azimuth_deg=az, onset_s=np.full(n, 0.33),
                duration_s=np.full(n, 0.03), onset_phase=np.zeros(n), push_id=np.arange(n),
                from_grid=np.ones(n, bool), diverged=np.zeros(n, bool))


def _fell(inputs: dict, seed: int, harm: float = 0.0) -> np.ndarray:
    """Falls likelier with the kick (and, with harm, more often pushed from behind)."""
    p = 0.8 * inputs["kick_mps"] + harm * (inputs["azimuth_deg"] == 0.0)
    return np.random.default_rng(seed).random(len(p)) < p


def _write(out: Path, rec: dict) -> Path:
    out.mkdir(parents=True)
    n = len(rec["fell"])
    chunks.update_manifest(out, lambda m: m | {"name": out.name, "spec": SPEC, "n_pushes": n,
                                               "complete": True})
    chunks.write_chunk(out, 0, rec)
    return out


def test_push_size_names_the_kick_or_the_impulse():
    assert push_size({"kick_mps": 0, "azimuth_deg": 0}) == ("kick_mps", "kick (m/s)")
    assert push_size({"impulse_ns": 0}) == ("impulse_ns", "impulse (N·s)")


def test_compare_of_two_kick_runs_bands_along_kick_mps(tmp_path):
    inputs = _inputs()
    n = len(inputs["kick_mps"])
    fells = (_fell(inputs, 1), _fell(inputs, 1, harm=0.3))   # the same draws: paired
    runs = [_write(tmp_path / name, inputs | dict(fell=f, control=np.full(n, c)))
            for name, f, c in (("off", fells[0], False), ("on", fells[1], True))]
    edges = (0.0, 0.25, 0.6)
    result = compare_runs([str(r) for r in runs], tmp_path / "cmp", labels=["off", "on"],
                          bands=Bands(impulse_edges=edges, phase_bands=1), min_pushes=10)
    pooled = [r for r in result["table"]["rows"] if r["phase"] == "all"]
    assert len(pooled) == len(SECTORS) * 2
    for row in pooled:
        # The reference count: sector by the exact azimuth, band by the kick against the edges.
        az = AZIMUTHS[SECTORS.index(row["sector"])]
        band = (inputs["kick_mps"] < 0.25) if row["impulse_lo"] == 0.0 else (
            inputs["kick_mps"] > 0.25)
        sel = (inputs["azimuth_deg"] == az) & band
        for label, fell in zip(("off", "on"), fells):
            assert row["runs"][label]["n"] == sel.sum()
            assert row["runs"][label]["rate"] == float(np.mean(fell[sel]))
    v = result["verdict"]["runs"]["on"]
    assert v["fall_rate"] == float(fells[1].mean())
    assert v["harmed_cells"], "the run falls 30 pp more often pushed from behind"
    for cell in v["harmed_cells"]:
        assert "impulse_ns" not in cell and cell["kick_mps"] in ([0.0, 0.25], [0.25, 0.6])
    assert {c["sector"] for c in v["harmed_cells"]} == {"behind"}
    doc = json.loads((tmp_path / "cmp" / "verdict.json").read_text())
    assert doc["bands"]["kick_edges_mps"] == list(edges)
    csv = (tmp_path / "cmp" / "table.csv").read_text()
    assert csv.startswith("sector,kick_lo_mps,kick_hi_mps,")
    summary = Path(result["summary"]).read_text()
    assert "| sector | kick (m/s) | phase |" in summary and "N·s" not in summary
    assert all(Path(f).stat().st_size > 0 for f in result["files"])


def test_standing_map_of_a_kick_sweep(tmp_path):
    inputs = _inputs()
    n = len(inputs["kick_mps"])
    both = {k: np.concatenate([v, v]) for k, v in inputs.items()}
    both["push_id"] = np.arange(2 * n)
    rng = np.random.default_rng(3)
    rec = both | dict(fell=np.concatenate([_fell(inputs, 4), _fell(inputs, 5)]),
                      control=np.repeat([False, True], n),
                      **{k: rng.random(2 * n) * 0.05 for k in (
                          "recovery_time_s", "step_length_m", "step_width_m", "peak_incl_deg",
                          "capture_point_m", "capture_point_y_m", "zmp_excursion_m")})
    out = _write(tmp_path / "kicks", rec)
    result = make_maps(out)
    assert len(result["files"]) == 5
    assert all(Path(f).stat().st_size > 0 for f in result["files"])
    summary = Path(result["summary"]).read_text()
    assert "kick (m/s)" in summary
    rows = json.loads((out / "maps" / "summary.json").read_text())
    assert sorted({r["azimuth_deg"] for r in rows}) == list(AZIMUTHS)
    # The sim max is a tested kick (or 0), the theory the LIP's impulse over its mass.
    assert all(r["sim_max_off"] in (0.0,) + KICKS for r in rows)
