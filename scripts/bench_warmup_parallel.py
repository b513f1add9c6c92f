"""Does compiling the tuner's programs side by side shorten its start? (results/bench/*warmup_parallel*.jsonl)

`run_search` calls, before its clock starts, each compiled function the method uses once: the
forward, the population call (CMA-ES, hybrid) and the grouped gradient (gradient, hybrid). One
after the other they cost the sum of their compiles. XLA compiles with the GIL released, so in
threads the compiles overlap and only the Python tracing stays serial.

    python scripts/bench_warmup_parallel.py SPEC BATCH DURATION_S serial|parallel [OUT.jsonl]

One mode per process, into an empty persistent cache: the wall time of the hybrid method's
warm-up (forward, population of `popsize`, grouped gradient), each call's own wall time
(`call_s`, from its start; side by side they overlap), and each call's value, to check the two
modes compute the same.
"""
# ruff: noqa: E501   (research script)

import json
import sys
import time

import jax
import numpy as np

from tkujax.sweeps.compile_cache import fresh_compilation_cache
from tkujax.studies.tune import search
from tkujax.studies.tune.search import SearchConfig, warm_up_calls
from tkujax.studies.tune.tune_spec import load_tune_spec, make_problem, sample_pushes


CALL_S: dict[str, float] = {}


def _timed_warm_up(calls, parallel=True):
    """search.warm_up, recording each call's own wall time (from its start, in its thread)."""

    def timed(name, call):
        def run():
            t0 = time.perf_counter()
            out = call()
            CALL_S[name] = round(time.perf_counter() - t0, 2)
            return out

        return run

    return _WARM_UP({name: timed(name, c) for name, c in calls.items()}, parallel)


_WARM_UP, search.warm_up = search.warm_up, _timed_warm_up


def main(spec_path: str, batch: int, duration_s: float, mode: str, out: str | None) -> None:
    spec = load_tune_spec(spec_path)
    problem = make_problem(spec, duration_s=duration_s)
    z0 = problem.reparam.latent_of(spec.base_params())
    pushes = sample_pushes(spec, batch, spec.seed)
    keys = jax.random.split(jax.random.PRNGKey(spec.seed), batch)
    cfg = SearchConfig(popsize=spec.popsize, groups=4 if batch % 4 == 0 else 1)
    with fresh_compilation_cache():
        pushes = problem.with_off_survived(pushes, keys)
        t0 = time.perf_counter()
        values = warm_up_calls(
            "hybrid", problem, z0, pushes, keys, cfg, parallel=mode == "parallel"
        )
        wall = time.perf_counter() - t0
    row = dict(
        device=str(jax.devices()[0]),
        spec=spec_path,
        batch=batch,
        duration_s=duration_s,
        mode=mode,
        warm_up_s=round(wall, 2),
        call_s=CALL_S,
        hard0=float(np.asarray(values["forward"])),
        population=np.asarray(values["population"]).tolist(),
        grads=np.asarray(values["gradient"]).tolist(),
    )
    print(json.dumps(row))
    if out:
        with open(out, "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main(
        sys.argv[1],
        int(sys.argv[2]),
        float(sys.argv[3]),
        sys.argv[4],
        sys.argv[5] if len(sys.argv) > 5 else None,
    )
