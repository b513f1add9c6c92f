"""Where an early-decision sweep's time goes: the cost of one control tick in the full-horizon
chunk program against a lane segment's, split into a fixed part per segment and a part per
tick, and the host loop's share (docs/sweeps.md, "Early decisions").

Times, on warm calls with `--lanes` lanes of the first pushes of a sweep spec:
  full      the chunk program (every push to the horizon), per push and per tick;
  segment   the segment program at each of --segment-ticks (every lane active), per call; a
            least-squares fit t = fixed + ticks x per_tick gives the fixed part (the reset,
            the outcomes read from the rows) and the early tick's cost;
  start     the start programs (fresh lanes, and from the pre-push snapshot);
  run       `run_lanes` on --pushes pushes: the wall time, and the time inside each program
            (blocked per call), the rest being the host loop.

    python scripts/profile_early.py --spec specs/sweep/scale.toml --lanes 65536 \
        --pushes 131072 --segment-ticks 4,8,16
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import functools
import time

import jax
import numpy as np

from bench_early import emit, timed   # scripts/ is on the path when this script runs

from tkujax.cli.runtime import configure_runtime
from tkujax.control.params_files import controller_params_from
from tkujax.control.controller_params import ControllerParams


def warm_time(fn, repeats: int = 3) -> float:
    """The fastest of `repeats` warm calls (after one compiling call), seconds."""
    return timed(fn, repeats + 1)[2]


def timed_fns(fns, spent: dict):
    """fns with each program blocked and timed into spent[name]."""
    def wrap(name, f):
        def call(*a, **k):
            t0 = time.perf_counter()
            out = jax.block_until_ready(f(*a, **k))
            spent[name] += time.perf_counter() - t0
            return out
        return call
    return dataclasses.replace(fns, start=wrap("start", fns.start),
                               start_snap=wrap("start_snap", fns.start_snap),
                               segment=wrap("segment", fns.segment))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default="specs/sweep/scale.toml")
    ap.add_argument("--lanes", type=int, default=16)
    ap.add_argument("--pushes", type=int, default=32)
    ap.add_argument("--segment-ticks", default="4,8")
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    configure_runtime()
    from tkujax.sweeps import early
    from tkujax.sweeps.chunk_program import (chunk_keys, make_chunk_fn, record_inputs,
                                             traced_params)
    from tkujax.dialects.sweep_spec import load_spec

    spec = load_spec(args.spec)
    recs = record_inputs(spec)
    n, L = args.pushes, args.lanes
    inputs = {k: recs[k][:n].astype(np.float32) for k in recs
              if k not in ("push_id", "from_grid", "case_id")}
    keys = chunk_keys(spec.seed, 0, max(n, spec.chunk_size))[:n]
    params = traced_params(controller_params_from(ControllerParams.paper(), spec.controller))
    lane_in = {k: jax.numpy.asarray(v[:L]) for k, v in inputs.items()}
    res = dict(lanes=L, pushes=n, duration_s=spec.duration_s,
               device=str(jax.devices()[0].device_kind), backend=jax.default_backend())

    full_fn = make_chunk_fn((), spec.duration_s, tree_passes=spec.tree_passes)
    full_s = warm_time(lambda: full_fn(lane_in, keys[:L], params))
    fns0 = early.make_lane_fns((), spec.duration_s, tree_passes=spec.tree_passes)
    n_ticks = fns0.n_ticks
    res["full"] = dict(call_s=full_s, per_push_s=full_s / L, per_tick_s=full_s / n_ticks,
                       pushes_per_s=L / full_s)
    limits = jax.numpy.full(L, n_ticks, jax.numpy.int32)
    seg = {}
    for ticks in [int(t) for t in args.segment_ticks.split(",")]:
        fns = early.make_lane_fns((), spec.duration_s, tree_passes=spec.tree_passes,
                                  segment_ticks=ticks)
        lanes = fns.start(lane_in, keys[:L], params, None, limits)
        reset = jax.numpy.zeros(L, bool)
        seg[ticks] = warm_time(functools.partial(fns.segment, lanes, lanes, reset, lane_in,
                                                 params, None))
        if ticks == fns0.segment_ticks:
            res["start_s"] = warm_time(functools.partial(fns.start, lane_in, keys[:L], params,
                                                         None, limits))
    t = np.array(sorted(seg))
    y = np.array([seg[k] for k in t])
    per_tick, fixed = np.polyfit(t, y, 1) if len(t) > 1 else (y[0] / t[0], 0.0)
    res["segment"] = dict(call_s={str(k): v for k, v in seg.items()}, fixed_s=float(fixed),
                          per_tick_s=float(per_tick),
                          per_tick_over_full=float(per_tick / res["full"]["per_tick_s"]))
    spent = collections.defaultdict(float)
    tfns = timed_fns(fns0, spent)
    jax.block_until_ready(early.run_lanes(fns0, inputs, keys, params, None, L)["fell"])
    t0 = time.perf_counter()
    out = early.run_lanes(tfns, inputs, keys, params, None, L)
    wall = time.perf_counter() - t0
    res["run"] = dict(wall_s=wall, pushes_per_s=n / wall, programs_s=dict(spent),
                      host_s=wall - sum(spent.values()),
                      mean_decided_s=float(np.mean(out[early.DECIDED_COLUMN])))
    emit(res, args.out)


if __name__ == "__main__":
    main()
