"""The dimension study: parameterisations of growing size (tkujax.control.policy,
tkujax.studies.tune.parameterisations), their exact start at the hand-designed controller, the
gradient
with respect to schedule parameters, the [study] spec and its resume logic.

The controller-level checks run the controller alone over a fixed synthetic IMU sequence
(20 periods, no physics: seconds on a CPU). One `slow` test compiles a tiny MJX batch."""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller import Sensors, controller_init, controller_step
from tkujax.control.controller_params import RECOMMENDED, ControllerParams
from tkujax.dialects.sweep_spec import SpecError
from tkujax.studies.tune import Reparam, parse_tune_spec
from tkujax.studies.tune.parameterisations import PolicyReparam, parse_policy
from tkujax.studies.tune.dimension_study import parse_only, plan, run_study, select
from tkujax.dialects.sweep_spec import read_toml

FIELDS = ("step_period", "cp_gain", "cp_trigger_forward_m", "cp_trigger_backward_m",
          "stance_ankle_kp", "stance_hip_kp", "stance_roll_kp", "accel_gate")
RANGES = dict(step_period=(0.1, 0.5), cp_gain=(0.5, 4.0), cp_trigger_backward_m=(0.02, 0.3),
              stance_ankle_kp=(-0.5, 1.0), stance_hip_kp=(-1.0, 1.0),
              stance_roll_kp=(-0.5, 1.0))
SCHEDULE = ("cp_gain", "stance_ankle_kp", "stance_hip_kp", "stance_roll_kp")
POLICIES = ("scalars", "sectors4", "sectors8", "mlp")


def _rep(policy: str) -> PolicyReparam:
    return PolicyReparam.make(Reparam.make(FIELDS, RANGES), policy, SCHEDULE)


def _imu(n=20, seed=0):
    """A forward-and-sideways fall as the IMU would report it, with noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)
    gyro = np.stack([0.8 + 0.3 * np.sin(t), -0.4 + 0.2 * np.cos(t), 0.0 * t], -1)
    gyro = gyro + rng.normal(0, 0.1, (n, 3))
    accel = np.array([0.0, 0.0, 9.81]) + rng.normal(0, 0.5, (n, 3))
    return jnp.asarray(gyro), jnp.asarray(accel)


def _targets(rep: PolicyReparam, base, z, scheduled=True, dtype=jnp.float32):
    """(n, 12) leg targets of the controller alone over the synthetic IMU sequence."""
    gyro, accel = _imu()
    params = rep.apply(base, z)
    schedule = rep.schedule(z) if scheduled else None
    state = controller_init(params, dtype)

    def body(s, x):
        s, out = controller_step(s, Sensors(x[0].astype(dtype), x[1].astype(dtype)), params,
                                 1.0, None, schedule)
        return s, out.leg_targets

    return jax.lax.scan(body, state, (gyro, accel))[1]


def test_parse_policy_names():
    assert parse_policy("scalars") == ("scalars", 0)
    assert parse_policy("sectors3") == ("sectors", 3)
    assert parse_policy("mlp") == ("mlp", 8)
    assert parse_policy("mlp16") == ("mlp", 16)
    assert parse_policy("mlp65") == ("mlp", 65)         # wide MLPs: up to 256 hidden units
    assert parse_policy("mlp256") == ("mlp", 256)
    for bad in ("sectors1", "sectors17", "mlp0", "mlp257", "tables", 4):
        with pytest.raises(ValueError):
            parse_policy(bad)


def test_sizes_and_latent_round_trip():
    base = ControllerParams.recommended()
    k, F = len(FIELDS), len(SCHEDULE)
    expect = {"scalars": k, "sectors4": k + 4 * F, "sectors8": k + 8 * F,
              "mlp": k + 5 * 8 + 9 * F}
    for policy in POLICIES:
        rep = _rep(policy)
        assert rep.size == expect[policy]
        z0 = rep.latent_of(base)
        assert z0.shape == (rep.size,)
        # The scalar part round-trips to the recommended values.
        np.testing.assert_allclose(rep.values_np(z0), [getattr(base, f) for f in FIELDS],
                                   rtol=1e-12, atol=1e-15)
        z = np.random.default_rng(1).normal(size=rep.size).astype(np.float32).astype(float)
        assert rep.describe(z)["latent"] == z.tolist()
        sched = rep.schedule(jnp.asarray(z))
        if policy == "scalars":
            assert sched is None
            continue
        assert sched.fields == SCHEDULE
        np.testing.assert_array_equal(np.asarray(sched.z_base),
                                      z[[FIELDS.index(f) for f in SCHEDULE]])
        if policy.startswith("sectors"):
            np.testing.assert_array_equal(np.asarray(sched.table).ravel(), z[k:])
            # At the start every correction is exactly zero.
            assert not np.any(z0[k:])
        else:
            parts = [sched.w1, sched.b1, sched.w2, sched.b2]
            np.testing.assert_array_equal(np.concatenate([np.ravel(p) for p in parts]), z[k:])
            s0 = rep.schedule(jnp.asarray(z0))
            assert not np.any(np.asarray(s0.w2)) and not np.any(np.asarray(s0.b2))
            assert np.any(np.asarray(s0.w1))                # a live hidden layer


def test_wide_mlp_has_over_a_thousand_parameters():
    """mlp96 on the 16 scalars and 8 scheduled fields of the dimension study (the gradients
    spec's large policy): 16 + 5 x 96 + 97 x 8 = 1,272 parameters, starting with every
    correction exactly 0."""
    from tkujax.dialects.sweep_spec import read_toml
    from tkujax.studies.tune import parse_tune_spec

    spec = parse_tune_spec(read_toml("specs/tune/tune_dimension.toml"))
    rep = spec.policy_reparam("mlp96")
    assert (rep.k, len(rep.schedule_fields), rep.size) == (16, 8, 1272)
    s0 = rep.schedule(jnp.asarray(rep.latent_of(spec.base_params())))
    assert s0.w1.shape == (4, 96) and not np.any(np.asarray(s0.w2))


def test_scheduled_fields_must_be_tuned_and_schedulable():
    with pytest.raises(ValueError, match="must be tuned too"):
        PolicyReparam.make(Reparam.make(FIELDS, RANGES), "sectors4", ("lift_height",))
    with pytest.raises(ValueError, match="cannot schedule 'accel_gate'"):
        PolicyReparam.make(Reparam.make(FIELDS, RANGES), "sectors4", ("accel_gate",))


@pytest.mark.parametrize("policy", POLICIES[1:] + ("mlp96",))
def test_start_reproduces_the_unscheduled_controller(policy):
    """At the start latent the scheduled controller is the plain one: within float32 rounding
    (the two programs fuse differently; measured <= 1 ulp, 7.5e-9 rad), and after a change of
    a schedule parameter it is not."""
    base = ControllerParams.recommended()
    rep = _rep(policy)
    z0 = jnp.asarray(rep.latent_of(base), jnp.float32)
    plain = jax.jit(lambda z: _targets(rep, base, z, scheduled=False))(z0)
    sched = jax.jit(lambda z: _targets(rep, base, z))(z0)
    np.testing.assert_allclose(np.asarray(sched), np.asarray(plain), rtol=0, atol=1e-7)
    j = SCHEDULE.index("stance_ankle_kp")    # sector 0's correction / an MLP output weight
    z1 = z0.at[rep.k + (j if policy.startswith("sectors") else 5 * rep.width + j)].add(2.0)
    moved = jax.jit(lambda z: _targets(rep, base, z))(z1)
    assert float(jnp.max(jnp.abs(moved - plain))) > 1e-4


@pytest.mark.parametrize("policy", ["sectors4", "mlp"])
def test_schedule_gradient_matches_finite_differences(policy):
    """d(sum of weighted leg targets)/d(one schedule parameter): jax.grad against central
    differences (float64, h = 1e-6; tolerance 1e-5 relative) on the controller alone. The
    parameter is an ankle-pitch gain correction (smooth: the stance feedback) in a sector the
    fall points into, or the MLP output weight of that gain."""
    base = ControllerParams.recommended()
    rep = _rep(policy)
    F = len(SCHEDULE)
    j = SCHEDULE.index("stance_ankle_kp")
    i = rep.k + (j if policy == "sectors4" else 5 * rep.width + 2 * F + j)
    w = jnp.linspace(0.5, 1.5, 12)
    with jax.enable_x64(True):
        z0 = jnp.asarray(rep.latent_of(base), jnp.float64)
        if policy == "mlp":
            z0 = z0.at[rep.k + 5 * rep.width:].set(0.05)    # away from the all-zero start

        def f(zi):
            z = z0.at[i].set(zi)
            return jnp.sum(_targets(rep, base, z, dtype=jnp.float64) * w)

        g = float(jax.jit(jax.grad(f))(z0[i]))
        h = 1e-6
        fd = float((jax.jit(f)(z0[i] + h) - jax.jit(f)(z0[i] - h)) / (2 * h))
    assert abs(g) > 1e-6, g
    assert abs(g - fd) <= 1e-5 * abs(fd), (g, fd)


# --- The spec ---------------------------------------------------------------------------------

def _spec_dict() -> dict:
    return read_toml("specs/tune/tune_dimension_cpu.toml")


def test_dimension_specs_parse():
    spec = parse_tune_spec(read_toml("specs/tune/tune_dimension.toml"))
    sizes = [spec.policy_reparam(p).size for p in spec.study["policies"]]
    assert max(sizes) >= 64 and len(set(sizes)) >= 3
    assert set(spec.study["methods"]) == {"cma", "gradient", "hybrid", "es", "linesearch"}
    # The study stays on the robot it started on (no accelerometer low-pass).
    assert spec.model_params().accel_lowpass_hz == 0.0
    assert len(spec.study["seeds"]) >= 3 and spec.study["budget_s"] >= 120
    # It starts at the recommended controller.
    base = spec.base_params()
    for k, v in RECOMMENDED.items():
        assert float(getattr(base, k)) == v, k
    small = parse_tune_spec(_spec_dict())
    assert small.study["budget_s"] <= 5


@pytest.mark.parametrize("patch, match", [
    ({"tune": {"policy": "sectors1"}}, "tune.policy"),
    ({"tune": {"schedule": ["lift_height"]}}, "tune.schedule"),
    ({"tune": {"schedule": ["accel_gate"], "params": ["accel_gate", "cp_gain"]}},
     "tune.schedule"),
    ({"tune": {"sharpness": 0.0}}, "tune.sharpness"),
    ({"tune": {"schedule": []}}, r"tune.schedule: study.policies\[1\] = 'sectors2'"),
    ({"study": {"policies": ["scalars", "mlp0"]}}, r"study.policies\[1\]"),
    ({"study": {"methods": ["cma", "adam"]}}, "study.methods"),
    ({"study": {"seeds": [0, 0]}}, "study.seeds"),
    ({"study": {"groups": 3}}, "study.groups"),
    ({"study": {"popsize": 4}}, "study.popsize"),
    ({"study": {"budget_s": -1.0}}, "study.budget_s"),
    ({"study": {"above_impulse_ns": [3.0, 2.0]}}, "study.above_impulse_ns"),
    ({"study": {"push_clip": -1.0}}, "study.push_clip"),
    ({"study": {"bogus": 1}}, "unknown key"),
])
def test_spec_validation_names_the_key(patch, match):
    data = _spec_dict()
    for table, values in patch.items():
        data[table] = {**data[table], **values}
    with pytest.raises(SpecError, match=match):
        parse_tune_spec(data)


# --- The study's bookkeeping, with a stand-in runner --------------------------------------------

def test_only_filters():
    runs = plan(dict(policies=["scalars", "mlp"], methods=["cma", "es"], seeds=[0, 1]))
    assert len(runs) == 8
    assert select(runs, ["policy=mlp", "seed=1"]) == [("mlp", "cma", 1), ("mlp", "es", 1)]
    assert len(select(runs, ["method=cma,es"])) == 8
    with pytest.raises(ValueError, match="KEY"):
        parse_only(["colour=red"])


class _FakeRunner:
    """Stand-in for the MJX runs: a row from the names; optionally dies on one run (a device
    time limit cutting a call)."""

    def __init__(self, die_on=None):
        self.calls, self.die_on = [], die_on

    def __call__(self, policy, method, seed):
        if (policy, method, seed) == self.die_on:
            raise KeyboardInterrupt("cut")
        self.calls.append((policy, method, seed))
        n = {"scalars": 6, "sectors2": 10, "mlp2": 22}[policy]
        fall = 0.1 + 0.01 * seed + (0.05 if method == "es" else 0.0)
        return dict(method=method, policy=policy, n_params=n, seed=seed, heldout_fall=fall,
                    shifted_fall=fall + 0.02, above_fall=fall + 0.3,
                    start_heldout_fall=0.2, start_shifted_fall=0.22, start_above_fall=0.5,
                    wall_s=3.0, budget_s=3.0, best_loss=1.0, start_loss=2.0, iterations=4,
                    compile_s=0.1, cma_variant=None, device="fake",
                    curve=[dict(wall_s=0.0, pushes=4, best_loss=2.0),
                           dict(wall_s=3.0, pushes=8, best_loss=1.0)], z_best=[0.0] * n)


def test_study_resumes_and_summarises(tmp_path):
    spec = parse_tune_spec(_spec_dict())
    n_runs = len(plan(spec.study))
    die = ("sectors2", "gradient", 0)
    first = _FakeRunner(die_on=die)
    with pytest.raises(KeyboardInterrupt):
        run_study(spec, tmp_path, runner=first, quiet=True)
    done_first = len(first.calls)
    assert done_first == 4 + 1            # every scalars run, then sectors2-cma, then the cut
    rows = json.loads((tmp_path / "summary.json").read_text())
    assert len(rows) == done_first
    assert not list((tmp_path / "runs").glob("*.tmp"))
    second = _FakeRunner()
    rec = run_study(spec, tmp_path, runner=second, quiet=True)
    assert die in second.calls and not set(first.calls) & set(second.calls)
    assert len(rec["skipped"]) == done_first and rec["left"] == []
    rows = json.loads((tmp_path / "summary.json").read_text())
    assert len(rows) == n_runs
    assert {"method", "n_params", "seed", "heldout_fall", "wall_s"} <= set(rows[0])
    assert [r["n_params"] for r in rows] == sorted(r["n_params"] for r in rows)
    md = (tmp_path / "study.md").read_text()
    assert "| 22 | cma |" in md or "| 22 | gradient |" in md    # a method per size
    clock = "included" if spec.study.get("budget_includes_compile") else "excluded"
    assert f"per run (compile {clock})" in md
    assert (tmp_path / "study.png").exists() and (tmp_path / "convergence.png").exists()
    third = _FakeRunner()
    run_study(spec, tmp_path, runner=third, quiet=True)
    assert third.calls == []
    # The comparison's format: one entry per run, wall clock with the compile.
    runs = json.loads((tmp_path / "summary_runs.json").read_text())
    assert len(runs) == n_runs
    assert set(runs[0]) == {"method", "kind", "policy", "n_params", "seed", "wall_s",
                            "heldout_fall", "device"}
    kinds = {r["method"]: r["kind"] for r in runs}
    assert kinds["cma"] == kinds["es"] == "zeroth" and kinds["gradient"] == "gradient"
    assert {r["wall_s"] for r in runs} == {3.1}               # compile 0.1 + search 3.0
    assert (tmp_path / "heldout_vs_wall.png").exists()


def test_study_deadline_starts_no_run_that_would_overrun(tmp_path):
    spec = parse_tune_spec(_spec_dict())
    runner = _FakeRunner()
    # budget 3 s + margin 5 s + compile 5 s > 10 s: nothing starts.
    rec = run_study(spec, tmp_path, runner=runner, quiet=True, deadline_s=10.0,
                    compiled=lambda p, m: False)
    assert runner.calls == [] and rec["stopped"] == "scalars-cma-s0"
    rec = run_study(spec, tmp_path, runner=runner, quiet=True, deadline_s=10.0,
                    only=["policy=mlp2", "method=es"])
    assert runner.calls == [("mlp2", "es", 0)] and rec["stopped"] is None


@pytest.mark.slow
def test_mjx_start_reproduces_the_recommended_controller():
    """A tiny MJX batch (the CPU smoke spec's 4 pushes x 0.6 s, so the persistent XLA cache of a
    smoke run serves it): the sectors and MLP policies at their start give the outcomes of the
    scalar parameterisation of ControllerParams.recommended() (measured: bit-equal losses;
    asserted: outcomes equal, losses within 1e-6 relative); the scalar one runs the values of
    recommended() up to the float32 rounding of their latents (asserted on the values)."""
    from tkujax.studies.tune import TuneProblem
    from tkujax.studies.tune.tune_spec import sample_pushes

    spec = parse_tune_spec(_spec_dict())
    base = ControllerParams.recommended()
    batch = sample_pushes(spec, spec.batch, spec.seed)
    keys = jax.random.split(jax.random.PRNGKey(spec.seed), spec.batch)
    losses, outs = {}, {}
    for policy in ("scalars", "sectors2", "mlp2"):
        rep = spec.policy_reparam(policy)
        prob = TuneProblem(rep, base, spec.loss, spec.duration_s, spec.remat,
                           quantise_targets=spec.quantise_targets)
        losses[policy], aux = prob.forward(rep.latent_of(base), 0.0, batch, keys)
        outs[policy] = aux["outcomes"]
    rep = spec.policy_reparam("scalars")
    vals = np.asarray(rep.values(jnp.asarray(rep.latent_of(base), jnp.float32)))
    np.testing.assert_allclose(vals, [getattr(base, f) for f in rep.fields], rtol=2e-6)
    for policy in ("sectors2", "mlp2"):
        assert math.isclose(losses[policy], losses["scalars"], rel_tol=1e-6)
        np.testing.assert_array_equal(outs[policy]["fell"], outs["scalars"]["fell"])
        np.testing.assert_allclose(outs[policy]["peak_incl_deg"],
                                   outs["scalars"]["peak_incl_deg"], rtol=1e-3)


# --- Seeds side by side (study.seeds_side_by_side) ----------------------------------------------

def _side_spec(**study):
    data = _spec_dict()
    data["study"] = {**data["study"], "policies": ["scalars", "mlp2"], "methods": ["cma", "es"],
                     "seeds": [0, 1, 2], "seeds_side_by_side": True, **study}
    return parse_tune_spec(data)


class _FakeGroupRunner(_FakeRunner):
    """Stand-in for the lockstep runs: one call per (policy, method) group of seeds; optionally
    dies on one group."""

    def __init__(self, die_on=None):
        super().__init__()
        self.groups, self.die_on_group = [], die_on

    def group(self, policy, method, seeds):
        if (policy, method) == self.die_on_group:
            raise KeyboardInterrupt("cut")
        self.groups.append((policy, method, tuple(seeds)))
        return [self(policy, method, s) for s in seeds]


def test_side_by_side_spec_key():
    assert _side_spec().study["seeds_side_by_side"] is True
    assert parse_tune_spec(_spec_dict()).study["seeds_side_by_side"] is False
    with pytest.raises(SpecError, match="study.seeds_side_by_side"):
        _side_spec(seeds_side_by_side="yes")
    gpu = parse_tune_spec(read_toml("specs/tune/tune_dimension.toml")).study
    assert gpu["seeds_side_by_side"] is True and len(gpu["seeds"]) == 3


def test_study_side_by_side_groups_and_resumes(tmp_path):
    spec = _side_spec()
    first = _FakeGroupRunner(die_on=("mlp2", "cma"))
    with pytest.raises(KeyboardInterrupt):
        run_study(spec, tmp_path, group_runner=first.group, quiet=True)
    assert first.groups == [("scalars", "cma", (0, 1, 2)), ("scalars", "es", (0, 1, 2))]
    runs = tmp_path / "runs"
    assert len(list(runs.glob("*.json"))) == 6
    assert json.loads((runs / "scalars-es-s2.json").read_text())["side_by_side"] == 3
    # A group done in part: only its missing seed reruns (alone now, and says so).
    (runs / "scalars-es-s1.json").unlink()
    second = _FakeGroupRunner()
    rec = run_study(spec, tmp_path, group_runner=second.group, quiet=True)
    assert second.groups == [("scalars", "es", (1,)), ("mlp2", "cma", (0, 1, 2)),
                             ("mlp2", "es", (0, 1, 2))]
    assert len(rec["skipped"]) == 5 and rec["left"] == [] and len(rec["done"]) == 7
    rows = json.loads((tmp_path / "summary.json").read_text())
    assert len(rows) == 12
    share = {(r["policy"], r["method"], r["seed"]): r["side_by_side"] for r in rows}
    assert share.pop(("scalars", "es", 1)) == 1 and set(share.values()) == {3}
    md = (tmp_path / "study.md").read_text()
    assert "side by side" in md and "11 run(s) shared it 3 ways" in md
    assert "1 run(s) had the device alone" in md
    third = _FakeGroupRunner()
    run_study(spec, tmp_path, group_runner=third.group, quiet=True)
    assert third.groups == []


def test_study_side_by_side_filters_and_deadline(tmp_path):
    spec = _side_spec()
    runner = _FakeGroupRunner()
    asked = []

    def compiled(policy, method, S):
        asked.append((policy, method, S))
        return False

    # One group counts as one run: budget 3 s + margin 5 s + compile 5 s > 10 s.
    rec = run_study(spec, tmp_path, group_runner=runner.group, quiet=True, deadline_s=10.0,
                    compiled=compiled)
    assert runner.groups == [] and rec["stopped"] == "scalars-cma-s0+1+2"
    assert asked == [("scalars", "cma", 3)]
    rec = run_study(spec, tmp_path, group_runner=runner.group, quiet=True, deadline_s=10.0,
                    only=["policy=mlp2", "seed=0,2"])
    assert runner.groups == [("mlp2", "cma", (0, 2)), ("mlp2", "es", (0, 2))]
    # Without a group runner the option cannot run.
    with pytest.raises(ValueError, match="group runner"):
        run_study(spec, tmp_path / "x", runner=_FakeRunner(), quiet=True)


@pytest.mark.slow
def test_mjx_study_side_by_side_evaluates_as_alone(tmp_path):
    """The real StudyRunner on a tiny MJX study (scalars, (1+1)-ES, 2 seeds, 2 pushes x 0.3 s,
    evaluation sets of 3 pushes: a padded chunk): the group's records have the per-seed
    records' keys, and the start's fall rates (deterministic) equal those of the runs alone.
    Its compiled shapes are those of tests/test_tune_lockstep.py's MJX test (persistent cache)."""
    data = _spec_dict()
    data["tune"] = dict(data["tune"], batch=2, duration_s=0.3)
    data["study"] = {**data["study"], "policies": ["scalars"], "methods": ["es"],
                     "seeds": [0, 1], "budget_s": 0.5, "groups": 1, "eval_n": 3}
    alone = parse_tune_spec(data)
    data["study"]["seeds_side_by_side"] = True
    side = parse_tune_spec(data)
    run_study(side, tmp_path / "side", quiet=True)
    run_study(alone, tmp_path / "alone", quiet=True)
    for seed in (0, 1):
        a = json.loads((tmp_path / "alone" / "runs" / f"scalars-es-s{seed}.json").read_text())
        s = json.loads((tmp_path / "side" / "runs" / f"scalars-es-s{seed}.json").read_text())
        assert set(a) == set(s) and (a["side_by_side"], s["side_by_side"]) == (1, 2)
        for label in ("heldout", "shifted", "above"):
            assert s[f"start_{label}_fall"] == a[f"start_{label}_fall"], label
        assert s["start_loss"] == pytest.approx(a["start_loss"], rel=1e-5)
        assert s["iterations"] >= 1 and len(s["curve"]) == s["iterations"] + 1


def test_recommended_method_follows_the_study_evidence():
    """tune.method = "auto" resolves by size to the dimension study's best method: the table
    agrees with the committed summary (when it holds rows), and sizes between map to the
    nearest measured size on a log scale."""
    import json
    from pathlib import Path

    from tkujax.studies.tune.advice import EVIDENCE, recommended_method
    from tkujax.studies.tune.dimension_study_report import recommend_methods

    summary = Path(__file__).resolve().parents[1] / "results/tune_dimension/summary.json"
    if summary.exists():
        measured = recommend_methods(json.loads(summary.read_text()))
        for n, method in EVIDENCE:
            if n in measured:      # the study names sep-CMA runs "cma" (cma_variant says which)
                assert measured[n] == ("cma" if method == "sepcma" else method), (n, measured)
    assert recommended_method(16) == "cma" and recommended_method(8) == "cma"
    assert recommended_method(30) == "cma" and recommended_method(100) == "sepcma"
    assert recommended_method(130) == "sepcma" and recommended_method(300) == "linesearch"
    assert recommended_method(1000) == "linesearch"
    for study, sizes in (("gradients_paper", (80, 1656)), ("gradients_paper_mlpr8", (160,)),
                         ("gradients_paper_mlpr16", (296,))):
        path = summary.parent.parent / study / "summary.json"
        if path.exists():
            measured = recommend_methods(json.loads(path.read_text()))
            for n in sizes:
                assert measured[n] == dict(EVIDENCE)[n], (study, n, measured)
    with pytest.raises(ValueError, match="n_params"):
        recommended_method(0)
    data = _spec_dict()
    data["tune"] = {**data["tune"], "method": "auto"}
    data.pop("study", None)
    assert parse_tune_spec(data).method == "auto"
    data["tune"]["method"] = "adam"
    with pytest.raises(SpecError, match="tune.method"):
        parse_tune_spec(data)


def test_heldout_curve_reuses_the_start_and_best_evaluations():
    """study.heldout_curves: a checkpoint whose latents are the start's or the best's takes
    their fall rates; any other is evaluated (once, all seeds together)."""
    from tkujax.studies.tune.dimension_study import heldout_curves

    start, best, mid = np.zeros((2, 3)), np.ones((2, 3)), np.full((2, 3), 0.5)
    latents = {"start": start, "best": best}
    fell = {"start": [np.array([1.0, 1.0]), np.array([1.0, 0.0])],
            "best": [np.array([0.0, 0.0]), np.array([0.0, np.nan])]}
    asked = []

    def evaluate(zs):
        asked.append(sorted(zs))
        return {"heldout": {n: [np.array([0.5, 0.0]), np.array([0.25, 0.25])] for n in zs}}

    clock = dict(snapshots=[(1.0, start), (2.0, mid), (3.0, best)])
    curves = heldout_curves(clock, latents, fell, evaluate)
    assert asked == [["t1"]]
    assert [[p["heldout_fall"] for p in c] for c in curves] == [[1.0, 0.25, 0.0],
                                                                 [0.5, 0.25, 0.0]]
    assert [p["wall_s"] for p in curves[0]] == [1.0, 2.0, 3.0]


def test_budget_override_replaces_the_study_budget_and_is_checked(monkeypatch, tmp_path):
    """`tkujax tune SPEC --budget-s S` (run_tune's budget_s) gives a [study] spec's runs that
    budget; a budget outside [1 s, 1 day] is refused naming the key."""
    import tkujax.studies.tune.dimension_study as study_module
    from tkujax.studies.tune.tune_command import run_tune

    seen = []
    monkeypatch.setattr(study_module, "run_study",
                        lambda spec, out_dir, **kw: seen.append(spec.study["budget_s"]) or {})
    data = _spec_dict()
    run_tune(data, tmp_path, budget_s=210.0)
    run_tune(data, tmp_path)
    assert seen == [210.0, parse_tune_spec(data).study["budget_s"]]
    with pytest.raises(SpecError, match=r"budget_s \(study.budget_s\).*out of range"):
        run_tune(data, tmp_path, budget_s=0.5)
