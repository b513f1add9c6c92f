"""`tkujax calibrate SPEC --out DIR`: fit the model's unknown parameters to the paper's Tables 4-5.

CMA-ES with IPOP restarts (the maintained `cmaes` package) in the unit cube of the fitted
parameters' bounds; one runner per objective ("ALL": 8 rows; "T4": Table 4, Table 5 held out),
interleaved generation by generation. Every candidate is simulated on all 8 rows, every chosen
reading of Algorithm 1 and every hit phase, and appended to DIR/archive.jsonl as soon as it is
scored. A rerun with the same spec replays the archive: CMA-ES is deterministic for a seed, so it
asks the same candidates again, and those already in the archive are read back, not simulated,
which resumes the search where it stopped. Then the report: best.json, calibration.md,
search_trace.png, model_params.json and controller_params.json of the best fit.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import time
from pathlib import Path

import numpy as np

from tkujax.studies.calibrate import fit_vector as P
from tkujax.sweeps.progress import StatusLog
from tkujax.studies.calibrate.calibrate_spec import CalibrateSpec, load_calibrate_spec
from tkujax.dialects.validation import SpecError
from tkujax.studies.calibrate.scoring import (CRITERION_P, FAILED_LOSS, OBJECTIVE_ROWS, Evaluator,
                                              criterion_shortfall, expected_rows, score)
from tkujax.studies.calibrate.calibration_outputs import score_many, write_report

__all__ = ["run_calibrate", "score", "expected_rows", "criterion_shortfall", "CRITERION_P",
           "FAILED_LOSS", "OBJECTIVE_ROWS", "Evaluator", "write_report"]
def _key(x: dict) -> tuple:
    # JSON round-trips floats exactly (repr), so an archived x matches a re-asked one bit for bit
    return tuple(float(x[n]) for n in P.NAMES)


class Archive:
    """DIR/archive.jsonl: one scored candidate per line, flushed as it is written."""

    def __init__(self, path: Path, digest: str):
        self.path, self.digest = path, digest
        self.records: list[dict] = []
        if path.exists():
            text = path.read_text()
            if text and not text.endswith("\n"):
                # a line cut by an interruption: drop it, so the next append starts a new line
                text = text[:text.rfind("\n") + 1]
                path.write_text(text)
            for n, line in enumerate(text.splitlines(), 1):
                if line.strip():
                    rec = json.loads(line)
                    rec["x"] = P.complete(rec["x"])      # archived before NEUTRAL names
                    if rec.get("spec") != digest:
                        raise SpecError(f"{path}:{n}: archived by a different fit (spec digest "
                                        f"{rec.get('spec')}, this spec {digest}): its losses "
                                        "are not comparable; use another --out")
                    self.records.append(rec)
        self.cache = {_key(r["x"]): r for r in self.records}
        self._fh = open(path, "a")

    def add(self, rec: dict) -> None:
        rec["spec"] = self.digest
        self._fh.write(json.dumps(rec) + "\n")
        self._fh.flush()
        self.records.append(rec)
        self.cache.setdefault(_key(rec["x"]), rec)

    def close(self) -> None:
        self._fh.close()


class Runner:
    """CMA-ES on one objective in the unit cube of the fitted parameters; IPOP restarts."""

    def __init__(self, objective: str, spec: CalibrateSpec, seed: int):
        self.objective, self.spec, self.seed = objective, spec, seed
        self.idx = [P.NAMES.index(n) for n in spec.params]
        self.lo = np.array([spec.bounds[n][0] for n in spec.params])
        self.hi = np.array([spec.bounds[n][1] for n in spec.params])
        self.popsize, self.restarts, self.gen, self.done = spec.popsize, 0, 0, False
        self.best = (math.inf, None)
        start = np.array([spec.start[n] for n in spec.params])
        self._new((start - self.lo) / (self.hi - self.lo))

    def _new(self, mean: np.ndarray) -> None:
        from cmaes import CMA

        bounds = np.tile([0.0, 1.0], (len(self.idx), 1))
        self.opt = CMA(mean=np.clip(mean, 0.02, 0.98), sigma=self.spec.sigma0, bounds=bounds,
                       seed=self.seed + 97 * self.restarts, population_size=self.popsize)
        self.stall, self.gen_best = 0, math.inf

    def full(self, u: np.ndarray) -> dict:
        """A candidate with every name: fitted ones from u, the others at their held values."""
        x = dict(self.spec.start)
        for n, v in zip(self.spec.params, self.lo + np.clip(u, 0.0, 1.0) * (self.hi - self.lo)):
            x[n] = float(v)
        return x

    def generation(self, run_many, evals_left: int) -> int:
        """Ask, score (run_many: list of x -> records), tell. Returns candidates used; a
        generation cut short by the evaluation budget is not told (a rerun re-asks it)."""
        us = [self.opt.ask() for _ in range(self.opt.population_size)]
        recs = run_many([self.full(u) for u in us[:max(evals_left, 0)]], self)
        if len(recs) < len(us):
            return len(recs)
        sols = []
        for u, rec in zip(us, recs):
            f = min(rec["loss"][self.objective][r] for r in self.spec.readings)
            sols.append((u, f))
            if f < self.best[0]:
                self.best = (f, rec)
        self.opt.tell(sols)
        self.gen += 1
        g = min(f for _, f in sols)
        self.stall = 0 if g < self.gen_best - 1e-3 else self.stall + 1
        self.gen_best = min(self.gen_best, g)
        if self.stall >= 6 or self.opt.should_stop():
            if self.restarts >= self.spec.restarts:
                self.done = True
            else:      # IPOP: double the population, restart from a random point of the cube
                self.restarts += 1
                self.popsize *= 2
                rng = np.random.default_rng(self.seed + self.restarts)
                self._new(rng.uniform(0.1, 0.9, len(self.idx)))
        return len(recs)


def run_calibrate(spec: CalibrateSpec | str | Path, out: str | Path, *,
                  evaluator: Evaluator | None = None, quiet: bool = False) -> dict:
    """Run (or resume) a calibration into `out`; returns the best.json summary.

    evaluator: replaces the MuJoCo evaluation (evaluate.evaluate_phases), for tests; it runs in
    this process (search.workers applies to the MuJoCo evaluation only)."""
    spec = spec if isinstance(spec, CalibrateSpec) else load_calibrate_spec(spec)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    archive = Archive(out / "archive.jsonl", spec.fit_digest())   # refuses another fit's
    (out / "spec.json").write_text(json.dumps(dataclasses.asdict(spec), indent=1) + "\n")
    n_cached = len(archive.records)
    log = StatusLog(quiet, budget_s=spec.budget_s, desc="calibrate ")
    pool = None
    if spec.workers > 1 and evaluator is None and spec.backend == "mujoco":
        import multiprocessing as mp

        os.environ.setdefault("TKUJAX_CAL_THREADS", "1")   # one MuJoCo thread per worker
        pool = mp.get_context("spawn").Pool(spec.workers)
    scorer = functools.partial(score, readings=spec.readings, hit_phases_ms=spec.samples,
                               evaluator=evaluator, criterion_weight=spec.criterion_weight)
    counts = dict(evals=0, simulated=0)
    t0 = time.time()

    def run_many(xs: list[dict], runner: Runner | None) -> list[dict]:
        new = [x for x in xs if _key(x) not in archive.cache]
        new = list({_key(x): x for x in new}.values())          # a generation may repeat one
        if spec.backend == "mjx" and evaluator is None and new:   # the generation in one batch
            recs = score_many(spec, new, spec.readings, evaluator)
        else:
            recs = (pool.map(scorer, new) if (pool is not None and len(new) > 1)
                    else map(scorer, new))
        for _x, rec in zip(new, recs):
            rec.update(objective=runner.objective if runner else "start",
                       restart=runner.restarts if runner else 0,
                       gen=runner.gen if runner else -1, t=round(time.time() - t0, 3))
            archive.add(rec)
        counts["evals"] += len(xs)
        counts["simulated"] += len(new)
        return [archive.cache[_key(x)] for x in xs]

    def evals_left() -> int:
        return (spec.max_evals - counts["evals"]) if spec.max_evals is not None else 1 << 60

    def time_left() -> bool:
        return spec.budget_s is None or time.time() - t0 < spec.budget_s

    try:
        start_rec = run_many([dict(spec.start)], None)[0]     # the start point, for reference
        runners = [Runner(o, spec, spec.seed + i) for i, o in enumerate(spec.objectives)]
        while evals_left() > 0 and time_left() and not all(r.done for r in runners):
            for r in runners:
                if r.done or evals_left() <= 0 or not time_left():
                    continue
                r.generation(run_many, evals_left())
                cap = f"/{spec.max_evals}" if spec.max_evals is not None else ""
                log(f"[{time.time() - t0:6.0f} s] candidates {counts['evals']}{cap} "
                    f"(simulated {counts['simulated']}, from the archive "
                    f"{counts['evals'] - counts['simulated']})  {r.objective}: restart "
                    f"{r.restarts} gen {r.gen} best {r.best[0]:.3f}")
    finally:
        archive.close()
        if pool is not None:
            pool.close()
    stopped = ("max_evals" if evals_left() <= 0 else "all runners done"
               if all(r.done for r in runners) else "budget_s")
    search = dict(wall_s=round(time.time() - t0, 1), candidates_this_run=counts["evals"],
                  simulated_this_run=counts["simulated"], archived_before=n_cached,
                  stopped_by=stopped, cpu_count=os.cpu_count(), workers=spec.workers)
    log(f"search stopped by {stopped} after {search['wall_s']} s; writing the report")
    return write_report(spec, out, archive.records, start_rec, search, evaluator)


