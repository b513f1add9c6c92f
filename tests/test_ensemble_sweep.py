"""Sweeps over an ensemble of robots ([randomize] ensemble): the spec key's
validation, the robot_id draw shared by a push's settings, the MJX sweep against each member run
alone (`tkujax.sim.rollout_mjx.simulate` on its own ModelParams: an independent reference), and
the map's per-member fall boundaries and their band on synthetic records."""

import json
from pathlib import Path

import numpy as np
import pytest

from tkujax.model.ensemble import save_ensemble
from tkujax.analysis import maps
from tkujax.studies.calibrate import fit_vector as P
from tkujax.dialects.sweep_spec import SpecError, load_spec, parse_spec
from tkujax.sweeps.sweep_hash import spec_hash
from tkujax.sweeps.sweep import choose_backend, record_inputs
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams

ROOT = Path(__file__).resolve().parents[1]


def _x(**changes) -> dict:
    x = P.as_dict(P.base_vector())
    x.update(changes)
    return x


# Two robots of one structure: the base vector and a soft-legged, short-footed one.
MEMBERS = [_x(), _x(foot_length_m=0.11, leg_kp=10.0, chest_com_frac=0.75)]


def _ensemble(path: Path, n_members: int = 2) -> Path:
    mps = [P.model_params(MEMBERS[k % len(MEMBERS)]) for k in range(n_members)]
    return save_ensemble(path, [dict(model_params=m, loss=0.0) for m in mps], 0, tolerance=0.1)


def _spec(ensemble, **randomize) -> dict:
    return {"sweep": {"name": "ens", "seed": 3, "chunk_size": 8, "duration_s": 1.0,
                      "control": ["off", "on"]},
            "push": {"grid": {"impulse_ns": [0.5, 1.5], "azimuth_deg": [0, 90, 180],
                              "onset_s": [0.3]}},
            "controller": {"grid": {"cp_gain": [1.0, 1.2]}},
            "randomize": {"ensemble": str(ensemble)} | randomize}


# --- The spec key ---

def test_missing_and_bad_files_are_spec_errors_naming_the_key(tmp_path):
    with pytest.raises(SpecError, match=r"randomize.ensemble: ensemble file .*none.json does not "
                                        r"exist"):
        parse_spec(_spec(tmp_path / "none.json"))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(SpecError, match=r"randomize.ensemble: ensemble file .*bad.json: not JSON"):
        parse_spec(_spec(bad))
    bad.write_text('{"version": 1, "members": []}')
    with pytest.raises(SpecError, match=r"randomize.ensemble: .*'members' must be a non-empty"):
        parse_spec(_spec(bad))
    bad.write_text('{"version": 1, "members": [{"model_params": {"foot_length_m": "x"}}]}')
    with pytest.raises(SpecError, match=r"randomize.ensemble: .*members\[0\].model_params: "
                                        r"foot_length_m"):
        parse_spec(_spec(bad))
    with pytest.raises(SpecError, match=r"randomize.ensemble: expected the path of an ensemble"):
        parse_spec(_spec("x") | {"randomize": {"ensemble": 3}})
    with pytest.raises(SpecError, match=r"\[randomize\]: unknown key\(s\) \['ensembles'\]; "
                                        r"allowed: .*'ensemble'"):
        parse_spec(_spec(tmp_path) | {"randomize": {"ensembles": "x"}})


def test_robot_id_is_drawn_per_push_and_shared_by_its_settings(tmp_path):
    path = _ensemble(tmp_path / "e.json", n_members=3)
    spec = parse_spec(_spec(path, link_mass_scale={"uniform": [0.9, 1.1]}))
    assert spec.ensemble.n == 3 and spec.ensemble.path == str(path)
    rec = record_inputs(spec)
    n_push, n_settings = 6, 4                       # 2 x 3 pushes; control x cp_gain
    rid = rec["robot_id"]
    assert rid.shape == (n_push * n_settings,) and set(np.unique(rid)) <= {0, 1, 2}
    blocks = rid.reshape(n_settings, n_push)
    assert (blocks == blocks[0]).all()              # paired: one member per push
    assert len(np.unique(blocks[0])) > 1
    # The other draws are those of the same spec without an ensemble (robot_id is drawn last)
    plain = _spec(path, link_mass_scale={"uniform": [0.9, 1.1]})
    del plain["randomize"]["ensemble"]
    without = record_inputs(parse_spec(plain))
    assert "robot_id" not in without
    np.testing.assert_array_equal(without["link_mass_scale"], rec["link_mass_scale"])
    # Deterministic in the seed
    np.testing.assert_array_equal(record_inputs(parse_spec(_spec(path)))["robot_id"],
                                  record_inputs(parse_spec(_spec(path)))["robot_id"])


def test_the_ensemble_content_enters_the_hash_and_both_backends_take_it(tmp_path):
    path = _ensemble(tmp_path / "e.json")
    spec = parse_spec(_spec(path))
    h = spec_hash(spec, ControllerParams.paper(), ModelParams())
    assert h == spec_hash(parse_spec(_spec(path)), ControllerParams.paper(), ModelParams())
    _ensemble(path, n_members=3)                    # same path, other content
    assert h != spec_hash(parse_spec(_spec(path)), ControllerParams.paper(), ModelParams())
    assert choose_backend("mujoco", spec) == "mujoco"
    assert choose_backend("mjx", spec) == "mjx"


def test_the_shipped_specs_parse(monkeypatch):
    """specs/sweep/ensemble_cpu.toml and ensemble_map.toml with the committed 39-member ensemble of
    results/calibration/expected (paths relative to the repository root)."""
    monkeypatch.chdir(ROOT)
    for name in ("ensemble_cpu", "ensemble_map"):
        spec = load_spec(ROOT / "specs" / "sweep" / f"{name}.toml")
        ids = spec.records()["robot_id"]
        assert spec.ensemble.n == 39 and ids.min() >= 0 and ids.max() < 39


# --- Running: the MJX sweep against each member alone (compiles 3 MJX programs: minutes) ---

@pytest.fixture(scope="module")
def ensemble_run(tmp_path_factory):
    from tkujax.sweeps.sweep import load, run_sweep

    tmp = tmp_path_factory.mktemp("ens")
    data = _spec(_ensemble(tmp / "e.json"))
    data["sweep"] |= {"seed": 1, "duration_s": 1.0}
    data["push"]["grid"] = {"impulse_ns": [1.0, 2.5], "azimuth_deg": [0, 180], "onset_s": [0.3]}
    del data["controller"]
    spec = parse_spec(data)
    manifest = run_sweep(spec, tmp / "mjx", backend="mjx", quiet=True)
    return spec, manifest, load(tmp / "mjx")


@pytest.mark.slow
def test_each_record_runs_on_its_member(ensemble_run):
    """Every record's outcome is that of its push on its member's own model
    (rollout_mjx.simulate with model_params = the member: MuJoCo's compile of that robot alone),
    and the two members answer the same pushes differently."""
    from tkujax.sim.push import Push
    from tkujax.sim.rollout_mjx import RolloutConfig, simulate

    spec, manifest, rec = ensemble_run
    assert manifest["complete"] and manifest["ensemble"]["sha256"] == spec.ensemble.sha256
    rid = rec["robot_id"].astype(int)
    assert set(rid) == {0, 1}
    n = len(rid)
    pushes = Push(*(np.asarray(v, np.float32) for v in (
        rec["impulse_ns"], np.radians(rec["azimuth_deg"]), rec["height_m"], rec["duration_s"],
        rec["onset_s"])))
    ref = [simulate(pushes, rec["control"].astype(np.float32), ControllerParams.paper(),
                    model_params=mp, config=RolloutConfig(duration_s=1.0))[1]
           for mp in spec.ensemble.members]
    own = {k: np.array([ref[rid[i]][k][i] for i in range(n)]) for k in ref[0]}
    np.testing.assert_array_equal(rec["fell"], own["fell"])
    up = ~rec["fell"].astype(bool)
    np.testing.assert_allclose(rec["peak_incl_deg"][up], own["peak_incl_deg"][up], atol=0.05)
    np.testing.assert_allclose(rec["step_length_m"][up], own["step_length_m"][up], atol=1e-3)
    # The member matters: the other member's peak inclination differs on the same pushes.
    other = np.array([ref[1 - rid[i]]["peak_incl_deg"][i] for i in range(n)])
    assert np.max(np.abs(other - own["peak_incl_deg"])) > 0.5


@pytest.mark.slow
def test_mujoco_c_runs_each_member(ensemble_run, tmp_path):
    """The MuJoCo C backend (one batch per member) agrees with the MJX sweep on the fall
    outcomes (the pushes are far from the boundary) and writes the same robot_id column; a
    replay runs the record on its member."""
    from tkujax.sweeps.sweep import load, run_sweep

    spec, _, mjx_rec = ensemble_run
    manifest = run_sweep(spec, tmp_path, backend="mujoco", quiet=True)
    assert manifest["backend"] == "mujoco"
    rec = load(tmp_path)
    np.testing.assert_array_equal(rec["robot_id"], mjx_rec["robot_id"])
    assert np.mean(rec["fell"] == mjx_rec["fell"]) >= 0.85
    # replay re-runs the record on its member, and refuses a changed ensemble file
    from tkujax.sweeps.replay import replay

    i = int(np.flatnonzero(rec["robot_id"] == 1)[0])
    again = replay(tmp_path, i)
    assert again["identical"] and again["model_params"] == spec.ensemble.members[1]
    _ensemble(Path(spec.ensemble.resolved), n_members=3)
    with pytest.raises(ValueError, match="has changed since the sweep ran"):
        replay(tmp_path, i)


# --- The map: per-member boundaries and their band (synthetic records, no simulation) ---

J = [0.5, 1.0, 1.5, 2.0]


def _synthetic() -> dict:
    """4 members, control off at azimuths 0 and 90 (2 records per tested cell), plus control-on
    and diverged records that must not count. Member boundaries (largest tested impulse below
    the first cell with fall fraction >= 1/2):
      azimuth 0:  m0 0.5 (1 of 2 fell at 1.0), m1 1.0, m2 1.5, m3 2.0 (none fell)
      azimuth 90: m0 1.0, m1 0.5 (1.0 untested, fell at 1.5), m2 0.0 (fell at 0.5),
                  m3 none (4 records < MIN_MEMBER_PUSHES = 6)."""
    rows = []   # (robot_id, azimuth, impulse, fell, control, diverged)

    def cell(m, az, j, n_fell, control=0):
        rows.extend((m, az, j, k < n_fell, control, False) for k in range(2))

    first_fall = {(0, 0): 1.0, (1, 0): 1.5, (2, 0): 2.0, (3, 0): 9.0,
                  (0, 90): 1.5, (1, 90): 1.5, (2, 90): 0.5}
    for (m, az), f in first_fall.items():
        for j in J:
            if (m, az) == (1, 90) and j == 1.0:
                continue
            cell(m, az, j, 0 if j < f else (1 if (m, az) == (0, 0) else 2))
    cell(3, 90, 0.5, 0)
    cell(3, 90, 1.0, 2)
    for m in range(4):   # control on: everything survives (its own band; must not leak)
        for az in (0, 90):
            for j in J:
                cell(m, az, j, 0, control=1)
    rows.append((0, 0, 0.5, True, 0, True))        # diverged: left out
    cols = list(zip(*rows))
    return dict(robot_id=np.array(cols[0]), azimuth_deg=np.array(cols[1], float),
                impulse_ns=np.array(cols[2]), fell=np.array(cols[3]),
                control=np.array(cols[4], bool), diverged=np.array(cols[5]))


def test_member_boundaries_and_their_band_by_hand():
    b = maps.member_boundaries(_synthetic(), control=False)
    np.testing.assert_array_equal(b["azimuth_deg"], [0, 90])
    np.testing.assert_array_equal(b["members"], [0, 1, 2, 3])
    np.testing.assert_array_equal(b["boundary"], [[0.5, 1.0], [1.0, 0.5], [1.5, 0.0],
                                                  [2.0, np.nan]])
    np.testing.assert_array_equal(b["pushes"], [[8, 8], [8, 6], [8, 8], [8, 4]])
    np.testing.assert_array_equal(b["n_members"], [4, 3])
    # np.quantile (linear): azimuth 0 over [0.5, 1, 1.5, 2]: position 0.1 * 3 = 0.3 -> 0.65,
    # median 1.25, position 2.7 -> 1.85; azimuth 90 over [0, 0.5, 1]: 0.1, 0.5, 0.9.
    np.testing.assert_allclose(b["q10"], [0.65, 0.1])
    np.testing.assert_allclose(b["median"], [1.25, 0.5])
    np.testing.assert_allclose(b["q90"], [1.85, 0.9])
    on = maps.member_boundaries(_synthetic(), control=True)
    np.testing.assert_allclose(on["median"], [2.0, 2.0])
    # Too few members with a boundary at an azimuth: no band there
    few = maps.member_boundaries(_synthetic(), control=False, min_members=4)
    assert np.isfinite(few["median"][0]) and np.isnan(few["median"][1])


def test_map_of_an_ensemble_sweep_draws_and_writes_the_band(tmp_path):
    """make_maps on a sweep folder of synthetic records: the band's files and summary section
    (and a sweep without robot_id gets none)."""
    from tkujax.sweeps import chunks

    rec = _synthetic()
    keep = ~rec.pop("diverged")
    rec = {k: v[keep] for k, v in rec.items()}
    n = len(rec["fell"])
    rec |= dict(height_m=np.full(n, 0.36), onset_s=np.full(n, 0.5), duration_s=np.full(n, 0.02),
                onset_phase=np.zeros(n), push_id=np.arange(n), from_grid=np.ones(n, bool),
                diverged=np.zeros(n, bool),
                **{k: np.zeros(n) for k in ("recovery_time_s", "step_length_m", "step_width_m",
                                            "peak_incl_deg", "capture_point_m",
                                            "capture_point_y_m", "zmp_excursion_m")})
    for name, cols in (("ens", rec), ("plain", {k: v for k, v in rec.items()
                                                if k != "robot_id"})):
        out = tmp_path / name
        out.mkdir()
        spec = _spec(tmp_path / "moved_away.json")     # maps do not read the ensemble file
        chunks.update_manifest(out, lambda m, d={"name": name, "spec": spec, "n_pushes": n,
                                                 "complete": True}: m | d)
        chunks.write_chunk(out, 0, cols)
        result = maps.make_maps(out)
        summary = Path(result["summary"]).read_text()
        if name == "ens":
            assert "## Fall boundary across the ensemble (4 robots)" in summary
            assert "| 0 | 1.25 [0.65, 1.85] (4) | 2.00 [2.00, 2.00] (4) |" in summary
            doc = json.loads((out / "maps" / "boundary_by_member.json").read_text())
            assert doc["controls"][0]["members"][3]["boundary_ns"] == [2.0, None]
            csv = (out / "maps" / "boundary_by_member.csv").read_text().splitlines()
            assert csv[0] == "control,robot_id,azimuth_deg,pushes,boundary_ns"
            assert "control off,3,90,4," in csv
            assert str(out / "maps" / "boundary_by_member.csv") in result["files"]
        else:
            assert "ensemble" not in summary
            assert not (out / "maps" / "boundary_by_member.json").exists()
