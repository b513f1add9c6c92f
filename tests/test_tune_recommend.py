"""`tkujax tune` never recommends a worse set: the rule
(tkujax.studies.tune.held_out_gate.recommend)
on hand-made evaluations, and run_tune end to end with the search and the evaluation stubbed
(no rollout is compiled)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tkujax.sweeps.sweep import load_params_json
from tkujax.studies.tune.held_out_gate import RULE, recommend


def _ev(fell, loss, diverged=None):
    fell, loss = np.asarray(fell, bool), np.asarray(loss, float)
    div = np.zeros(loss.size, bool) if diverged is None else np.asarray(diverged, bool)
    return dict(heldout_fall_rate=float(fell[~div].mean()), heldout_fell=fell[~div].tolist(),
                heldout_push_loss=loss.tolist(), heldout_push_diverged=div.tolist())


def test_keeps_the_start_when_the_tuned_set_falls_as_often_or_more():
    before = _ev([1, 0, 0, 0], [5.0, 1.0, 1.0, 1.0])
    after = _ev([1, 1, 0, 0], [5.0, 5.0, 0.5, 0.5])            # 50 % vs 25 %
    d = recommend({"before": before, "after": after})
    assert d["recommended"] == "before" and d["verified"]
    assert "not below" in d["reason"] and "25.0 %" in d["reason"]
    same = recommend({"before": before, "after": _ev([0, 1, 0, 0], [1.0, 5.0, 0.1, 0.1])})
    assert same["recommended"] == "before"                       # equal fall rate: not better


def test_keeps_the_start_when_the_loss_is_worse_beyond_one_standard_error():
    before = _ev([1, 1, 0, 0], [1.0, 1.0, 1.0, 1.0])
    # One fall fewer, but the loss rises on every push: paired d = (1, 1.2, 0.8, 1),
    # mean 1.0, s.e. = std(d, ddof=1) / 2 = 0.0816..., so mean > s.e.
    after = _ev([1, 0, 0, 0], [2.0, 2.2, 1.8, 2.0])
    d = recommend({"before": before, "after": after})
    assert d["recommended"] == "before"
    assert d["loss_diff"] == pytest.approx(1.0)
    assert d["loss_diff_se"] == pytest.approx(np.std([1, 1.2, 0.8, 1], ddof=1) / 2)
    assert "loss is worse" in d["reason"]


def test_recommends_the_tuned_set_when_better():
    before = _ev([1, 1, 0, 0], [5.0, 5.0, 1.0, 1.0])
    # d = (0, -4, 0.1, 0.3): mean -0.9 <= its s.e.
    after = _ev([1, 0, 0, 0], [5.0, 1.0, 1.1, 1.3])
    d = recommend({"before": before, "after": after})
    assert d["recommended"] == "after" and d["verified"]
    assert d["loss_diff"] == pytest.approx(-0.9) and d["n_paired"] == 4
    # A slightly worse loss within one standard error still passes: d = (0.2, -0.1, 0.2, -0.1)
    # mean 0.05, s.e. 0.0866.
    after2 = _ev([1, 0, 0, 0], [5.2, 4.9, 1.2, 0.9])
    assert recommend({"before": before, "after": after2})["recommended"] == "after"
    # Pushes that diverged in either set leave the paired loss difference.
    after3 = _ev([1, 0, 0, 0, 0], [5.0, 1.0, 1.1, 1.3, 99.0], diverged=[0, 0, 0, 0, 1])
    before3 = _ev([1, 1, 0, 0, 0], [5.0, 5.0, 1.0, 1.0, 0.0])
    d3 = recommend({"before": before3, "after": after3})
    assert d3["n_paired"] == 4 and d3["loss_diff"] == pytest.approx(-0.9)


def test_without_an_evaluation_the_tuned_set_is_flagged_unchecked():
    d = recommend({})
    assert d["recommended"] == "after" and not d["verified"] and "UNCHECKED" in d["reason"]


@pytest.mark.parametrize("better", [False, True])
def test_run_tune_writes_the_recommendation(tmp_path, monkeypatch, capsys, better):
    """The search and the evaluation stubbed: params_after.json is the starting set (with
    recommended_from = start) when the tuned set is not better, the tuned set otherwise; the
    summary and the CLI's stdout say which."""
    from tkujax import cli
    from tkujax.studies.tune import tune_command as run_mod

    def fake_search(method, problem, z0, train, keys, cfg, seed, log):
        z = np.asarray(z0) + 1.0                          # "tuned": a different set
        return dict(method=method, seed=seed, z_best=z.tolist(), best_loss=1.0, compile_s=0.0,
                    iterations=1, curve=[dict(wall_s=0.0, pushes=4, best_loss=2.0),
                                         dict(wall_s=1.0, pushes=8, best_loss=1.0)], extra={})

    def fake_evaluate(problem, latents, heldout, grid, batch, seed):
        worse = dict(before=_ev([1, 0, 0, 0], [5, 1, 1, 1]), after=_ev([1, 1, 0, 0], [5, 5, 1, 1]))
        good = dict(before=_ev([1, 1, 0, 0], [5, 5, 1, 1]), after=_ev([1, 0, 0, 0], [5, 1, 1, 1]))
        return good if better else worse

    monkeypatch.setattr(run_mod, "run_search", fake_search)
    monkeypatch.setattr(run_mod, "evaluate", fake_evaluate)
    spec = tmp_path / "spec.toml"
    spec.write_text('[tune]\nname = "stub"\nbatch = 4\niterations = 1\nduration_s = 1.0\n'
                    'popsize = 3\n[push]\nimpulse_ns = {uniform = [0.2, 1.0]}\n'
                    'azimuth_deg = [0, 180]\n[evaluate]\nn = 4\nimpulse_ns = [0.5, 1.0]\n'
                    'azimuth_deg = [0, 180]\n')
    out = tmp_path / "out"
    assert cli.main(["tune", str(spec), "--out", str(out), "--no-compare"]) == 0
    stdout = capsys.readouterr().out
    after = json.loads((out / "params_after.json").read_text())
    before = json.loads((out / "params_before.json").read_text())
    tuned = json.loads((out / "params_tuned.json").read_text())
    assert tuned["step_period"] != before["step_period"]
    summary = (out / "summary.md").read_text()
    if better:
        assert after.pop("recommended_from") == "tuned" and after == tuned
        assert "recommended the tuned set" in stdout and "Recommended the tuned set" in summary
    else:
        assert after.pop("recommended_from") == "start" and after == before
        assert "kept the starting set" in stdout and "Kept the starting set" in summary
        assert "params_tuned.json" in summary
    # The note does not stop `tkujax sweep --params` from reading the file.
    p = load_params_json(out / "params_after.json")
    assert p.step_period == pytest.approx((tuned if better else before)["step_period"])
    assert json.loads((out / "history.json").read_text())["recommendation"]["recommended"] == (
        "after" if better else "before")
    assert RULE in summary


def test_direction_harm_is_reported_not_vetoed():
    from tkujax.studies.tune.held_out_gate import harmed_directions

    # Sectors: 0 = behind, 2 = front; 4 pushes each. Behind: 3 -> 1 falls; front: 0 -> 1.
    sector = np.array([0, 0, 0, 0, 2, 2, 2, 2])
    before = _ev([1, 1, 1, 0, 0, 0, 0, 0], [5, 5, 5, 1, 1, 1, 1, 1])
    after = _ev([1, 0, 0, 0, 1, 0, 0, 0], [5, 1, 1, 1, 5, 1, 1, 1])
    evals = {"before": before, "after": after}
    harmed = harmed_directions(evals, sector, ("behind", "right", "front", "left"))
    assert harmed == [dict(direction="front", before=0.0, after=0.25, n=4)]
    d = recommend(evals, harmed)
    assert d["recommended"] == "after" and "WARNING" in d["reason"] and "from front" in d["reason"]
    assert d["harmed_directions"] == harmed
