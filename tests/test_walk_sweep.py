"""Walking sweeps: a sweep spec's [walk] table and pushes placed by gait phase
(tkujax.dialects.walk_table; docs/walking.md).

The spec against closed forms (the onset of a gait phase, the record count, the gait phase of an
onset); refusals naming the key and its range (exit code 2 from the command line); the spec hash
covering [walk]; a MuJoCo C walking sweep's records against the direct walk simulation
(`tkujax.walking.walk.run_walk` with the same command and push); MJX against MuJoCo C and early
decisions against the full horizon (slow: MJX compiles).
"""

import json
from pathlib import Path

import numpy as np
import pytest

from tkujax.cli import main
from tkujax.control.gait import WalkCommand
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim.push import stack_pushes
from tkujax.analysis.compare import Bands
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.sweep import load, run_sweep
from tkujax.sweeps.sweep_hash import spec_hash
from tkujax.walking.walk import run_walk, walk_metrics, walker
from tkujax.walking.walk_push import push_at_gait_phase

from walk_helpers import full_and_early

PARAMS = ControllerParams.paper()


def _spec(walk=None, grid=None, sweep=None, random=None):
    push = {"grid": grid if grid is not None else {"impulse_ns": [0.4, 1.5],
                                                     "gait_phase": [0.25]}}
    if random is not None:
        push["random"] = random
    return {"sweep": {"duration_s": 2.0, "chunk_size": 8} | (sweep or {}),
            "walk": {"speed_mps": 0.1, "push_cycle": 1} | (walk or {}), "push": push}


def test_gait_phase_onsets_follow_the_gait_schedule():
    """Closed form: the first left touchdown of TKU-X's walk is start 0.3 s + T (1 - gamma / 2)
    = 0.57 s; phase p of cycle c is 0.57 + (c + p) 2 T."""
    spec = parse_spec(_spec(walk={"recovery": ["off", "on"]},
                            grid={"impulse_ns": [0.5], "gait_phase": [0.0, 0.25, 0.5, 0.75]}))
    rec = spec.records()
    assert len(rec["push_id"]) == 8          # 4 phases x recovery off, on (control: on)
    np.testing.assert_allclose(rec["onset_s"][:4], 0.57 + (1 + np.array([0, .25, .5, .75])) * .6,
                               atol=1e-6)
    np.testing.assert_array_equal(rec["walk_recovery"], [0.0] * 4 + [1.0] * 4)
    np.testing.assert_array_equal(rec["control"], True)
    np.testing.assert_allclose(rec["walk_speed_mps"], 0.1)
    np.testing.assert_allclose(rec["walk_step_period_s"], 0.3, rtol=1e-6)
    np.testing.assert_array_equal(rec["gait_phase"][4:], rec["gait_phase"][:4])
    # The same pushes placed by the library's own placement.
    cmd = WalkCommand.for_params(PARAMS, 0.1)
    for phase, onset in zip(rec["gait_phase"][:4], rec["onset_s"][:4]):
        assert onset == pytest.approx(float(push_at_gait_phase(cmd, phase, 0.5, cycle=1).onset_s),
                                      abs=1e-6)


def test_onsets_given_in_seconds_record_their_gait_phase():
    spec = parse_spec(_spec(grid={"impulse_ns": [0.5], "onset_s": [0.57, 0.87, 1.02]},
                            walk={"step_period_s": 0.3}))
    np.testing.assert_allclose(spec.records()["gait_phase"], [0.0, 0.5, 0.75], atol=1e-5)


def test_random_gait_phases_are_drawn_in_range():
    spec = parse_spec(_spec(grid={"impulse_ns": [0.5], "gait_phase": [0.0]},
                            random={"n": 50, "gait_phase": {"uniform": [0.2, 0.4]}}))
    rec = spec.records()
    ph = rec["gait_phase"][1:]
    assert ((ph >= 0.2) & (ph < 0.4)).all() and len(np.unique(ph)) == 50
    np.testing.assert_allclose(rec["onset_s"][1:], np.round(0.57 + (1 + ph) * 0.6, 6), atol=2e-6)


@pytest.mark.parametrize("change, message", [
    ({"walk": {"speed_mps": 1.5}}, r"walk\.speed_mps: 1\.5 is out of range \[-1\.0, 1\.0\] m/s"),
    ({"walk": {"lateral_mps": -0.7}}, r"walk\.lateral_mps: .*\[-0\.5, 0\.5\]"),
    ({"walk": {"step_period_s": 0.05}}, r"walk\.step_period_s: .*\[0\.1, 2\.0\] s"),
    ({"walk": {"recovery": ["on", "maybe"]}}, r"walk\.recovery: expected"),
    ({"walk": {"push_cycle": 101}}, r"walk\.push_cycle: expected an integer in \[0, 100\]"),
    ({"walk": {"pace": 1}}, r"\[walk\]: unknown key\(s\) \['pace'\]"),
    ({"grid": {"gait_phase": [1.0]}}, r"push\.grid\.gait_phase: 1\.0 is out of range \[0, 1\)"),
    ({"grid": {"gait_phase": [0.5], "onset_s": [1.0]}}, r"gait_phase gives the onset"),
    ({"random": {"n": 3, "gait_phase": {"uniform": [1.0, 1.0]}}},
     r"push\.random\.gait_phase\.uniform\[0\]: 1\.0 is out of range \[0, 1\)"),
    ({"walk": {"push_cycle": 3}}, r"push\.grid\.gait_phase \(in walk\.push_cycle = 3\).*after "
                                  r"the horizon sweep\.duration_s = 2 s"),
])
def test_refusals_name_the_key_and_the_range(change, message):
    data = _spec(**change)
    with pytest.raises(SpecError, match=message):
        parse_spec(data)


def test_walking_refuses_commanded_steps():
    with pytest.raises(SpecError, match=r"\[step\]: commanded steps do not run while walking"):
        parse_spec(_spec() | {"step": {"grid": {"x_m": [0.05]}}})


def test_gait_phase_needs_a_walk():
    with pytest.raises(SpecError, match=r"push\.grid\.gait_phase: a gait phase needs a \[walk\]"):
        parse_spec({"push": {"grid": {"impulse_ns": [0.5], "gait_phase": [0.5]}}})


def test_command_line_refuses_a_bad_walk_with_exit_code_2(tmp_path, capsys):
    spec = tmp_path / "walk.toml"
    spec.write_text('[walk]\nspeed_mps = 2.0\n[push.grid]\nimpulse_ns = [0.5]\n')
    assert main(["sweep", str(spec), "--out", str(tmp_path / "out")]) == 2
    assert "walk.speed_mps: 2.0 is out of range [-1.0, 1.0] m/s" in capsys.readouterr().err


def test_spec_hash_covers_the_walk():
    model = ModelParams()
    hashes = {spec_hash(parse_spec(_spec(walk=w)), PARAMS, model)
              for w in ({}, {"speed_mps": 0.2}, {"recovery": "on"}, {"step_period_s": 0.31})}
    standing = parse_spec({"sweep": {"duration_s": 2.0},
                           "push": {"grid": {"impulse_ns": [0.4, 1.5], "onset_s": [1.32]}}})
    hashes.add(spec_hash(standing, PARAMS, model))
    assert len(hashes) == 5


@pytest.fixture(scope="module")
def walk_sweep(tmp_path_factory):
    """A MuJoCo C walking sweep: 2 impulses x 2 directions x 2 gait phases x recovery off, on."""
    data = _spec(walk={"recovery": ["off", "on"]}, sweep={"duration_s": 2.4},
                 grid={"impulse_ns": [0.4, 1.5], "azimuth_deg": [0.0, 90.0],
                       "gait_phase": [0.25, 0.75]})
    out = tmp_path_factory.mktemp("walk") / "sweep"
    run_sweep(parse_spec(data), out, backend="mujoco", quiet=True)
    return out


def test_mujoco_walking_sweep_matches_the_direct_walk(walk_sweep):
    """Each record of a MuJoCo C walking sweep against the same walk and push simulated
    directly: the same fall, peak inclination, and the distance walk_metrics measures."""
    rec = load(walk_sweep)
    assert len(rec["push_id"]) == 16
    who = walker()
    for recovery in (0.0, 1.0):
        rows = np.flatnonzero(rec["walk_recovery"] == recovery)
        cmd = WalkCommand.for_params(PARAMS, 0.1, recovery=recovery)
        pushes = stack_pushes([push_at_gait_phase(cmd, float(rec["gait_phase"][i]),
                                                  float(rec["impulse_ns"][i]),
                                                  float(rec["azimuth_deg"][i]), cycle=1)
                               for i in rows])
        np.testing.assert_allclose(rec["onset_s"][rows], pushes.onset_s, atol=1e-6)
        series, out = run_walk(who, [cmd] * len(rows), 2.4, "mujoco", pushes=pushes)
        np.testing.assert_array_equal(rec["fell"][rows], out.fell)
        np.testing.assert_allclose(rec["peak_incl_deg"][rows], out.peak_incl_deg, rtol=1e-5)
        for j, i in enumerate(rows):
            direct = walk_metrics(series, j, cmd)
            # walk_metrics starts one sample (30 ms) later, before the first step moves the CoM.
            assert rec["distance_m"][i] == pytest.approx(direct["distance_m"], abs=5e-3)
    fell = rec["fell"].astype(bool)
    assert fell.any() and not fell.all()     # the set has both outcomes
    assert (rec["distance_m"][~fell] > 0.1).all()   # 2.1 s of walking at 0.1 m/s


def test_map_of_a_walking_sweep_counts_every_cell(walk_sweep):
    """tkujax map's walking cells: falls and pushes per (recovery, azimuth, impulse, gait
    phase), against the records counted directly; the files are written."""
    from tkujax.analysis.maps import make_maps
    from tkujax.analysis.walk_maps import walk_cells

    rec = load(walk_sweep)
    cells = walk_cells(rec)
    assert cells["settings"] == [False, True]
    np.testing.assert_array_equal(cells["gait_phase"], [0.25, 0.75])
    assert cells["count"].shape == (2, 2, 2, 2) and (cells["count"] == 1).all()
    for i in range(len(rec["fell"])):
        k = int(rec["walk_recovery"][i])
        a = int(np.flatnonzero(cells["azimuth_deg"] == rec["azimuth_deg"][i])[0])
        j = int(np.flatnonzero(cells["impulse_ns"] == rec["impulse_ns"][i])[0])
        p = int(np.flatnonzero(cells["gait_phase"] == rec["gait_phase"][i])[0])
        assert cells["falls"][k, a, j, p] == float(rec["fell"][i])
    res = make_maps(walk_sweep)
    assert [Path(f).name for f in res["files"]] == ["walk_polar.png", "fall_vs_gait_phase.png"]
    doc = json.loads((walk_sweep / "maps" / "summary.json").read_text())
    on = rec["walk_recovery"] > 0.5
    assert doc["overall"]["recovery on"]["fall_rate"] == pytest.approx(rec["fell"][on].mean())
    assert sum(c["falls"] for c in doc["cells"]) == int(rec["fell"].sum())


def test_compare_recovery_on_against_off_bands_by_gait_phase(walk_sweep, tmp_path):
    """tkujax compare DIR:recovery-off DIR:recovery-on: the verdict's fall rates are the
    records', and the phase bands split the gait phase (0.25 in the first of 2, 0.75 in the
    second), not the onset's phase in the control period."""
    from tkujax.analysis.compare import compare_runs, load_run

    rec = load(walk_sweep)
    on = rec["walk_recovery"] > 0.5
    res = compare_runs([f"{walk_sweep}:recovery-off", f"{walk_sweep}:recovery-on"], tmp_path,
                       min_pushes=1, bands=Bands(phase_bands=2, impulse_bands=2))
    v = res["verdict"]
    assert v["reference"]["fall_rate"] == pytest.approx(rec["fell"][~on].mean())
    label, run = next(iter(v["runs"].items()))
    assert run["fall_rate"] == pytest.approx(rec["fell"][on].mean())
    harmed = [(c["sector"], c["phase"]) for c in run["harmed_cells"]]
    rows = [r for r in res["table"]["rows"] if r["phase"] != "all"]
    for r in rows:
        sel = (~on & (rec["gait_phase"] >= r["phase_lo"]) & (rec["gait_phase"] < r["phase_hi"])
               & (rec["impulse_ns"] >= r["impulse_lo"]) & (rec["impulse_ns"] <= r["impulse_hi"])
               & (np.mod(rec["azimuth_deg"], 360) == {"behind": 0, "right": 90}[r["sector"]]))
        ref = r["runs"][v["reference"]["label"]]
        assert ref["n"] == int(sel.sum()) == 1 and ref["falls"] == int(rec["fell"][sel].sum())
    worse = [r for r in res["table"]["rows"] if r["runs"][label]["diff_pp"] > 2.0]
    assert sorted(harmed) == sorted((r["sector"], r["phase"]) for r in worse)
    assert run["no_harm"] == (not worse)
    assert "gait phase at onset" in Path(res["summary"]).read_text()
    with pytest.raises(SpecError, match="recovery-on' selects a walking sweep"):
        standing = tmp_path / "standing"
        run_sweep(parse_spec({"sweep": {"duration_s": 0.9, "control": ["on"]},
                              "push": {"grid": {"impulse_ns": [0.3]}}}), standing,
                  backend="mujoco", quiet=True)
        load_run(f"{standing}:recovery-on")


@pytest.mark.slow
def test_early_walking_decisions_stop_only_at_falls(tmp_path):
    """decisions = "early" on a walking sweep (MJX lanes): a walking lane is decided by a fall
    only. The falls are the full horizon's; a fallen push is decided before the horizon, every
    other one runs to it, and the distance of those that stood is the full run's (1 mm)."""
    data = _spec(walk={"recovery": "on", "push_cycle": 0},
                 sweep={"duration_s": 1.5, "chunk_size": 4, "lanes": 2},
                 grid={"impulse_ns": [0.4, 1.5], "gait_phase": [0.25, 0.75]})
    out = full_and_early(data, tmp_path)
    fell = out["full"]["fell"].astype(bool)
    assert fell.any() and not fell.all()
    np.testing.assert_array_equal(out["early"]["fell"].astype(bool), fell)
    decided = out["early"]["decided_s"]
    assert (decided[fell] < 1.5 - 0.03).all() and np.allclose(decided[~fell], 1.5, atol=1e-4)
    np.testing.assert_allclose(out["early"]["distance_m"][~fell], out["full"]["distance_m"][~fell],
                               atol=1e-3)


@pytest.mark.slow
def test_mjx_walking_sweep_matches_mujoco(tmp_path):
    """The same walking sweep on MJX (float32) and MuJoCo C (float64): the same falls, the
    distance walked within 1 cm."""
    data = _spec(walk={"recovery": "on", "push_cycle": 0}, sweep={"duration_s": 1.5,
                                                                  "chunk_size": 2})
    out = {}
    for backend in ("mujoco", "mjx"):
        run_sweep(parse_spec(data), tmp_path / backend, backend=backend, quiet=True)
        out[backend] = load(tmp_path / backend)
    np.testing.assert_array_equal(out["mjx"]["fell"], out["mujoco"]["fell"])
    np.testing.assert_allclose(out["mjx"]["distance_m"], out["mujoco"]["distance_m"], atol=0.01)
    np.testing.assert_array_equal(out["mjx"]["gait_phase"], out["mujoco"]["gait_phase"])


def test_replay_of_a_walking_record_is_identical(walk_sweep):
    """tkujax replay re-runs a walking record with its walk (MuJoCo C: its whole chunk)."""
    from tkujax.sweeps.replay import replay

    rec = load(walk_sweep)
    i = int(np.flatnonzero(rec["fell"].astype(bool) & (rec["walk_recovery"] > 0.5))[0])
    res = replay(walk_sweep, i)
    assert res["identical"], res["differences"]


OP3_FILE = Path(__file__).resolve().parent.parent / "specs" / "robots" / "op3.toml"
OP3_MODEL = Path(__file__).resolve().parent.parent.parent / "shared" / "models" / "robotis_op3"


@pytest.mark.skipif(not OP3_MODEL.is_dir(), reason="OP3's Menagerie model is not here")
def test_a_robot_files_walk_takes_its_step_period():
    """[robot] file = OP3: the walk's default step period is the robot's gait's (0.313 s), and
    the gait-phase onsets follow it."""
    spec = parse_spec(_spec(walk={"recovery": "on"}) | {"robot": {"file": str(OP3_FILE)}})
    period = float(walker(str(OP3_FILE)).gait_params.step_period)
    assert period == pytest.approx(0.313, abs=5e-4)
    rec = spec.records()
    np.testing.assert_allclose(rec["walk_step_period_s"], period, rtol=1e-6)
    cmd = WalkCommand.for_params(walker(str(OP3_FILE)).gait_params, 0.1)
    onset = float(push_at_gait_phase(cmd, 0.25, 0.5, cycle=1).onset_s)
    np.testing.assert_allclose(rec["onset_s"], onset, atol=1e-6)


@pytest.mark.skipif(not OP3_MODEL.is_dir(), reason="OP3's Menagerie model is not here")
def test_a_robot_given_on_the_command_line_resolves_the_walk_again():
    """`tkujax sweep --robot op3.toml` of a spec without [robot]: the walk is resolved for OP3
    (walk_for_robot), as if the spec named it."""
    from tkujax.robot.robot_setup import robot_setup
    from tkujax.dialects.walk_table import walk_for_robot

    named = parse_spec(_spec() | {"robot": {"file": str(OP3_FILE)}}).records()
    given = walk_for_robot(parse_spec(_spec()), robot_setup(str(OP3_FILE))).records()
    for k in ("onset_s", "walk_step_period_s", "gait_phase"):
        np.testing.assert_array_equal(given[k], named[k])
    assert given["onset_s"][0] != parse_spec(_spec()).records()["onset_s"][0]


def test_random_walking_pushes_are_mapped_in_cells_of_many_pushes():
    """A grid keeps its values; random pushes share a binning whose cells hold about
    MIN_PUSHES_PER_CELL pushes on average, never fewer than MIN_RANDOM_BINS bins an axis."""
    from tkujax.analysis.walk_maps import (MIN_PUSHES_PER_CELL, MIN_RANDOM_BINS, cell_bins,
                                           walk_cells)

    grid = [np.repeat([0.0, 90.0, 180.0, 270.0], 16), np.tile([0.5, 0.7, 0.9, 1.2], 16),
            np.tile([0.0, 0.25, 0.5, 0.75], 16)]
    assert cell_bins(grid, (72, 48, 16), 64) == [72, 48, 16]
    rng = np.random.default_rng(0)
    n = 65536
    rec = {"azimuth_deg": rng.uniform(0, 360, 2 * n), "impulse_ns": rng.uniform(0.1, 2.4, 2 * n),
           "gait_phase": rng.uniform(0, 1, 2 * n), "fell": rng.random(2 * n) < 0.5,
           "walk_recovery": np.repeat([0.0, 1.0], n)}
    cells = walk_cells(rec)
    per_cell = cells["count"][0][cells["count"][0] > 0]
    assert 0.8 * MIN_PUSHES_PER_CELL <= per_cell.mean() <= 1.5 * MIN_PUSHES_PER_CELL
    assert cells["count"].sum() == 2 * n
    few = cell_bins([a[:200] for a in (rec["azimuth_deg"], rec["impulse_ns"], rec["gait_phase"])],
                    (72, 48, 16), 100)
    assert few == [MIN_RANDOM_BINS] * 3
