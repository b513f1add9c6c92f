"""Global gradient-free search: CMA-ES (the maintained `cmaes` package, CyberAgent) in the unit
cube of the bounded parameter vector, with restarts (IPOP: population doubled on each restart,
restart on stagnation), two objectives interleaved generation by generation:

  "T4":  Table 4 rows only (pushes from behind)  -> its best is the held-out predictor of Table 5
  "ALL": all 8 rows

Every candidate is simulated on all 8 rows and every reading of Algorithm 1, and appended to an
archive (JSONL), so each objective can also be re-scored from the archive. The objective of a
candidate is the stand-lean penalty plus the minimum over readings of the table loss (the
discrete reading is profiled out); the archive keeps the per-reading losses for model selection.

python -m tkujax.studies.calibrate.search --budget-s 1500 --out results/calibration
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
from cmaes import CMA

from tkujax.studies.calibrate import evaluate as E
from tkujax.studies.calibrate import params as P
from tkujax.studies.calibrate import targets as T

OBJECTIVES = {"T4": T.TABLE4, "ALL": T.ROWS}


def _key(k) -> str:
    return "/".join(k)


def score_candidate(x: np.ndarray) -> dict:
    """Simulate x; per reading and objective the loss; the record written to the archive."""
    try:
        res = E.evaluate(x)
    except Exception as err:  # noqa: BLE001  (an invalid model: a penalty, not a crash)
        return dict(x=P.as_dict(x), error=repr(err),
                    loss={o: {r: 1e3 for r in P.READINGS} for o in OBJECTIVES})
    any_r = next(iter(res.values()))
    pen = E.stand_penalty(any_r)
    loss = {o: {r: pen + T.table_loss(res[r], rows)[0] for r in res} for o, rows in OBJECTIVES.items()}
    return dict(x=P.as_dict(x), stand_penalty=pen, loss=loss,
                rows={r: {_key(k): v for k, v in res[r].items()} for r in res})


class Runner:
    def __init__(self, name: str, x0: np.ndarray, seed: int, popsize: int, sigma: float = 0.25):
        self.name, self.seed, self.popsize, self.sigma = name, seed, popsize, sigma
        self.restarts = 0
        self.best = (math.inf, None)
        self._new(P.to_unit(x0))

    def _new(self, mean):
        bounds = np.tile([0.0, 1.0], (len(P.NAMES), 1))
        self.opt = CMA(mean=np.clip(mean, 0.02, 0.98), sigma=self.sigma, bounds=bounds,
                       seed=self.seed + 97 * self.restarts, population_size=self.popsize)
        self.stall, self.gen_best = 0, math.inf

    def generation(self, archive, pool=None) -> None:
        sols = []
        us = [self.opt.ask() for _ in range(self.opt.population_size)]
        xs = [P.from_unit(u) for u in us]
        recs = pool.map(score_candidate, xs) if pool is not None else map(score_candidate, xs)
        for u, rec in zip(us, recs):
            rec.update(objective=self.name, restart=self.restarts, t=time.time())
            archive.write(json.dumps(rec) + "\n")
            archive.flush()
            f = min(rec["loss"][self.name].values())
            sols.append((u, f))
            if f < self.best[0]:
                self.best = (f, rec)
        self.opt.tell(sols)
        g = min(f for _, f in sols)
        self.stall = 0 if g < self.gen_best - 1e-3 else self.stall + 1
        self.gen_best = min(self.gen_best, g)
        if self.stall >= 6 or self.opt.should_stop():
            # IPOP restart: double the population, restart from a random point of the cube
            self.restarts += 1
            self.popsize *= 2
            rng = np.random.default_rng(self.seed + self.restarts)
            self._new(rng.uniform(0.1, 0.9, len(P.NAMES)))


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--budget-s", type=float, default=1500.0)
    ap.add_argument("--out", default="results/calibration")
    ap.add_argument("--popsize", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--objectives", default="T4,ALL")
    ap.add_argument("--workers", type=int, default=0,
                    help="processes evaluating a generation in parallel (0: in this process); "
                         "each uses MuJoCo threads = its CPU share")
    a = ap.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    # Start near today's model with the toe margin that the README's sensitivity singled out.
    x0 = P.DEFAULT.copy()
    x0[P.NAMES.index("foot_forward_offset_m")] = -0.028
    runners = [Runner(o, x0, a.seed + i, a.popsize) for i, o in enumerate(a.objectives.split(","))]
    t0 = time.time()
    pool = None
    if a.workers > 1:
        import multiprocessing as mp
        import os
        os.environ.setdefault("TKUJAX_CAL_THREADS", "1")
        pool = mp.get_context("spawn").Pool(a.workers)
    with open(out / "archive.jsonl", "a") as archive:
        gen = 0
        while time.time() - t0 < a.budget_s:
            for r in runners:
                r.generation(archive, pool)
                print(f"[{time.time() - t0:6.0f}s] gen {gen} {r.name} restart {r.restarts} "
                      f"best {r.best[0]:.3f} gen-best {r.gen_best:.3f}", flush=True)
            gen += 1
    best = {r.name: dict(loss=r.best[0], record=r.best[1]) for r in runners}
    (out / "search_best.json").write_text(json.dumps(best, indent=1))


if __name__ == "__main__":
    main()
