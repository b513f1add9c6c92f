"""A set of robots in one program (tkujax.sim.robots) and the batched MJX calibration built on it
(tkujax.studies.calibrate.evaluate_mjx), against independent references: each robot's own
MuJoCo-compiled MJX model, and the MuJoCo C backend on the paper's rows."""

import jax
import numpy as np
import pytest

from tkujax.model import load_model
from tkujax.model.ensemble import load_ensemble, save_ensemble
from tkujax.sim import robots as R
from tkujax.sim.mjx_import import mjx
from tkujax.studies.calibrate import paper_rows as E
from tkujax.studies.calibrate import evaluate_mjx as M
from tkujax.studies.calibrate import fit_vector as P

READING = "deviation/latched"


def _x(**changes) -> dict:
    x = P.as_dict(P.base_vector())
    x.update(changes)
    return x


CANDIDATES = [_x(), _x(foot_length_m=0.13, leg_kp=18.0, chest_com_frac=0.7, leg_mass_kg=1.0)]


def test_each_robot_is_its_own_compiled_model():
    """model_of / state_of rebuild robot k's MJX model and settled stand exactly as MuJoCo
    compiles and settles it alone (every field, derived ones included)."""
    mps = [P.model_params(x) for x in CANDIDATES]
    rs = R.robot_set(mps)
    mv, sv = rs.values()
    for k, mp in enumerate(mps):
        host = load_model(mp)
        ref_m = jax.tree_util.tree_leaves(mjx.put_model(host))
        got_m = jax.tree_util.tree_leaves(R.model_of(rs, mv, k))
        assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(got_m, ref_m))
        from tkujax.sim import physics
        ref_s = jax.tree_util.tree_leaves(mjx.put_data(host, physics.settled_stand_data(host)))
        got_s = jax.tree_util.tree_leaves(R.state_of(rs, sv, k))
        assert all(np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(got_s, ref_s))
    assert len(rs.model_leaf_ids) > 0 and rs.n == 2


def test_a_field_outside_the_program_is_refused():
    mps = [P.model_params(x) for x in CANDIDATES]
    with pytest.raises(ValueError, match="vary that the program does not vary: .*body_mass"):
        R.robot_set(mps, model_leaf_ids=(), state_leaf_ids=None)


@pytest.fixture(scope="module")
def batched():
    samples = (E.Sample(0.0), E.Sample(10.0, 25.0))
    res = M.evaluate_many(CANDIDATES + [_x(foot_length_m=-0.1)], (READING,), samples,
                          robots_per_call=2)
    return samples, res


def test_mjx_generation_matches_mujoco_c(batched):
    """The paper's 8 rows of two robots at two (phase, contact) samples: MJX in one batch against
    MuJoCo C one robot at a time. Fall outcomes equal; steps within 3 mm (float32 vs 64)."""
    samples, res = batched
    for x, r in zip(CANDIDATES, res):
        ref = E.evaluate_phases(x, (READING,), samples)
        for s in samples:
            for key, row in ref[s][READING].items():
                got = r[s][READING][key]
                assert got["fell"] == row["fell"], (s, key)
                assert abs(got["step_cm"] - row["step_cm"]) < 0.3, (s, key)
                assert abs(got["stand_deg"] - row["stand_deg"]) < 0.05


def test_a_refused_candidate_is_an_error_in_its_place(batched):
    _, res = batched
    assert isinstance(res[2], ValueError) and "foot_length_m" in str(res[2])


def test_ensemble_file_round_trip_and_errors(tmp_path):
    mps = [P.model_params(x) for x in CANDIDATES]
    path = save_ensemble(tmp_path / "e.json", [dict(model_params=m, loss=1.0) for m in mps], 1,
                         tolerance=0.5)
    ens = load_ensemble(path)
    assert ens.members == tuple(mps) and ens.default_member == 1
    bad = tmp_path / "bad.json"
    bad.write_text('{"version": 1, "members": [{"model_params": {"foot_length_m": "x"}}]}')
    with pytest.raises(ValueError, match=r"members\[0\].model_params: foot_length_m"):
        load_ensemble(bad)
    with pytest.raises(ValueError, match="does not exist"):
        load_ensemble(tmp_path / "none.json")
