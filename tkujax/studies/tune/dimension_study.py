"""`[study]`: the dimension study. Every parameterisation (`study.policies`, growing size) x
search method x seed at one wall-clock budget per run, evaluated on held-out pushes of the
training distribution, on the shifted set ([evaluate.shift]) and above the training impulses
(`study.above_impulse_ns`).

Seeds side by side (`study.seeds_side_by_side = true`): the seeds of one (policy, method) run
together as one group, in lockstep (tkujax.studies.tune.lockstep.run_search_lockstep): each
seed keeps its own training batch, optimiser and random numbers, but every compiled call
serves all the group's seeds at once, and the group shares ONE budget_s of wall clock. Each
seed then gets a share of the device (between about 1/S and 1/2 of it, S seeds, since one
search alone leaves the GPU far from saturated at the study's batches), the same share for
every method, so the comparison at equal wall clock stays fair. Every run record and summary
row says how many ways the device was shared in `side_by_side` (1: the run had it alone).
Without the option (the default) the runs go one after another, each with the device alone.

Resumable: each finished run writes `runs/<policy>-<method>-s<seed>.json` (atomically, with its
convergence curve and best latent); a rerun skips the runs whose file exists, so a call cut by a
device time limit loses only the run (or the side-by-side group) it was in. A group is skipped
only when every seed's file exists; a group done in part reruns only its missing seeds, side by
side. `only` filters select runs ("policy=mlp", "method=cma,es", "seed=0"; filters on different
keys must all hold; with seeds side by side the group is the selected seeds), and a deadline
starts no run (or group: a group counts as one run) that would end after it (the estimate:
study.budget_s + study.margin_s, plus study.compile_s when the run's functions are not compiled
yet in this process).

After every run (group), `summary.json` (one row per finished run: method, policy, n_params,
seed, heldout_fall, shifted_fall, above_fall, wall_s, side_by_side, ...), `study.md`,
`study.png` (held-out fall rate against parameter count per method), `convergence.png` (best
hard training loss against wall time, one panel per policy) and, for gradient and hybrid runs,
`iterates.png` (the hard loss of every Adam iterate) are rewritten from all run files present.

Seeds as in [compare]: training batch tune.seed + s, held-out evaluate.seed + s, shifted
evaluate.seed + 1000 + s, above the training range evaluate.seed + 2000 + s. Each run also
reports the start (the hand-designed controller, which every parameterisation reproduces at
its start latent) on the same pushes, so differences are paired.

Compile included (`study.budget_includes_compile = true`): each run's budget_s counts its own
compiles (tkujax.studies.tune.budget_clock): wall_s is then compile + search, and the run
records `heldout_curve`, the held-out fall rate of its best-so-far latent at
`study.heldout_checkpoints` even times of its clock and at its end. `summary_runs.json` (one
entry per run: method, kind "gradient" or "zeroth", n_params, seed, wall_s compile included,
heldout_fall, device) and `heldout_vs_wall.png` are written with the summary.

`method = "cma"` runs separable CMA-ES (`sepcma`) from `study.sep_cma_from` parameters on; the
row keeps method "cma" and says which in `cma_variant`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from tkujax.studies.tune.method_compare import json_default
from tkujax.studies.tune.search import calls_used
from tkujax.studies.tune.searchers import searcher_class
from tkujax.studies.tune.dimension_study_report import (comparison_runs, plot_heldout_vs_wall,
                                                        plot_study,
                                                        plot_validation_vs_wall, study_markdown)

RUN_KEYS = ("policy", "method", "seed")


def run_name(policy: str, method: str, seed: int) -> str:
    return f"{policy}-{method}-s{seed}"


def plan(study: dict) -> list[tuple[str, str, int]]:
    """Every (policy, method, seed), grouped by policy, then method: a call that runs several
    seeds of one method compiles its functions once."""
    return [(p, m, s) for p in study["policies"] for m in study["methods"]
            for s in study["seeds"]]


def parse_only(only: list[str] | None) -> dict[str, set[str]]:
    """["policy=mlp,sectors8", "seed=0"] -> {"policy": {...}, "seed": {"0"}}."""
    out: dict[str, set[str]] = {}
    for item in only or []:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or key not in RUN_KEYS or not values.strip():
            raise ValueError(f"--only {item!r}: expected KEY=V1[,V2...] with KEY in {RUN_KEYS}")
        out.setdefault(key, set()).update(v.strip() for v in values.split(",") if v.strip())
    return out


def select(runs: list[tuple[str, str, int]], only: list[str] | None):
    f = parse_only(only)
    return [r for r in runs if all(str(dict(zip(RUN_KEYS, r))[k]) in v for k, v in f.items())]


def _write_json(path: Path, obj) -> None:
    """Atomic: a run cut mid-write leaves no half file (which would count as finished)."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")   # processes may share out_dir
    tmp.write_text(json.dumps(obj, indent=1, default=json_default))
    os.replace(tmp, path)


Runner = Callable[[str, str, int], dict]
GroupRunner = Callable[[str, str, list[int]], list[dict]]


def group_name(policy: str, method: str, seeds: list[int]) -> str:
    return f"{policy}-{method}-s{'+'.join(str(s) for s in seeds)}"


def groups(runs: list[tuple[str, str, int]]) -> list[tuple[str, str, list[int]]]:
    """The runs as (policy, method, [seeds]) groups, in plan order."""
    out: dict[tuple[str, str], list[int]] = {}
    for policy, method, seed in runs:
        out.setdefault((policy, method), []).append(seed)
    return [(p, m, seeds) for (p, m), seeds in out.items()]


def run_study(spec, out_dir, only: list[str] | None = None, deadline_s: float | None = None,
              quiet: bool = False, compiler_options: dict | None = None,
              runner: Runner | None = None, compiled: Callable[..., bool] | None = None,
              group_runner: GroupRunner | None = None) -> dict:
    """Run the spec's [study] (the runs not finished yet), then rewrite the summary.

    runner(policy, method, seed) -> run record (a dict with at least the summary row's keys);
    group_runner(policy, method, seeds) -> one such record per seed, the seeds run side by side
    (used when study.seeds_side_by_side is set); default for both: the MJX search and
    evaluation (`StudyRunner` and its `run_group`). compiled(policy, method) (seeds side by
    side: compiled(policy, method, S)): whether the functions that run (group of S seeds) uses
    are already compiled (for the deadline's estimate)."""
    out = Path(out_dir)
    (out / "runs").mkdir(parents=True, exist_ok=True)
    log = (lambda s: None) if quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    study = spec.study
    side = bool(study.get("seeds_side_by_side", False))
    todo = select(plan(study), only)
    if runner is None and group_runner is None:
        sr = StudyRunner(spec, log, compiler_options)
        runner, group_runner, compiled = sr, sr.run_group, sr.compiled
    if (group_runner if side else runner) is None:
        raise ValueError("study.seeds_side_by_side = " + ("true needs a group runner" if side
                                                         else "false needs a runner"))
    compiled = compiled or (lambda *a: True)
    units = groups(todo) if side else [(p, m, [s]) for p, m, s in todo]
    t0 = time.perf_counter()
    done, skipped, stopped = [], [], None
    for policy, method, seeds in units:
        paths = {s: out / "runs" / f"{run_name(policy, method, s)}.json" for s in seeds}
        missing = [s for s in seeds if not paths[s].exists()]
        skipped += [run_name(policy, method, s) for s in seeds if s not in missing]
        if not missing:
            continue
        name = group_name(policy, method, missing)
        ready = compiled(policy, method, len(missing)) if side else compiled(policy, method)
        compile_s = 0.0 if ready else study["compile_s"]
        est = study["margin_s"] + (max(study["budget_s"], compile_s)
                                   if study.get("budget_includes_compile")
                                   else study["budget_s"] + compile_s)
        if deadline_s is not None and time.perf_counter() - t0 + est > deadline_s:
            stopped = name
            log(f"study: stopping before {name}: {time.perf_counter() - t0:.0f} s + ~{est:.0f} "
                f"s would pass the deadline of {deadline_s:g} s (rerun to resume)")
            break
        if side:
            log(f"study: {name}, {len(missing)} seed(s) side by side (budget "
                f"{study['budget_s']:g} s shared) ...")
            recs = list(group_runner(policy, method, list(missing)))
            got = [r.get("seed") for r in recs]
            if got != missing:
                raise RuntimeError(f"group runner returned seeds {got} for {missing}")
        else:
            log(f"study: {name} (budget {study['budget_s']:g} s) ...")
            recs = [runner(policy, method, missing[0])]
        for seed, rec in zip(missing, recs):
            _write_json(paths[seed], dict(rec, side_by_side=len(missing) if side else 1))
            done.append(run_name(policy, method, seed))
        write_summary(out, spec)
    summary = write_summary(out, spec)
    left = [run_name(*r) for r in plan(study)
            if not (out / "runs" / f"{run_name(*r)}.json").exists()]
    log(f"study: {len(done)} run(s) done now, {len(skipped)} already done, "
        f"{len(left)} of {len(plan(study))} left" + (f" (stopped before {stopped})"
                                                     if stopped else ""))
    return dict(summary=summary, done=done, skipped=skipped, left=left, stopped=stopped)


ROW_KEYS = ("method", "policy", "n_params", "seed", "heldout_fall", "shifted_fall",
            "above_fall", "start_heldout_fall", "start_shifted_fall", "start_above_fall",
            "wall_s", "budget_s", "best_loss", "start_loss", "iterations", "compile_s",
            "cma_variant", "push_clip", "device", "side_by_side", "budget_includes_compile",
            "search_s", "select", "fresh_batches", "validation_fall", "start_validation_fall")


def load_runs(out: Path) -> list[dict]:
    runs = []
    for p in sorted((Path(out) / "runs").glob("*.json")):
        try:
            runs.append(json.loads(p.read_text()))
        except json.JSONDecodeError:      # never written atomically by this module
            continue
    return runs


def write_summary(out: Path, spec=None) -> list[dict]:
    """summary.json (rows of every finished run, each with its method's kind: "gradient" or
    "zeroth"), study.md and the plots."""
    out = Path(out)
    runs = load_runs(out)
    rows = sorted(({k: r.get(k) for k in ROW_KEYS} for r in runs),
                  key=lambda r: (r["n_params"], r["method"], r["seed"]))
    for row, c in zip(rows, comparison_runs(runs)):      # both in (n_params, method, seed) order
        row["kind"] = c["kind"]
    _write_json(out / "summary.json", rows)
    _write_json(out / "summary_runs.json", comparison_runs(runs))
    (out / "study.md").write_text(study_markdown(rows, spec))
    if runs:
        plot_study(out, rows, runs)
        plot_heldout_vs_wall(out, runs)
        plot_validation_vs_wall(out, runs)
        if spec is not None:
            write_best_policy(out, spec, runs)
    return rows


def best_run(runs: list[dict], key: str = "heldout_fall") -> dict | None:
    """The run with the lowest held-out fall rate (ties: fewer parameters, then the name)."""
    ok = [r for r in runs if r.get(key) is not None and math.isfinite(r[key])]
    return min(ok, key=lambda r: (r[key], r["n_params"], run_name(r["policy"], r["method"],
                                                                   r["seed"])), default=None)


def write_best_policy(out: Path, spec, runs: list[dict]) -> Path | None:
    """best_policy.json: the study's best run as a file `tkujax sweep --params` runs (a policy
    file for a scheduled policy), to evaluate it on other pushes (results/recovery_eval)."""
    from tkujax.studies.tune.parameterisations import save_policy

    r = best_run(runs)
    if r is None or r["policy"] not in spec.study["policies"]:
        return None
    name = run_name(r["policy"], r["method"], r["seed"])
    source = (f"tkujax tune [study]: runs/{name}.json, the lowest held-out fall rate of the "
              f"study ({r['heldout_fall']:.4f}; start {r['start_heldout_fall']:.4f})")
    return save_policy(spec.policy_reparam(r["policy"]), spec.base_params(), r["z_best"],
                       out / "best_policy.json", source)


class StudyRunner:
    """The real runs: one TuneProblem per policy (compiled once per process), run_search (or
    run_search_lockstep for seeds side by side, `run_group`), and the hard-gate evaluation of
    the start and the best latent on the evaluation sets."""

    def __init__(self, spec, log, compiler_options=None):
        self.spec, self.log, self.opts = spec, log, compiler_options
        self.problems: dict = {}
        # {(policy, S): functions compiled}; S = 0: run_search's, S >= 1: the lockstep ones
        # for S seeds side by side (another shape, another compile).
        self.done: dict[tuple[str, int], set[str]] = {}
        # {(policy, S): {call: seconds of its first, compiling, call}} (compile included)
        self.compile_times: dict[tuple[str, int], dict[str, float]] = {}
        self.base = spec.base_params()

    def compiled(self, policy: str, method: str, side_by_side: int = 0) -> bool:
        """Whether this process has compiled what `method` calls for this policy (run_search
        compiles the forward, the population call (cma, sepcma, hybrid) and the grouped
        gradient (gradient, hybrid) before its clock starts; side_by_side = S: the lockstep
        versions for S seeds, which the group's evaluation uses too)."""
        return calls_used(method) <= self.done.get((policy, side_by_side), set())

    def problem(self, policy: str):
        from tkujax.studies.tune.tune_spec import make_problem

        if policy not in self.problems:
            self.problems[policy] = make_problem(self.spec, self.spec.policy_reparam(policy),
                                                 compiler_options=self.opts)
        return self.problems[policy]

    def eval_sets(self, seed: int) -> dict:
        import jax

        from tkujax.studies.tune.tune_spec import sample_pushes, shifted

        spec, st = self.spec, self.spec.study
        sets = {"heldout": (spec, spec.eval_seed + seed)}
        if spec.shift is not None:
            sets["shifted"] = (shifted(spec), spec.eval_seed + 1000 + seed)
        if st["above_impulse_ns"] is not None:
            push = dict(spec.push, impulse_ns=tuple(st["above_impulse_ns"]))
            sets["above"] = (dataclasses.replace(spec, push=push), spec.eval_seed + 2000 + seed)
        out = {}
        for label, (sp, es) in sets.items():
            out[label] = (sample_pushes(sp, st["eval_n"], es),
                          jax.random.split(jax.random.PRNGKey(es), st["eval_n"]))
        return out

    def _setup(self, policy: str, method: str):
        """(problem, reparam, z0, cma variant, search method, SearchConfig)."""
        from tkujax.studies.tune.search import SearchConfig
        from tkujax.studies.tune.start_policy import start_latent

        spec, st = self.spec, self.spec.study
        problem = self.problem(policy)
        rep = problem.reparam
        z0 = start_latent(spec, rep)
        variant, m = None, method
        if method == "cma":
            variant = "sep-CMA" if rep.size >= st["sep_cma_from"] else "CMA"
            m = "sepcma" if variant == "sep-CMA" else "cma"
        cfg = SearchConfig(budget_s=st["budget_s"], popsize=st["popsize"],
                           sigma0=st["sigma0"], zo_sigma=st["zo_sigma"],
                           groups=st["groups"], learning_rate=st["learning_rate"],
                           clip_norm=spec.clip_norm, temperature_deg=st["temperature_deg"],
                           push_clip=st["push_clip"], ray_radius=st["ray_radius"],
                           ray_ratio=st["ray_ratio"],
                           guided_steps=st["guided_steps"])
        return problem, rep, z0, variant, m, cfg

    def _train(self, seed: int):
        """Seed s's training batch and keys (tune.seed + s)."""
        return self._draw(self.spec.seed + seed, self.spec.batch)

    def _draw(self, seed: int, n: int):
        """n pushes of the training distribution and their keys, drawn with `seed`."""
        import jax

        from tkujax.studies.tune.tune_spec import sample_pushes

        return (sample_pushes(self.spec, n, seed),
                jax.random.split(jax.random.PRNGKey(seed), n))

    def _selection(self, problem, seeds: list[int], side_by_side: bool):
        """(ValidationSelector or None, BatchStream or None) of study.select and
        study.fresh_batches (tkujax.studies.tune.selection)."""
        from tkujax.studies.tune.selection import (VALIDATION_SEED_OFFSET, BatchStream,
                                                   ValidationSelector)

        spec, st = self.spec, self.spec.study
        stream = (BatchStream(lambda sd: self._draw(sd, spec.batch), seeds, spec.seed)
                  if st["fresh_batches"] else None)
        if st["select"] != "validation":
            return None, stream
        sets = [{"heldout": self._draw(spec.eval_seed + VALIDATION_SEED_OFFSET + s,
                                       st["select_n"])} for s in seeds]

        def rates(zs):
            fell = self._fell(problem, {"z": zs}, sets, side_by_side)["heldout"]["z"]
            return np.array([np.nanmean(f) for f in fell])

        return ValidationSelector(rates, st["select_every_s"]), stream

    def _record(self, policy, method, seed, rep, variant, r, fell: dict,
                clock: dict | None = None) -> dict:
        """The run record: the summary row's keys, the curve, the best latent.
        fell: {label: (start fell (n,), best fell (n,))}. clock (compile included): the
        charged compile seconds ("charge") and the held-out curve before the end ("curve")."""
        import jax

        from tkujax.studies.tune.start_policy import start_record
        from tkujax.studies.tune.tune_spec import ensembles_record

        st = self.spec.study
        search_s = max([r["curve"][-1]["wall_s"]]
                       + [c["wall_s"] for c in r.get("selection_curve", [])[-1:]])
        row = dict(method=method, policy=policy, n_params=rep.size, seed=seed,
                   cma_variant=variant, budget_s=st["budget_s"],
                   push_clip=st["push_clip"] if searcher_class(method).uses_gradient else None,
                   wall_s=search_s if clock is None else round(clock["charge"] + search_s, 3),
                   search_s=search_s, budget_includes_compile=clock is not None,
                   best_loss=r["best_loss"],
                   start_loss=r["curve"][0]["best_loss"], iterations=r["iterations"],
                   compile_s=r["compile_s"] if clock is None else round(clock["charge"], 2),
                   select=r.get("select", "training"), fresh_batches=st["fresh_batches"],
                   validation_fall=r.get("validation_fall"),
                   start_validation_fall=r.get("start_validation_fall"),
                   device=str(jax.devices()[0].device_kind))
        for label, (start, best) in fell.items():
            row[f"{label}_fall"] = float(np.nanmean(best))
            row[f"start_{label}_fall"] = float(np.nanmean(start))
            row[f"{label}_diverged"] = int(np.sum(~np.isfinite(best)))
        if clock is not None:
            row["heldout_curve"] = clock["curve"] + [dict(wall_s=row["wall_s"],
                                                          heldout_fall=row["heldout_fall"])]
        self.log(f"  {run_name(policy, method, seed)}: held-out {row['heldout_fall']:.3f} "
                 f"(start {row['start_heldout_fall']:.3f}), {r['iterations']} iterations")
        return dict(row, curve=r["curve"], z_best=r["z_best"], extra=r["extra"],
                    selection_curve=r.get("selection_curve"),
                    policy_layout=rep.describe(r["z_best"]),
                    ensembles=ensembles_record(self.spec), model=dict(self.spec.model),
                    start_policy=start_record(self.spec), devices=[str(d) for d in jax.devices()])

    def __call__(self, policy: str, method: str, seed: int) -> dict:
        """One seed alone: `run_group` of one seed without the lockstep functions."""
        return self.run_group(policy, method, [seed], side_by_side=False)[0]

    def _search(self, policy, method, m, problem, z0, trains, seeds, cfg, side_by_side):
        """(run records, clock or None): run_search / run_search_lockstep, or with
        study.budget_includes_compile the same loop under a clock counting the compiles."""
        from tkujax.studies.tune.lockstep import lockstep_calls, run_search_lockstep
        from tkujax.studies.tune.search import OneSeedCalls, run_search
        from tkujax.studies.tune.budget_clock import clocked_search

        st = self.spec.study
        batches, keys = [t[0] for t in trains], [t[1] for t in trains]
        select, stream = self._selection(problem, seeds, side_by_side)
        if not st["budget_includes_compile"]:
            if not side_by_side:
                return [run_search(m, problem, z0, batches[0], keys[0], cfg, seed=seeds[0],
                                   log=self.log, select=select)], None
            return run_search_lockstep(m, problem, z0, batches, keys, cfg, seeds,
                                       log=self.log, compiler_options=self.opts,
                                       select=select, stream=stream), None
        if side_by_side:
            calls = lockstep_calls(problem, batches, keys, cfg, len(seeds), self.opts, stream)
        else:
            calls = OneSeedCalls(problem, problem.with_off_survived(batches[0], keys[0]),
                                 keys[0], cfg)
        times = self.compile_times.setdefault((policy, len(seeds) if side_by_side else 0), {})
        n = st["heldout_checkpoints"]
        rs, charge, snaps = clocked_search(m, calls, z0, cfg, seeds, f"{m} x{len(seeds)}",
                                           times, [i / n for i in range(1, n)], self.log,
                                           select)
        return rs, dict(charge=charge, snapshots=snaps)

    def _fell(self, problem, latents: dict, sets: list[dict], side_by_side: bool) -> dict:
        """{label: {name: [per seed fell (n,)]}} of latents {name: (S, k)} on each seed's
        evaluation sets."""
        from tkujax.studies.tune.method_compare import fell_rates
        from tkujax.studies.tune.lockstep import fell_rates_lockstep

        if side_by_side:
            return {label: fell_rates_lockstep(problem, latents, [e[label][0] for e in sets],
                                               [e[label][1] for e in sets], self.spec.batch,
                                               self.opts)
                    for label in sets[0]}
        return {label: {name: [fell_rates(problem, {name: zs[0]}, *sets[0][label],
                                          self.spec.batch)[name]]
                        for name, zs in latents.items()}
                for label in sets[0]}

    def run_group(self, policy: str, method: str, seeds: list[int],
                  side_by_side: bool = True) -> list[dict]:
        """The seeds side by side: run_search_lockstep, then each seed's evaluation, all seeds
        in one call per chunk (the lockstep forward at the training batch's shape, compiled
        for the search already). One record per seed. side_by_side=False: one seed alone,
        run_search and compare.fell_rates."""
        from tkujax.studies.tune.problem import x64

        spec, seeds = self.spec, list(seeds)
        S = len(seeds) if side_by_side else 0
        with x64(spec.float64):
            problem, rep, z0, variant, m, cfg = self._setup(policy, method)
            trains = [self._train(s) for s in seeds]
            rs, clock = self._search(policy, method, m, problem, z0, trains, seeds, cfg,
                                     side_by_side)
            self.done.setdefault((policy, S), set()).update(calls_used(method))
            sets = [self.eval_sets(s) for s in seeds]
            latents = {"start": np.repeat(np.asarray(z0, float)[None], len(seeds), 0),
                       "best": np.stack([np.asarray(r["z_best"], float) for r in rs])}
            fell = self._fell(problem, latents, sets, side_by_side)
            curves = [[] for _ in seeds]
            if clock is not None:
                curves = heldout_curves(clock, latents, fell["heldout"], lambda zs: self._fell(
                    problem, zs, [{"heldout": e["heldout"]} for e in sets], side_by_side))
        return [self._record(policy, method, s, rep, variant, r,
                             {label: (f["start"][i], f["best"][i])
                              for label, f in fell.items()},
                             None if clock is None else dict(charge=clock["charge"],
                                                             curve=curves[i]))
                for i, (s, r) in enumerate(zip(seeds, rs))]


def heldout_curves(clock: dict, latents: dict, fell: dict, evaluate) -> list[list[dict]]:
    """Per seed [{wall_s, heldout_fall}] at the clock's checkpoints: the start's and the
    best's fall rates where a checkpoint's latents are theirs (no new evaluation), else
    evaluate({name: (S, k)})["heldout"]."""
    known = {name: (np.asarray(zs), fell[name]) for name, zs in latents.items()}
    todo = {f"t{i}": zs for i, (_, zs) in enumerate(clock["snapshots"])
            if not any(np.array_equal(zs, z) for z, _ in known.values())}
    got = evaluate(todo)["heldout"] if todo else {}
    out = [[] for _ in range(len(latents["start"]))]
    for i, (t, zs) in enumerate(clock["snapshots"]):
        per_seed = got.get(f"t{i}") or next(f for z, f in known.values()
                                            if np.array_equal(zs, z))
        for s, f in enumerate(per_seed):
            out[s].append(dict(wall_s=round(t, 3), heldout_fall=float(np.nanmean(f))))
    return out
