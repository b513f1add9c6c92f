"""`tkujax tune SPEC --out DIR`: run the spec's method (or the [compare] study), evaluate the
result with the hard controller on held-out pushes, and write the outputs.

With an [evaluate.shift] table the start and the tuned set are also evaluated on the shifted
held-out pushes (history.json "evaluation_shifted", a section of summary.md); the
recommendation does not use them.

params_tuned.json is what the search found; params_after.json is the recommendation: the tuned
set when the held-out evaluation says it is better than the starting set (the rule:
`tkujax.studies.tune.held_out_gate.RULE`), else the starting set; its `recommended_from` says which
("tuned", "start", or "tuned (unchecked)" without an evaluation)."""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax
import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.sweeps.progress import StatusLog
from tkujax.studies.tune.advice import EVIDENCE_NOTE, recommended_method
from tkujax.studies.tune.method_compare import json_default
from tkujax.studies.tune.held_out_gate import evaluate, harmed_directions, params_json, recommend
from tkujax.studies.tune.problem import x64
from tkujax.studies.tune.parameterisations import PolicyReparam, save_policy
from tkujax.studies.tune.tune_outputs import plot_outputs, summary_markdown
from tkujax.studies.tune.search import GradientOptions, SearchConfig, calls_used, run_search
from tkujax.dialects.validation import SpecError, integer, number
from tkujax.studies.tune.robot_table import on_robot, robot_record
from tkujax.studies.tune.start_policy import start_latent, start_record
from tkujax.studies.tune.tune_spec import (TuneSpec, ensembles_record, grid_pushes,
                                           load_tune_spec, make_problem, parse_tune_spec,
                                           sample_pushes, shifted)

# The shifted held-out pushes use evaluate.seed + SHIFT_SEED (as [compare] does for seed 0).
SHIFT_SEED = 1000


def run_tune(spec: TuneSpec | dict | str | Path, out_dir: str | Path, quiet: bool = False,
             iterations: int | None = None, compiler_options: dict | None = None,
             evaluation: bool = True, compare: bool = True, only: list[str] | None = None,
             deadline_s: float | None = None, robot=None,
             budget_s: float | None = None) -> dict:
    """Tune with the spec's method, evaluate, and write the outputs into out_dir.

    spec: a TuneSpec, a parsed TOML dict, or a path. iterations overrides tune.iterations.
    compare: also run the spec's [compare] study when it has one. Returns the record.
    A spec with a [study] table runs the dimension study instead
    (tkujax.studies.tune.dimension_study;
    only: its run filters, deadline_s: start no run that would end after it). robot: the
    Robot to tune on (tkujax.studies.robot_inputs.tune_robot loads the spec's [robot]
    file). budget_s:
    stop the search after this many seconds of generations (compile excluded); with a [study]
    table it replaces study.budget_s (each run records the budget it had).
    """
    if isinstance(spec, dict):
        spec = parse_tune_spec(spec)
    elif not isinstance(spec, TuneSpec):
        spec = load_tune_spec(spec)
    spec = on_robot(spec, robot)
    if iterations is not None:      # checked like the spec's own tune.iterations
        spec = dataclasses.replace(spec, iterations=integer("iterations (tune.iterations)",
                                                         iterations, 1, 100_000))
    if spec.study is not None:
        from tkujax.studies.tune.dimension_study import run_study

        if budget_s is not None:
            spec = dataclasses.replace(spec, study={**spec.study, "budget_s": number(
                "budget_s (study.budget_s)", budget_s, 1.0, 86_400.0, "s")})

        return run_study(spec, out_dir, only=only, deadline_s=deadline_s, quiet=quiet,
                         compiler_options=compiler_options)
    with x64(spec.float64):       # the optimiser's latents in the problem's precision too
        return _run_tune(spec, Path(out_dir), quiet, compiler_options, evaluation, compare,
                         budget_s)


@dataclasses.dataclass(frozen=True)
class TuneRun:
    """A tune spec resolved once into what `tkujax tune` runs: the latent layout, the starting
    parameters and latent, the method (tune.method, "auto" resolved) and the search settings."""

    spec: TuneSpec
    reparam: PolicyReparam
    base: ControllerParams
    z0: np.ndarray
    method: str
    advised: str                      # the dimension study's method for this size
    search: SearchConfig


def resolve_run(spec: TuneSpec, budget_s: float | None = None) -> TuneRun:
    """The run of `spec`: tune.method "auto" becomes the dimension study's advice; budget_s
    (None: [compare]'s, else none) bounds the search's time."""
    reparam, base = spec.policy_reparam(), spec.base_params()
    advised = recommended_method(reparam.size)
    c = spec.compare or {}
    budget = c.get("budget_s", float("inf")) if budget_s is None else float(budget_s)
    cfg = SearchConfig(budget_s=budget, max_iterations=spec.iterations,
                       popsize=spec.popsize, learning_rate=spec.learning_rate,
                       clip_norm=spec.clip_norm, sigma0=spec.baseline_sigma,
                       temperature_deg=c.get("temperature_deg", 0.5),
                       groups=c.get("groups", 4 if spec.batch % 4 == 0 else 1),
                       ray_radius=c.get("ray_radius", 2.0),
                       ray_ratio=c.get("ray_ratio", 0.5))
    return TuneRun(spec, reparam, base, start_latent(spec, reparam),
                   advised if spec.method == "auto" else spec.method, advised, cfg)


def _log_method(run: TuneRun, log) -> None:
    """The method chosen by "auto", or a note when the spec's differs from the advice."""
    size = run.reparam.size
    if run.spec.method == "auto":
        log(f"tune.method = auto: {run.method} for {size} parameters ({EVIDENCE_NOTE})")
    elif run.method != run.advised:
        log(f"note: for {size} parameters the dimension study recommends {run.advised} "
            f"(tune.method = \"auto\"; {EVIDENCE_NOTE})")


def check_out(out: Path, spec: TuneSpec) -> None:
    """SpecError when `out` holds another spec's tune (its history.json's spec differs): a
    tune's outputs are replaced as a whole by a rerun of its spec, never mixed with another's."""
    held = out / "history.json"
    if not held.is_file():
        return
    try:
        raw = json.loads(held.read_text()).get("spec")
    except (OSError, ValueError, AttributeError):
        raw = None
    if raw != json.loads(json.dumps(spec.raw, default=json_default)):
        name = raw.get("tune", {}).get("name") if isinstance(raw, dict) else None
        raise SpecError(f"{out} holds another spec's tune ({name!r}, {held.name}), this is "
                        f"{spec.name!r}: its outputs would mix with this one's. Nothing was "
                        "written: choose another --out")


def _run_tune(spec: TuneSpec, out: Path, quiet: bool, compiler_options: dict | None,
              evaluation: bool, compare: bool, budget_s: float | None = None) -> dict:
    check_out(out, spec)
    out.mkdir(parents=True, exist_ok=True)
    log = StatusLog(quiet, desc="tune ")
    t_start = time.perf_counter()
    run = resolve_run(spec, budget_s)
    problem = make_problem(spec, run.reparam, compiler_options=compiler_options)
    comparison = None
    if compare and spec.compare is not None:
        from tkujax.studies.tune.method_compare import run_compare

        comparison = run_compare(spec, out, problem, log)
    train = sample_pushes(spec, spec.batch, spec.seed)
    keys = jax.random.split(jax.random.PRNGKey(spec.seed), spec.batch)
    _log_method(run, log)
    log(f"tune {spec.name}: method {run.method}, {spec.batch} pushes x {spec.duration_s} s, "
        f"up to {spec.iterations} iterations, tuning {', '.join(run.reparam.fields)}. Compiling "
        "(minutes on a CPU) ...")
    # Bundled gradients and diagnostics concern the methods that take gradients only.
    options = (dict(options=GradientOptions(spec.diagnose_every, spec.bundle_antithetic))
               if "gradient" in calls_used(run.method) else {})
    found = run_search(run.method, problem, run.z0, train, keys, run.search, seed=spec.seed,
                       log=log, **options)
    cands = {"before": run.z0, "after": np.asarray(found["z_best"])}
    evals, evals_shifted, heldout = ({}, None, None) if not evaluation else _evaluate(
        run, problem, cands, compiler_options, log)
    decision = _recommend(spec, evals, heldout, evaluation)
    log(decision["reason"])
    _write_params(run, cands, decision, out)
    reparam = run.reparam
    record = dict(
        name=spec.name, spec=spec.raw, method=run.method, tuned=list(reparam.fields),
        ranges_user_units=reparam.user_ranges(), batch=spec.batch, duration_s=spec.duration_s,
        iterations=found["iterations"], float64=spec.float64, remat=spec.remat, run=found,
        params_user={n: reparam.user(z) for n, z in cands.items()},
        latents={n: np.asarray(z).tolist() for n, z in cands.items()}, evaluation=evals,
        evaluation_shifted=evals_shifted,
        recommendation=decision, ensembles=ensembles_record(spec), model=dict(spec.model),
        start_policy=start_record(spec),
        robot=robot_record(spec),
        compare=None if comparison is None else dict(winner=comparison["winner"],
                                                     pooled=comparison["pooled"]),
        wall_s=round(time.perf_counter() - t_start, 2), devices=[str(d) for d in jax.devices()])
    (out / "history.json").write_text(json.dumps(record, indent=1, default=json_default))
    plot_outputs(out, record)
    (out / "summary.md").write_text(summary_markdown(record, comparison))
    log(f"wrote {out}/summary.md")
    return record


def _evaluate(run: TuneRun, problem, cands: dict, compiler_options, log):
    """(held-out and grid evaluation, the shifted held-out evaluation or None, the held-out
    pushes) of the start and the tuned latents, with the hard gate."""
    spec = run.spec
    log(f"evaluating (hard gate) on {spec.eval_n} held-out pushes (seed {spec.eval_seed}) "
        f"and a {len(spec.eval_impulse_ns)} x {len(spec.eval_azimuth_deg)} grid ...")
    eval_problem = problem if spec.eval_duration_s == spec.duration_s else make_problem(
        spec, run.reparam, spec.eval_duration_s, False, compiler_options)
    heldout = sample_pushes(spec, spec.eval_n, spec.eval_seed)
    evals = evaluate(eval_problem, cands, heldout, grid_pushes(spec), spec.batch,
                     spec.eval_seed)
    evals_shifted = None
    shift_spec = shifted(spec)
    if shift_spec is not None and spec.eval_n:
        # [evaluate.shift] (never trained on), seeded as in [compare]: reported next to
        # the held-out set; the recommendation stays the held-out set's.
        log(f"evaluating (hard gate) on {spec.eval_n} shifted held-out pushes "
            f"([evaluate.shift], seed {spec.eval_seed + SHIFT_SEED}) ...")
        shift_recs = sample_pushes(shift_spec, spec.eval_n, spec.eval_seed + SHIFT_SEED)
        evals_shifted = evaluate(eval_problem, cands, shift_recs, {"impulse_ns": ()},
                                 spec.batch, spec.eval_seed + SHIFT_SEED)
    return evals, evals_shifted, heldout


def _recommend(spec: TuneSpec, evals: dict, heldout, evaluation: bool) -> dict:
    """Never recommend a worse set: params_after.json is the tuned set only when the held-out
    evaluation says it is better (evaluate.RULE); else the starting set, with a note."""
    harmed = []
    if evaluation and spec.eval_n:
        from tkujax.analysis.compare import SECTOR_NAMES, sector_index

        harmed = harmed_directions(evals, sector_index(heldout["azimuth_deg"], 4),
                                   SECTOR_NAMES[4])
    return recommend(evals, harmed)


def _write_params(run: TuneRun, cands: dict, decision: dict, out: Path) -> None:
    """params_before/tuned/after.json, and for a scheduled policy policy.json and
    policy_after.json."""
    reparam, base, spec = run.reparam, run.base, run.spec
    params = {name: reparam.params_np(base, z) for name, z in cands.items()}
    chosen = decision["recommended"]
    note = {"recommended_from": ("tuned" if decision["verified"] else "tuned (unchecked)")
            if chosen == "after" else "start"}
    if reparam.kind != "scalars":      # the schedule has no ControllerParams form
        (out / "policy.json").write_text(json.dumps(
            {n: reparam.describe(z) for n, z in cands.items()}, indent=1))
        # What `tkujax sweep --params` runs: the recommended set with its schedule.
        save_policy(reparam, base, cands[chosen], out / "policy_after.json",
                    f"tkujax tune {spec.name}: the {'tuned' if chosen == 'after' else 'start'} "
                    f"policy ({note['recommended_from']})")
    for name, payload in (("params_before.json", params_json(params["before"].validate())),
                          ("params_tuned.json", params_json(params["after"].validate())),
                          ("params_after.json", params_json(params[chosen].validate()) | note)):
        (out / name).write_text(json.dumps(payload, indent=1))
