"""Tuning over the robot ensemble and the "harm nowhere" weight: the spec keys
([randomize] ensemble, [evaluate.shift] ensemble, tune.loss.w_harm), the robot_id draw (last,
so specs without an ensemble draw exactly the pushes they drew before), the harm-weighted mean
by hand, and one MJX check: a TuneProblem on a 2-member ensemble gives each push the loss terms
of a TuneProblem built on its robot alone (an independent reference), and its loss is the
harm-weighted mean of those terms with the control-off column.

The MJX part compiles 4 forward programs (the ensemble problem's loss and its control-off pass,
two single-robot references): a few minutes on a 2-core CPU, once per module.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np
import pytest

from tkujax.model import ModelParams
from tkujax.model.ensemble import save_ensemble
from tkujax.studies.calibrate import fit_vector as P
from tkujax.dialects.sweep_spec import SpecError
from tkujax.studies.tune.loss import OFF_SURVIVED, LossConfig, harm_weighted_mean
from tkujax.studies.tune.problem import RECORD_KEYS, TuneProblem
from tkujax.studies.tune.tune_spec import (ensembles_record, grid_pushes, make_problem,
                                           parse_tune_spec, robot_table, sample_pushes, shifted)

ROOT = Path(__file__).resolve().parents[1]
DURATION = 0.5


def _members(n: int = 2) -> list[ModelParams]:
    """Member 0: the default robot; member 1: short feet, soft legs, CoM high in the chest."""
    x = P.as_dict(P.base_vector())
    x.update(foot_length_m=0.11, leg_kp=10.0, chest_com_frac=0.75)
    mps = [ModelParams(), P.model_params(x)]
    return [mps[k % 2] for k in range(n)]


def _ensemble(path: Path, n: int = 2) -> Path:
    return save_ensemble(path, [dict(model_params=m, loss=0.0) for m in _members(n)], 0,
                         tolerance=0.1)


def _spec(**tables) -> dict:
    data = {"tune": {"batch": 4, "duration_s": DURATION, "remat": False,
                     "params": ["step_period", "cp_gain"]},
            "push": {"impulse_ns": {"uniform": [0.2, 2.8]}, "azimuth_deg": {"uniform": [0, 360]},
                     "height_m": {"uniform": [0.3, 0.42]}, "onset_s": {"uniform": [0.1, 0.2]},
                     "duration_s": {"uniform": [0.01, 0.04]}, "azimuth_jitter_deg": 5.0},
            "randomize": {"link_mass_scale": {"uniform": [0.95, 1.05]},
                          "servo_kp_scale": {"uniform": [0.9, 1.1]}, "gyro_noise_std": 0.005}}
    for name, table in tables.items():
        if name == "shift":
            data.setdefault("evaluate", {})["shift"] = table
        else:
            data[name] = data.get(name, {}) | table
    return data


# sample_pushes(parse_tune_spec(_spec()), 3, 7) as drawn by the code before ensembles came in
# (commit d84769f): a spec without an ensemble must keep drawing exactly these.
BEFORE = {
    "impulse_ns": [1.825248213172134, 2.5327558825208962, 2.216782794637503],
    "azimuth_deg": [81.609561917358, 113.01486540238508, 317.40585953479183],
    "height_m": [0.30063183654786896, 0.39854741020593193, 0.3956483314502455],
    "duration_s": [0.01764608762962374, 0.0233522891764794, 0.0251364477687386],
    "onset_s": [0.14679349528437208, 0.13030324268193136, 0.12784256121007734],
    "link_mass_scale": [1.0122179229441164, 1.0488960147681885, 0.9715308698235599],
    "torso_com_offset_x_m": [0.0, 0.0, 0.0],
    "floor_friction": [-1.0, -1.0, -1.0],
    "servo_kp_scale": [0.9320424067715689, 1.0225079208546062, 0.9087884015922767],
    "gyro_noise_std": [0.005, 0.005, 0.005],
    "accel_noise_std": [0.0, 0.0, 0.0],
}


# --- Spec keys ---

def test_ensemble_keys_parse_and_lay_out_the_robot_table(tmp_path):
    two, three = _ensemble(tmp_path / "two.json"), _ensemble(tmp_path / "three.json", 3)
    spec = parse_tune_spec(_spec(randomize={"ensemble": str(two)},
                                 shift={"ensemble": str(three),
                                        "servo_kp_scale": {"uniform": [0.85, 1.15]}}))
    assert spec.ensemble.n == 2 and spec.shift["ensemble"].n == 3
    assert spec.loss.w_harm == 0.0                       # the default
    # Rows: 0 the default robot, 1-2 the training members, 3-5 the shift's members.
    table = robot_table(spec)
    assert len(table) == 6 and table[0] == ModelParams() and table[2] == _members()[1]
    ids = sample_pushes(spec, 200, 0)["robot_id"]
    assert set(ids) == {1.0, 2.0}
    sh = shifted(spec)
    assert set(sample_pushes(sh, 200, 0)["robot_id"]) == {3.0, 4.0, 5.0}
    assert robot_table(sh) == table                      # one table, one program
    np.testing.assert_array_equal(grid_pushes(spec)["robot_id"], 0.0)   # the default robot
    rec = ensembles_record(spec)
    assert rec["randomize.ensemble"]["first_row"] == 1
    assert rec["evaluate.shift.ensemble"]["first_row"] == 3
    assert rec["randomize.ensemble"]["sha256"] == spec.ensemble.sha256
    # The same file in both places is one block of rows.
    same = parse_tune_spec(_spec(randomize={"ensemble": str(two)}, shift={"ensemble": str(two)}))
    assert len(robot_table(same)) == 3
    assert set(sample_pushes(shifted(same), 50, 1)["robot_id"]) == {1.0, 2.0}
    # A shift without its own ensemble runs on the default robot (it replaces [randomize]).
    own = parse_tune_spec(_spec(randomize={"ensemble": str(two)}, shift={}))
    np.testing.assert_array_equal(sample_pushes(shifted(own), 20, 2)["robot_id"], 0.0)
    # w_harm is a [tune.loss] key
    assert parse_tune_spec(_spec(tune={"loss": {"w_harm": 2.0}})).loss.w_harm == 2.0


@pytest.mark.parametrize("where", ["randomize", "shift"])
def test_bad_ensemble_values_name_the_key(tmp_path, where):
    key = "randomize.ensemble" if where == "randomize" else "evaluate.shift.ensemble"
    with pytest.raises(SpecError, match=rf"{key}: ensemble file .*none.json does not exist"):
        parse_tune_spec(_spec(**{where: {"ensemble": str(tmp_path / "none.json")}}))
    with pytest.raises(SpecError, match=rf"{key}: expected the path of an ensemble file .*got 3"):
        parse_tune_spec(_spec(**{where: {"ensemble": 3}}))
    bad = tmp_path / "bad.json"
    bad.write_text('{"version": 1, "members": []}')
    with pytest.raises(SpecError, match=rf"{key}: .*'members' must be a non-empty list"):
        parse_tune_spec(_spec(**{where: {"ensemble": str(bad)}}))


def test_other_bad_values_name_the_key(tmp_path):
    two = _ensemble(tmp_path / "two.json")
    with pytest.raises(SpecError, match=r"tune.float64: an ensemble .* runs in float32"):
        parse_tune_spec(_spec(tune={"float64": True}, shift={"ensemble": str(two)}))
    with pytest.raises(SpecError, match=r"tune.loss.w_harm: -1 is out of range \[0.0, 1000.0\]"):
        parse_tune_spec(_spec(tune={"loss": {"w_harm": -1}}))
    with pytest.raises(SpecError, match=r"tune.loss.w_harm: expected a number"):
        parse_tune_spec(_spec(tune={"loss": {"w_harm": "high"}}))


def test_without_an_ensemble_the_pushes_are_drawn_as_before(tmp_path):
    spec = parse_tune_spec(_spec())
    got = sample_pushes(spec, 3, 7)
    assert list(got) == list(RECORD_KEYS) and "robot_id" not in got
    for k, v in BEFORE.items():
        np.testing.assert_array_equal(got[k], v, err_msg=k)
    assert "robot_id" not in grid_pushes(spec)
    # With an ensemble the member is drawn last: every other column is unchanged.
    two = _ensemble(tmp_path / "two.json")
    with_ens = sample_pushes(parse_tune_spec(_spec(randomize={"ensemble": str(two)})), 3, 7)
    for k, v in BEFORE.items():
        np.testing.assert_array_equal(with_ens[k], v, err_msg=k)
    # With only a shifted ensemble the training pushes run on the default robot (row 0).
    shift_only = sample_pushes(parse_tune_spec(_spec(shift={"ensemble": str(two)})), 3, 7)
    np.testing.assert_array_equal(shift_only["robot_id"], 0.0)
    for k, v in BEFORE.items():
        np.testing.assert_array_equal(shift_only[k], v, err_msg=k)


# --- The harm weight, by hand ---

def test_harm_weighted_mean_by_hand():
    terms = np.array([0.5, 2.0, 10.0, 1.0, np.nan])
    kept = np.array([True, True, True, True, False])        # the last push diverged
    off = np.array([1.0, 0.0, 0.0, 1.0, 1.0])
    # (1 + 2) * 0.5 + 2.0 + 10.0 + (1 + 2) * 1.0, over 4 kept pushes
    assert float(harm_weighted_mean(terms, kept, off, 2.0)) == pytest.approx(16.5 / 4)
    # w_harm = 0 or no column: the plain mean over the kept pushes
    assert float(harm_weighted_mean(terms, kept, off, 0.0)) == pytest.approx(13.5 / 4)
    assert float(harm_weighted_mean(terms, kept)) == pytest.approx(13.5 / 4)
    # nothing kept: 0, not a division by zero
    assert float(harm_weighted_mean(terms, np.zeros(5, bool), off, 2.0)) == 0.0


def test_the_shipped_spec_parses(monkeypatch):
    """specs/tune/tune_recovery_ensemble.toml: the committed 39-member ensemble, w_harm = 2, its
    start the recommendation it improved on (results/tune_recovery's third run), strictly
    inside the tuning ranges."""
    from tkujax.studies.tune import load_tune_spec

    monkeypatch.chdir(ROOT)
    spec = load_tune_spec(ROOT / "specs" / "tune" / "tune_recovery_ensemble.toml")
    assert spec.ensemble.n == 39 and spec.loss.w_harm == 2.0 and spec.popsize == 15
    assert spec.push["impulse_ns"] == (0.2, 2.8)
    assert spec.shift is not None and "ensemble" not in spec.shift
    start = spec.base_params()
    before = json.loads((ROOT / "results" / "tune_recovery" / "params_after.json").read_text())
    for f in spec.reparam().fields:
        assert getattr(start, f) == pytest.approx(before[f], rel=1e-12), f
    ids = sample_pushes(spec, spec.batch, spec.seed)["robot_id"]
    assert ids.min() >= 1 and ids.max() <= 39 and len(np.unique(ids)) > 30


# --- MJX: each push on its own robot; the harm weight in the compiled loss ---

@pytest.fixture(scope="module")
def ens(tmp_path_factory):
    path = _ensemble(tmp_path_factory.mktemp("ens") / "two.json")
    spec = parse_tune_spec(_spec(randomize={"ensemble": str(path)},
                                 tune={"loss": {"w_harm": 2.0}}))
    problem = make_problem(spec)
    # 4 pushes: rows 0 (the default robot), 1 (member 0, the default robot's numbers read back
    # from the file) and 2 (member 1) twice; gentle and hard pushes from behind and in front,
    # the push's own randomisation on top of its robot.
    rec = {k: np.asarray(v, float) for k, v in dict(
        impulse_ns=[0.4, 2.6, 0.4, 2.6], azimuth_deg=[0.0, 180.0, 180.0, 0.0],
        height_m=[0.36] * 4, duration_s=[0.02] * 4, onset_s=[0.1] * 4,
        link_mass_scale=[1.0, 1.03, 0.97, 1.0], torso_com_offset_x_m=[0.0, 0.0, 0.005, 0.0],
        floor_friction=[-1.0] * 4, servo_kp_scale=[1.0, 0.95, 1.05, 1.0],
        gyro_noise_std=[0.0] * 4, accel_noise_std=[0.0] * 4, robot_id=[0, 1, 2, 2]).items()}
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    z0 = problem.reparam.latent_of(spec.base_params())
    rec = problem.with_off_survived(rec, keys)
    loss, aux = problem.forward(z0, 0.0, rec, keys)
    return spec, problem, rec, keys, z0, loss, aux


@pytest.mark.slow
def test_each_push_runs_on_its_robot(ens):
    """Per-push loss terms and outcomes of the ensemble problem against a TuneProblem on the
    push's robot alone (its own MuJoCo compile, no RobotSet), with the same randomisation."""
    spec, problem, rec, keys, z0, _, aux = ens
    assert problem.robots.n == 3 and spec.ensemble.members[0] == ModelParams()
    rid = rec["robot_id"].astype(int)
    ref_auxes = {}
    for member in (0, 1):
        ref = TuneProblem(problem.reparam, spec.base_params(), LossConfig(), DURATION,
                          remat=False, model_params=spec.ensemble.members[member])
        assert ref.input_keys == RECORD_KEYS          # the single-robot program
        _, ref_aux = ref_auxes[member] = ref.forward(z0, 0.0, rec, keys)
        rows = np.flatnonzero(rid <= 1) if member == 0 else np.flatnonzero(rid == 2)
        for k in ("total", "fall", "recovery", "step", "margin_m"):
            np.testing.assert_allclose(aux["terms"][k][rows], ref_aux["terms"][k][rows],
                                       rtol=2e-4, atol=2e-5, err_msg=f"member {member}: {k}")
        for k in ("fell", "diverged"):
            np.testing.assert_array_equal(aux["outcomes"][k][rows], ref_aux["outcomes"][k][rows])
    # The robot matters: member 1 answers the same push differently.
    other = ref_auxes[1][1]
    assert abs(other["terms"]["recovery"][0] - aux["terms"]["recovery"][0]) > 1e-3


@pytest.mark.slow
def test_the_loss_is_the_harm_weighted_mean(ens):
    spec, problem, rec, keys, z0, loss, aux = ens
    off = rec[OFF_SURVIVED]
    assert set(np.unique(off)) <= {0.0, 1.0}
    total, kept = aux["terms"]["total"], ~aux["outcomes"]["diverged"].astype(bool)
    by_hand = np.sum(np.where(kept, (1.0 + 2.0 * off) * total, 0.0)) / max(kept.sum(), 1)
    assert float(loss) == pytest.approx(by_hand, rel=1e-5)
    np.testing.assert_allclose(aux["terms"]["weighted"], (1.0 + 2.0 * off) * total, rtol=1e-6)
    # The control-off column is the control-off outcome, and the gentle pushes survive it.
    again = problem.control_off(rec, keys)
    np.testing.assert_array_equal(off, (~again["fell"] & ~again["diverged"]).astype(float))
    assert off[0] == 1.0 and off[2] == 1.0
    # A batch without the column gets it computed (the same loss).
    plain = {k: v for k, v in rec.items() if k != OFF_SURVIVED}
    assert float(problem.forward(z0, 0.0, plain, keys)[0]) == pytest.approx(float(loss))
    # Without w_harm the problem reads no such column (the program of today).
    no_harm = dataclasses.replace(spec, loss=LossConfig())
    assert OFF_SURVIVED not in make_problem(no_harm).input_keys
