"""Sweeps over an ensemble of robots ([randomize] ensemble, issue 21 item 3): the spec key's
validation, the robot_id draw shared by a push's settings, the MJX sweep against each member run
alone (`tkujax.sim.rollout_mjx.simulate` on its own ModelParams: an independent reference), and
the map's per-member fall boundaries and their band on synthetic records."""

from pathlib import Path

import numpy as np
import pytest

from tkujax.model.ensemble import save_ensemble
from tkujax.studies.calibrate import params as P
from tkujax.studies.spec import SpecError, load_spec, parse_spec
from tkujax.studies.sweep import _spec_hash, choose_backend, record_inputs
from tkujax.control.params import ControllerParams
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
    h = _spec_hash(spec, ControllerParams.paper(), ModelParams())
    assert h == _spec_hash(parse_spec(_spec(path)), ControllerParams.paper(), ModelParams())
    _ensemble(path, n_members=3)                    # same path, other content
    assert h != _spec_hash(parse_spec(_spec(path)), ControllerParams.paper(), ModelParams())
    assert choose_backend("mujoco", spec) == "mujoco"
    assert choose_backend("mjx", spec) == "mjx"


def test_the_cpu_spec_parses(tmp_path, monkeypatch):
    """sweeps/ensemble_cpu.toml, pointed at a 2-member ensemble written here."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results" / "calibration").mkdir(parents=True)
    _ensemble(tmp_path / "results" / "calibration" / "ensemble.json")
    spec = load_spec(ROOT / "sweeps" / "ensemble_cpu.toml")
    assert spec.ensemble.n == 2 and "robot_id" in spec.records()
