"""`tkujax tune SPEC --out DIR`: tune, run the baseline, evaluate, write the outputs."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import jax
import numpy as np

from tkujax.studies.tune.evaluate import evaluate, params_json
from tkujax.studies.tune.methods import _f, evolution_baseline, make_optimizer, optimise, temperature_schedule
from tkujax.studies.tune.problem import TuneProblem, _x64
from tkujax.studies.tune.reparam import DEG
from tkujax.studies.tune.report import _plot, summary_markdown
from tkujax.studies.tune.spec import TuneSpec, grid_pushes, load_tune_spec, parse_tune_spec, sample_pushes


def run_tune(spec: TuneSpec | dict | str | Path, out_dir: str | Path, quiet: bool = False,
             iterations: int | None = None, compiler_options: dict | None = None,
             baseline: bool = True, evaluation: bool = True) -> dict:
    """Tune, run the baseline, evaluate, and write the outputs into out_dir. Returns a summary.

    spec: a TuneSpec, a parsed TOML dict, or a path. iterations overrides the spec's count.
    """
    if isinstance(spec, dict):
        spec = parse_tune_spec(spec)
    elif not isinstance(spec, TuneSpec):
        spec = load_tune_spec(spec)
    if iterations is not None:
        spec = dataclasses.replace(spec, iterations=int(iterations))
    with _x64(spec.float64):       # the optimiser's latents in the problem's precision too
        return _run_tune(spec, Path(out_dir), quiet, compiler_options, baseline, evaluation)


def _run_tune(spec: TuneSpec, out: Path, quiet: bool, compiler_options: dict | None,
              baseline: bool, evaluation: bool) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    log = (lambda s: None) if quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    t_start = time.perf_counter()

    reparam, base = spec.reparam(), spec.base_params()
    z0 = reparam.latent_of(base)
    problem = TuneProblem(reparam, base, spec.loss, spec.duration_s, spec.remat, spec.float64,
                          compiler_options=compiler_options,
                          quantise_targets=spec.quantise_targets)
    train = sample_pushes(spec, spec.batch, spec.seed)
    train_keys = jax.random.split(jax.random.PRNGKey(spec.seed), spec.batch)
    temps = temperature_schedule(*spec.anneal[:2], spec.iterations, spec.anneal[2])
    log(f"tune {spec.name}: {spec.batch} pushes x {spec.duration_s} s, {spec.iterations} "
        f"iterations, tuning {', '.join(reparam.fields)}; float64={spec.float64}, "
        f"remat={spec.remat}. Compiling the gradient (minutes on a CPU) ...")

    # 1. Gradient descent.
    t0 = time.perf_counter()
    step_fn = lambda z, tau: problem.value_and_grad(z, tau, train, train_keys)  # noqa: E731
    z_grad, history = optimise(step_fn, z0, temps, make_optimizer(spec.learning_rate,
                                                                   spec.clip_norm),
                               reparam, log, pushes_per_step=spec.batch)
    grad_wall = time.perf_counter() - t0
    compile_note = history[0]["wall_s"] if history else None

    # 2. Gradient-free baseline, same loss (at a fixed temperature), same pushes simulated.
    tau_b = spec.baseline_temperature_deg * DEG
    es_rows, z_es, es_wall = [], None, 0.0
    if baseline:
        log(f"baseline: (1+1)-ES, {spec.iterations} evaluations x {spec.batch} pushes at "
            f"gate temperature {spec.baseline_temperature_deg:g} deg ...")
        t0 = time.perf_counter()
        es_loss = lambda z: problem.forward(z, tau_b, train, train_keys)[0]  # noqa: E731
        z_es, es_rows = evolution_baseline(es_loss, z0, spec.iterations, spec.baseline_sigma,
                                           spec.baseline_seed, log, spec.batch)
        es_wall = time.perf_counter() - t0

    # 3. Same-objective comparison on the training batch: final soft temperature and hard.
    cands = {"before": z0, "gradient": z_grad} | ({"baseline": z_es} if z_es is not None else {})
    train_loss = {}
    for name, z in cands.items():
        soft = problem.forward(z, temps[-1], train, train_keys)[0]
        hard = problem.forward(z, 0.0, train, train_keys)[0]
        es_t = (None if not baseline else soft if math.isclose(tau_b, temps[-1])
                else problem.forward(z, tau_b, train, train_keys)[0])
        train_loss[name] = dict(final_temperature=_f(soft), hard=_f(hard), baseline_temperature=
                                _f(es_t) if es_t is not None else None)

    # 4. Honest evaluation: held-out pushes (another seed), hard controller.
    evals = {}
    if evaluation:
        log(f"evaluating (hard gate) on {spec.eval_n} held-out pushes (seed {spec.eval_seed}) "
            f"and a {len(spec.eval_impulse_ns)} x {len(spec.eval_azimuth_deg)} grid ...")
        eval_problem = problem if spec.eval_duration_s == spec.duration_s else TuneProblem(
            reparam, base, spec.loss, spec.eval_duration_s, False, spec.float64,
            compiler_options=compiler_options, quantise_targets=spec.quantise_targets)
        heldout = sample_pushes(spec, spec.eval_n, spec.eval_seed)
        evals = evaluate(eval_problem, cands, heldout, grid_pushes(spec), spec.batch,
                         spec.eval_seed)

    # 5. Outputs.
    params = {name: reparam.params_np(base, z) for name, z in cands.items()}
    for name, fname in (("before", "params_before.json"), ("gradient", "params_after.json"),
                        ("baseline", "params_baseline.json")):
        if name in params:
            (out / fname).write_text(json.dumps(params_json(params[name].validate()), indent=1))
    n_skipped = sum(r["skipped"] for r in history)
    record = dict(
        name=spec.name, spec=spec.raw, tuned=list(reparam.fields),
        ranges_user_units=reparam.user_ranges(), batch=spec.batch, duration_s=spec.duration_s,
        iterations=spec.iterations, float64=spec.float64, remat=spec.remat,
        temperatures_deg=(temps / DEG).tolist(), history=history,
        skipped_steps=[r["iteration"] for r in history if r["skipped"]], n_skipped=n_skipped,
        baseline=dict(method="(1+1)-ES, 1/5 rule", sigma0=spec.baseline_sigma,
                      gate_temperature_deg=spec.baseline_temperature_deg, rows=es_rows,
                      wall_s=round(es_wall, 2)),
        pushes_simulated=dict(gradient=spec.iterations * spec.batch,
                              baseline=len(es_rows) * spec.batch),
        params_user={n: reparam.user(z) for n, z in cands.items()},
        latents={n: np.asarray(z).tolist() for n, z in cands.items()},
        train_loss=train_loss, evaluation=evals,
        wall_s=dict(gradient=round(grad_wall, 2), first_iteration_incl_compile=compile_note,
                    baseline=round(es_wall, 2), total=round(time.perf_counter() - t_start, 2)),
        devices=[str(d) for d in jax.devices()])
    (out / "history.json").write_text(json.dumps(record, indent=1, default=_json_default))
    _plot(out, record)
    (out / "summary.md").write_text(summary_markdown(record))
    log(f"wrote {out}/summary.md")
    return record


def _json_default(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return str(x)
