"""`tkujax calibrate`: spec validation, the parameter vector, the resumable search and its files.

The search tests use a cheap stand-in evaluator (rows computed from the candidate's distance to a
target point, scored by the real loss and report code) so that they run in seconds; one smoke
test runs the real MuJoCo evaluation on a single candidate."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from tkujax.model import ModelParams
from tkujax.model.params_json import load_model_params_json, model_params_from_dict
from tkujax.studies.calibrate import paper_rows as E
from tkujax.studies.calibrate import fit_vector as P
from tkujax.studies.calibrate import targets as T
from tkujax.studies.calibrate.calibrate_command import run_calibrate
from tkujax.studies.calibrate.calibrate_spec import parse_calibrate_spec
from tkujax.dialects.sweep_spec import SpecError

SEARCH = {"max_evals": 10, "popsize": 4, "restarts": 1, "seed": 3}


def _spec(fit=None, search=None, report=None):
    data = {"fit": fit or {}, "search": {**SEARCH, **(search or {})}}
    if report is not None:
        data["report"] = report
    return parse_calibrate_spec(data)


# ----------------------------------------------------------------------------- spec


@pytest.mark.parametrize("data,match", [
    ({"fit": {"paramz": []}, "search": SEARCH}, r"\[fit\]: unknown key\(s\) \['paramz'\]"),
    ({"fit": {}, "search": SEARCH, "extra": {}}, r"top level.*unknown key\(s\) \['extra'\]"),
    ({"fit": {"params": ["leg_kp"], "bounds": {"leg_kp": [5.0, 24.0]}}, "search": SEARCH},
     r"fit.bounds.leg_kp: \[5, 24\] widens the physically plausible bound \[8, 32\]"),
    ({"fit": {"params": ["leg_kp"], "bounds": {"leg_kp": [10.0, 40.0]}}, "search": SEARCH},
     r"fit.bounds.leg_kp: .* widens"),
    ({"fit": {"params": ["leg_kp"], "bounds": {"leg_kp": [20.0, 10.0]}}, "search": SEARCH},
     r"fit.bounds.leg_kp: lower bound 20 must be below upper bound 10"),
    ({"fit": {"params": ["leg_kp"], "bounds": {"foot_length_m": [0.12, 0.14]}}, "search": SEARCH},
     r"fit.bounds.foot_length_m: foot_length_m is not fitted"),
    ({"fit": {"readings": ["deviation/wobbly"]}, "search": SEARCH},
     r"fit.readings: .*'deviation/latched'.*not allowed: \['deviation/wobbly'\]"),
    ({"fit": {"params": ["leg_stiffness"]}, "search": SEARCH}, r"fit.params: .*leg_kp"),
    ({"fit": {"rows": "table5"}, "search": SEARCH},
     r"fit.rows: expected one of \['all', 'table4'\]"),
    ({"fit": {"hit_phases_ms": [0, 30]}, "search": SEARCH}, r"fit.hit_phases_ms: .*\[0, 30\) ms"),
    ({"fit": {"hit_phases_ms": [-5]}, "search": SEARCH}, r"fit.hit_phases_ms\[0\]"),
    ({"fit": {"start": {"leg_kp": 50.0}}, "search": SEARCH},
     r"fit.start.leg_kp: 50.0 is out of range"),
    ({"fit": {}, "search": {"popsize": 4}}, r"search: give budget_s .* and/or max_evals"),
    ({"fit": {}, "search": {**SEARCH, "popsize": 1}},
     r"search.popsize: expected an integer in \[2, 4096\]"),
    ({"fit": {}, "search": SEARCH, "report": {"sensitivity": "yes"}}, r"report.sensitivity"),
])
def test_spec_errors_name_the_key(data, match):
    with pytest.raises(SpecError, match=match):
        parse_calibrate_spec(data)


def test_spec_defaults_and_narrowing():
    s = _spec({"params": ["leg_kp", "foot_length_m"], "bounds": {"leg_kp": [12.0, 30.0]},
               "hit_phases_ms": [20, 0, 10]})
    assert s.params == ("foot_length_m", "leg_kp")           # params.NAMES order
    assert s.bounds["leg_kp"] == (12.0, 30.0) and s.bounds["foot_length_m"] == (0.10, 0.16)
    assert s.readings == tuple(P.READINGS) and s.objectives == ("ALL", "T4")
    assert s.hit_phases_ms == (20.0, 0.0, 10.0)
    assert _spec({"rows": "table4"}).objectives == ("T4",)
    assert _spec({"heldout": False}).objectives == ("ALL",)
    np.testing.assert_allclose([s.start[n] for n in P.NAMES], P.base_vector())


def test_shipped_specs_parse():
    from tkujax.studies.calibrate.calibrate_spec import load_calibrate_spec

    cpu, full = load_calibrate_spec("specs/calibrate/calibrate_cpu.toml"), load_calibrate_spec(
        "specs/calibrate/calibrate.toml")
    assert cpu.max_evals is not None and len(full.hit_phases_ms) >= 3
    # every parameter but the front hit's (params.NEUTRAL: named by the fits that move it)
    assert set(full.params) == set(P.NAMES) - set(P.NEUTRAL)


# ----------------------------------------------------------------------------- the vector


def test_vector_round_trip_and_hard_constraints():
    rng = np.random.default_rng(0)
    base = ModelParams()
    for _ in range(20):
        u = rng.uniform(0, 1, len(P.NAMES))
        x = P.from_unit(u)
        np.testing.assert_allclose(P.to_unit(x), u, atol=1e-12)
        assert list(P.as_dict(x)) == list(P.NAMES)
        mp = P.model_params(x)
        parts = (mp.pelvis_mass_kg + mp.chest_mass_kg + mp.head_mass_kg + 2 * mp.arm_mass_kg
                 + 2 * mp.leg_mass_kg)
        assert parts == pytest.approx(4.5, abs=1e-9) and mp.total_mass_kg == 4.5
        assert mp.height_m == pytest.approx(0.5645, abs=1e-9) == base.height_m
        assert mp.pelvis_mass_kg > 0.2 - 1e-9
        # the mapping is what the vector says
        v = P.as_dict(x)
        assert mp.leg_servo.kp_nm_per_rad == v["leg_kp"]
        assert mp.leg_servo.damping_nms_per_rad == v["leg_damping"]
        assert mp.chest_mass_kg / (mp.chest_mass_kg + mp.pelvis_mass_kg) == pytest.approx(
            v["chest_share"])
        cp = P.controller_params(x, "excess/updated", mp)
        assert cp.kalman_q == pytest.approx(10 ** v["kalman_q"]) and cp.cp_excess == 1.0


def test_base_vector_is_the_default_model():
    mp = P.model_params(P.base_vector())
    d = ModelParams()
    for f in ("foot_forward_offset_m", "foot_length_m", "leg_mass_kg", "chest_mass_kg",
              "pelvis_mass_kg", "chest_com_frac"):
        assert getattr(mp, f) == pytest.approx(getattr(d, f))
    assert mp.leg_servo.damping_nms_per_rad == pytest.approx(d.leg_servo.damping_nms_per_rad)


def test_hit_phase_onsets():
    assert E.hit_onset_s(0.0) == pytest.approx(0.75)
    assert E.hit_onset_s(15.0) == pytest.approx(0.765)
    with pytest.raises(ValueError, match="hit_phase_ms"):
        E.hit_onset_s(30.0)
    on = np.asarray(E.pushes_for(P.base_vector(), (0.0, 10.0)).onset_s)
    np.testing.assert_allclose(on, [0.75] * 4 + [0.76] * 4, atol=1e-6)


def test_model_params_json():
    d = json.loads(json.dumps(__import__("dataclasses").asdict(P.model_params(P.DEFAULT))))
    assert model_params_from_dict(d) == P.model_params(P.DEFAULT)
    with pytest.raises(ValueError, match=r"unknown field\(s\) \['foot_size'\]"):
        model_params_from_dict({"foot_size": 0.1})
    with pytest.raises(ValueError, match="leg_servo.kp_nm_per_rad must be a non-negative"):
        model_params_from_dict({"leg_servo": {"kp_nm_per_rad": -1}})
    with pytest.raises(ValueError, match="mass split does not add up"):
        model_params_from_dict({"leg_mass_kg": 1.5})


def test_cli_model_option(tmp_path):
    from tkujax.cli.shared_options import model_params_from_options as model_params_from
    from tkujax.model.params_json import save_model_params_json

    mp = P.model_params(P.from_unit(np.full(len(P.NAMES), 0.3)))
    path = save_model_params_json(mp, tmp_path / "model_params.json")
    assert model_params_from([str(path)]) == mp
    both = model_params_from([str(path), "floor_friction=0.8"])
    assert both.floor_friction == 0.8 and both.leg_servo == mp.leg_servo
    assert model_params_from([]) is None


# ----------------------------------------------------------------------------- the search


TARGET_U = 0.3                        # the stand-in's optimum, in every fitted unit coordinate


def stand_in(calls: list):
    """A cheap evaluator: the paper's rows, recovery times and steps off by the candidate's
    (unit-cube) distance to TARGET_U; every row's fall outcome matches the paper. The real loss
    and report code then score it."""

    def evaluate(x, readings, phases):
        calls.append(dict(x))
        err = sum((P.to_unit(np.array([x[n] for n in P.NAMES]))[i] - TARGET_U) ** 2
                  for i, n in enumerate(P.NAMES) if n in ("leg_kp", "foot_length_m"))
        out = {}
        for ph in phases:
            out[ph] = {}
            for k, rd in enumerate(readings):
                rows = {}
                for key, (rec_p, step_p) in T.PAPER_TABLE.items():
                    fell = rec_p is None
                    sign = 1 if key[0] == "back" else -1
                    rows[key] = dict(
                        fell=fell, rec=math.nan if fell else rec_p * (1 + err + 0.1 * k),
                        step_cm=0.0 if step_p is None else sign * step_p * (1 + err),
                        peak_deg=45.0 if fell else 5.0, phi_peak_deg=1.0, phi_max_deg=13.0,
                        phi_min_deg=-3.0, stand_deg=7.0, x_sup_cm=0.0)
                out[ph][rd] = rows
        return out

    return evaluate


def _fit(**search):
    return _spec({"params": ["foot_length_m", "leg_kp", "chest_share"],
                  "readings": ["deviation/latched", "excess/updated"], "hit_phases_ms": [0, 20]},
                 search, report={"sensitivity": True})


def test_search_improves_and_writes_files(tmp_path):
    """Stand-in evaluator (see stand_in): the search must beat its start and write every file."""
    calls = []
    spec = _fit(max_evals=30)
    summary = run_calibrate(spec, tmp_path, evaluator=stand_in(calls), quiet=True)
    for f in ("archive.jsonl", "best.json", "calibration.md", "search_trace.png",
              "model_params.json", "controller_params.json", "spec.json"):
        assert (tmp_path / f).stat().st_size > 0, f
    best = json.loads((tmp_path / "best.json").read_text())
    assert best["n_candidates"] == 30 and best["search"]["stopped_by"] == "max_evals"
    assert summary["ALL"]["x"] == best["ALL"]["x"]      # what it returns is what it wrote
    for obj in ("ALL", "T4"):
        assert math.isfinite(best[obj]["loss"])
        assert best[obj]["loss"] < best["start"]["loss"][obj]
        assert best[obj]["reading"] == "deviation/latched"     # the stand-in's better reading
        assert set(best[obj]["fitted"]) == {"foot_length_m", "leg_kp", "chest_share"}
        assert set(best[obj]["rows"]) == {"0", "20"}
    assert "heldout_T5" in best["T4"] and len(best["sensitivity"]) == 3
    # held parameters stay at the start, fitted ones within their bounds
    x = best["ALL"]["x"]
    assert x["foot_forward_offset_m"] == spec.start["foot_forward_offset_m"]
    for n in spec.params:
        assert spec.bounds[n][0] <= x[n] <= spec.bounds[n][1]
    assert load_model_params_json(tmp_path / "model_params.json") == P.model_params(x)
    md = (tmp_path / "calibration.md").read_text()
    for heading in ("Fit on all 8 rows", "Table 5 (held out", "Model selection",
                    "Identifiability", "FINDINGS.md"):
        assert heading in md
    # 30 candidates, 2 phases: the evaluator saw each candidate once (plus the sensitivities)
    assert len(calls) == 30 + 1 + 2 * 3


def test_resume_equals_an_uninterrupted_run(tmp_path):
    """Stand-in evaluator. Stopped after 7 candidates (mid-generation), then rerun with a larger
    budget: the archive's candidates are read back, not re-simulated, and the result is the
    uninterrupted run's."""
    straight, calls = tmp_path / "straight", []
    run_calibrate(_fit(max_evals=19), straight, evaluator=stand_in(calls), quiet=True)
    split = tmp_path / "split"
    run_calibrate(_fit(max_evals=7), split, evaluator=stand_in([]), quiet=True)
    # an interruption that cut the last line in half
    text = (split / "archive.jsonl").read_text()
    (split / "archive.jsonl").write_text(text + text.splitlines()[-1][:50])
    calls2 = []
    s2 = run_calibrate(_fit(max_evals=19), split, evaluator=stand_in(calls2), quiet=True)
    assert s2["search"]["archived_before"] == 7
    assert s2["search"]["simulated_this_run"] == 19 - 7
    a = [json.loads(line)["x"] for line in (straight / "archive.jsonl").read_text().splitlines()]
    b = [json.loads(line)["x"] for line in (split / "archive.jsonl").read_text().splitlines()]
    assert a == b
    assert (json.loads((straight / "best.json").read_text())["ALL"]["x"] == s2["ALL"]["x"])


def test_archive_of_another_fit_is_refused(tmp_path):
    run_calibrate(_fit(max_evals=2), tmp_path, evaluator=stand_in([]), quiet=True)
    other = _spec({"params": ["leg_kp"]}, {"max_evals": 2})
    with pytest.raises(SpecError, match="archived by a different fit"):
        run_calibrate(other, tmp_path, evaluator=stand_in([]), quiet=True)


def test_real_evaluation_one_candidate(tmp_path):
    """The MuJoCo C evaluation end to end on one candidate (the start point)."""
    from tkujax.control.params_files import load_controller_params_json as load_params_json

    spec = _spec({"params": ["leg_kp", "foot_length_m"], "readings": ["deviation/updated"],
                  "rows": "table4"}, {"max_evals": 1}, report={"sensitivity": False})
    s = run_calibrate(spec, tmp_path, quiet=True)
    assert s["n_candidates"] == 1 and math.isfinite(s["T4"]["loss"])
    rows = s["T4"]["rows"]["0"]
    assert set(rows) == {"/".join(k) for k in T.ROWS}
    assert all(isinstance(r["fell"], bool) for r in rows.values())
    cp = load_params_json(tmp_path / "controller_params.json")
    assert cp == P.controller_params(s["T4"]["x"], "deviation/updated")


def test_ensemble_default_member_and_islands(tmp_path):
    """Stand-in evaluator: ensemble.json holds distinct candidates within the tolerance of the
    best, its default member is their medoid, and the islands contain the default member."""
    from tkujax.model.ensemble import load_ensemble
    from tkujax.studies.calibrate import ensemble_build as ENS

    spec = _spec({"params": ["foot_length_m", "leg_kp"], "readings": ["deviation/latched"],
                  "hit_phases_ms": [0], "contact_times_ms": [15, 25], "heldout": False},
                 {"max_evals": 24, "popsize": 6},
                 report={"sensitivity": False, "ensemble_tolerance": 0.5, "ensemble_max": 8,
                         "island_points": 7})
    summary = run_calibrate(spec, tmp_path, evaluator=stand_in([]), quiet=True)
    ens = load_ensemble(tmp_path / "ensemble.json")
    members = ens.raw["members"]
    losses = [m["loss"] for m in members]
    assert 2 <= len(members) <= 8 and losses == sorted(losses)
    assert losses[-1] <= losses[0] + 0.5
    assert ens.default_member == ENS.medoid([{"x": m["x"]} for m in members], spec.params,
                                            spec.bounds)
    isl = summary["ensemble"]["islands"]
    for n in spec.params:
        v0 = members[ens.default_member]["x"][n]
        lo, hi = isl[n]["island_loss"]            # the slice goes through the member itself
        assert lo <= v0 <= hi and v0 in isl[n]["values"]
        assert len(isl[n]["values"]) in (7, 8)    # 7 even points, plus v0 when not one of them
    assert (tmp_path / "default_model_params.json").exists()
    assert "@15ms" in (tmp_path / "calibration.md").read_text()


def test_ensemble_spec_errors():
    with pytest.raises(SpecError, match="report.island_points"):
        _spec({}, {"max_evals": 2}, report={"island_points": 10})
    with pytest.raises(SpecError, match=r"fit.contact_times_ms\[0\]"):
        _spec({"contact_times_ms": [1]}, {"max_evals": 2})
    with pytest.raises(SpecError, match="search.backend"):
        _spec({}, {"max_evals": 2, "backend": "gpu"})


def test_criterion_shortfall_by_hand():
    """The acceptance penalty: 0.8 minus the probability of the paper's outcome where
    positive, plus for the stepping rows P(stand and step against the paper's way)."""
    from tkujax.studies.calibrate.calibrate_command import criterion_shortfall

    exp = {"/".join(k): {"p_paper": 1.0} for k in T.ROWS}
    exp["back/volleyball/on"] = {"p_paper": 0.7, "p_step_wrong_way": 0.0}     # 0.1
    exp["front/volleyball/on"] = {"p_paper": 0.9, "p_step_wrong_way": 0.5}    # 0 + 0.45
    exp["front/baseball/on"] = {"p_paper": 0.5}                               # 0.3, no step
    assert math.isclose(criterion_shortfall(exp, T.ROWS), 0.1 + 0.45 + 0.3)
    assert math.isclose(criterion_shortfall(exp, T.TABLE4), 0.1)
    a = _spec({"criterion_weight": 50}, {"max_evals": 2})
    b = _spec({}, {"max_evals": 2})
    assert a.criterion_weight == 50 and a.fit_digest() != b.fit_digest()
    with pytest.raises(SpecError, match="fit.criterion_weight"):
        _spec({"criterion_weight": -1}, {"max_evals": 2})


# ------------------------------------------------------------- the front hit relative to the back


def test_front_hit_parameters_move_only_the_front_pushes():
    """front_height_offset_m and front_impulse_ratio: neutral values give the pushes of one hit
    for both directions (what fits before them simulated); otherwise only the front pushes
    change, by exactly the offset and the ratio."""
    from tkujax.studies.calibrate.paper_rows import CASES, pushes_for

    # The default contact has its own front hit (BallContact); from the neutral one:
    base = dict(P.as_dict(P.base_vector()), **P.NEUTRAL)
    old = dict(base)
    for n in P.NEUTRAL:                    # an x archived before these names existed
        old.pop(n)
    a, b = pushes_for(old, (0.0, 6.0)), pushes_for(base, (0.0, 6.0))
    for f in ("impulse_ns", "height_m", "azimuth_rad", "onset_s", "duration_s"):
        np.testing.assert_array_equal(np.asarray(getattr(a, f)), np.asarray(getattr(b, f)))
    moved = pushes_for(dict(base, front_height_offset_m=0.02, front_impulse_ratio=1.1), (0.0,))
    front = np.array([d == "front" for d, _ in CASES])
    np.testing.assert_allclose(np.asarray(moved.height_m)[front],
                               np.asarray(b.height_m)[:len(CASES)][front] + 0.02, atol=1e-7)
    np.testing.assert_allclose(np.asarray(moved.impulse_ns)[front],
                               np.asarray(b.impulse_ns)[:len(CASES)][front] * 1.1, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(moved.height_m)[~front],
                                  np.asarray(b.height_m)[:len(CASES)][~front])
    np.testing.assert_array_equal(np.asarray(moved.impulse_ns)[~front],
                                  np.asarray(b.impulse_ns)[:len(CASES)][~front])
    # The front contact stays on the chest at the corners of the box.
    top = pushes_for(dict(base, push_height_m=0.43, front_height_offset_m=0.05), (0.0,))
    assert float(np.max(np.asarray(top.height_m)[front])) == pytest.approx(0.435)


def test_fits_that_hold_the_front_hit_keep_their_digest_and_archives(tmp_path):
    """A spec that does not fit the front hit has the digest it had before the names existed
    (the shipped specs' archives resume), and an archived candidate without them reads as
    the neutral values."""
    from tkujax.studies.calibrate.calibrate_spec import parse_calibrate_spec

    data = {"fit": {"params": ["leg_kp"]}, "search": {"max_evals": 1}}
    spec = parse_calibrate_spec(data)
    moved = parse_calibrate_spec({**data, "fit": {"params": ["leg_kp", "front_impulse_ratio"]}})
    assert "front_impulse_ratio" not in spec.params and spec.fit_digest() != moved.fit_digest()
    assert P.complete({"leg_kp": 20.0}) == {"leg_kp": 20.0, **P.NEUTRAL}
    assert P.complete({"front_impulse_ratio": 1.1})["front_impulse_ratio"] == 1.1
