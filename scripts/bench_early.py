"""Pushes per second with early decisions against the full horizon, on the same pushes and
build, and their fall agreement (docs/sweeps.md, "Early decisions").

Takes the first --pushes records of a sweep spec (chunk 0's noise keys), runs them once
through the full-horizon chunk program (one batch) and once through the early-decision lanes
(--lanes lanes, refilled), each timed on a second, warm call, and prints JSON: pushes_per_s of
both modes, their ratio, the fall agreement and the mean decision time.

    python scripts/bench_early.py --spec specs/sweep/scale.toml --pushes 131072 --lanes 65536

With --chunk C it instead streams the pushes as chunks of C (each chunk's own noise keys, as a
sweep does) through the lanes twice: one chunk at a time (the lanes drain at every chunk's end)
and with refill across chunk boundaries (`tkujax.sweeps.lane_stream`), and prints both modes'
pushes/s, the fraction of lane-segments idle (no push in the lane) and whether the records
are the same bit for bit.

    python scripts/bench_early.py --pushes 1024 --chunk 128 --lanes 64
"""
from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import time

import jax
import numpy as np

from tkujax.cli.runtime import configure_runtime
from tkujax.control.params_files import controller_params_from
from tkujax.control.controller_params import ControllerParams


def timed(fn, repeats: int = 2) -> tuple[object, float, float]:
    """(result, first call s, fastest later call s)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - t0
    best = float("inf")
    for _ in range(repeats - 1):
        t0 = time.perf_counter()
        out = jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - t0)
    return out, first, best


def emit(res: dict, out: str | None) -> None:
    """Print res as JSON, and also write it to `out` when given."""
    text = json.dumps(res, indent=1)
    print(text)
    if out:
        with open(out, "w") as fh:
            fh.write(text + "\n")


def measure(spec, n: int, lanes: int, repeats: int = 2) -> dict:
    """Full horizon and early decisions on the first n records of `spec`."""
    from tkujax.sweeps import early
    from tkujax.sweeps.chunk_program import (chunk_keys, make_chunk_fn, record_inputs,
                                             traced_params)

    recs = record_inputs(spec)
    inputs = {k: recs[k][:n].astype(np.float32) for k in recs
              if k not in ("push_id", "from_grid", "case_id")}
    keys = chunk_keys(spec.seed, 0, max(n, spec.chunk_size))[:n]
    params = traced_params(controller_params_from(ControllerParams.paper(), spec.controller))
    full_fn = make_chunk_fn((), spec.duration_s, tree_passes=spec.tree_passes)
    batch = {k: jax.numpy.asarray(v) for k, v in inputs.items()}
    full, full_first, full_s = timed(lambda: full_fn(batch, keys, params), repeats)
    fns = early.make_lane_fns((), spec.duration_s, tree_passes=spec.tree_passes,
                              segment_ticks=spec.decisions.segment_ticks)
    got, early_first, early_s = timed(
        lambda: early.run_lanes(fns, inputs, keys, params, None, lanes), repeats)
    fell_full, fell_early = np.asarray(full["fell"]), np.asarray(got["fell"])
    return dict(pushes=n, lanes=lanes, duration_s=spec.duration_s,
                segment_ticks=spec.decisions.segment_ticks,
                pushes_per_s=n / early_s, baseline_pushes_per_s=n / full_s,
                speedup=full_s / early_s, fell_agreement=float(np.mean(fell_full == fell_early)),
                fell_rate=float(np.mean(fell_full)),
                mean_decided_s=float(np.mean(got[early.DECIDED_COLUMN])),
                first_call_s={"full": full_first, "early": early_first},
                device=str(jax.devices()[0].device_kind), backend=jax.default_backend())


def measure_refill(spec, n: int, lanes: int, chunk: int, repeats: int = 2) -> dict:
    """Early decisions on the first n records of `spec` in chunks of `chunk`, one chunk at a
    time and with refill across chunks."""
    from tkujax.sweeps import early
    from tkujax.sweeps.chunk_program import chunk_keys, record_inputs, traced_params
    from tkujax.sweeps.lane_stream import LaneStream

    recs = record_inputs(spec)
    inputs = {k: recs[k][:n] for k in recs if k not in ("push_id", "from_grid", "case_id")}
    params = traced_params(controller_params_from(ControllerParams.paper(), spec.controller))
    fns = early.make_lane_fns((), spec.duration_s, tree_passes=spec.tree_passes,
                              segment_ticks=spec.decisions.segment_ticks)
    bounds = [(lo, min(lo + chunk, n)) for lo in range(0, n, chunk)]
    keys = [np.asarray(chunk_keys(spec.seed, i, chunk))[:hi - lo]
            for i, (lo, hi) in enumerate(bounds)]

    def run(cross: bool):
        stream, out = LaneStream(lanes, params, None, cross=cross), {}
        todo = list(range(len(bounds)))

        def more(idle):
            if not todo:
                return []
            i = todo.pop(0)
            lo, hi = bounds[i]
            return [stream.part(i, fns, {k: v[lo:hi] for k, v in inputs.items()}, keys[i])]

        stream.run(more, lambda part: out.__setitem__(part.label, part.out))
        cols = {k: np.concatenate([out[i][k] for i in range(len(bounds))]) for k in out[0]}
        return cols, stream.stats

    res = dict(pushes=n, chunk=chunk, lanes=lanes, duration_s=spec.duration_s,
               segment_ticks=spec.decisions.segment_ticks,
               device=str(jax.devices()[0].device_kind), backend=jax.default_backend())
    got = {}
    for name, cross in (("one_chunk_at_a_time", False), ("across_chunks", True)):
        (cols, stats), first, best = timed(functools.partial(run, cross), repeats)
        got[name] = cols
        res[name] = dict(pushes_per_s=n / best, first_call_s=first, **stats,
                         idle_fraction=stats["idle_lane_segments"] / stats["lane_segments"])
    res["speedup"] = (res["across_chunks"]["pushes_per_s"]
                      / res["one_chunk_at_a_time"]["pushes_per_s"])
    a, b = got.values()
    res["identical"] = all(np.array_equal(a[k], b[k], equal_nan=True) for k in a)
    return res


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default="specs/sweep/scale.toml")
    ap.add_argument("--pushes", type=int, default=64)
    ap.add_argument("--lanes", type=int, default=16)
    ap.add_argument("--chunk", type=int, default=None,
                    help="compare one chunk at a time with refill across chunks of this size")
    ap.add_argument("--duration-s", type=float, default=None, help="override the spec's")
    ap.add_argument("--repeats", type=int, default=2, help="calls per mode (the first compiles)")
    ap.add_argument("--out", default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    configure_runtime()
    from tkujax.dialects.sweep_spec import load_spec

    spec = load_spec(args.spec)
    if args.duration_s is not None:
        spec = dataclasses.replace(spec, duration_s=args.duration_s)
    if args.chunk:
        res = measure_refill(spec, args.pushes, args.lanes, args.chunk, max(2, args.repeats))
    else:
        res = measure(spec, args.pushes, args.lanes, max(2, args.repeats))
    emit(res, args.out)


if __name__ == "__main__":
    main()
