"""Is a sweep chunk repeatable on this device? (results/scale/determinism_h200.json)

Compiles the chunk program of specs/sweep/stability_map.toml once per variant, calls it three
times on the same records and keys in one process, and counts the rows of each later call that
differ from the first (NaN equal to NaN), with the time per call. Variants: the tree passes
("compact", the sweeps' default, or "mjx"), optionally with XLA's deterministic ops.

    python scripts/sweep_repeatability.py --out OUT.json --batch 16384 --variants compact,mjx
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time

import jax
import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.sweeps import chunk_program
from tkujax.dialects.sweep_spec import load_spec


def rows_differing(a: dict, b: dict) -> dict[str, int]:
    out = {}
    for k in a:
        x, y = np.asarray(a[k], float), np.asarray(b[k], float)
        out[k] = int(np.sum(~((x == y) | (np.isnan(x) & np.isnan(y)))))
    return out


def run_variant(spec, batch, keys, params, tree_passes: str, deterministic_ops: bool) -> dict:
    chunk_program._make_chunk_fn.cache_clear()
    # XLA's options are per program (SWEEP_COMPILER_OPTIONS, read when the chunk is built).
    base = dict(chunk_program.SWEEP_COMPILER_OPTIONS)
    if deterministic_ops:
        chunk_program.SWEEP_COMPILER_OPTIONS = base | {"xla_gpu_deterministic_ops": True}
    try:
        fn = chunk_program.make_chunk_fn((), spec.duration_s, tree_passes=tree_passes)
        t0 = time.perf_counter()
        first = jax.block_until_ready(fn(batch, keys, params))
        first_s, calls, diffs = time.perf_counter() - t0, [], []
        for _ in range(2):
            t0 = time.perf_counter()
            again = jax.block_until_ready(fn(batch, keys, params))
            calls.append(time.perf_counter() - t0)
            diffs.append(rows_differing(first, again))
    finally:
        chunk_program.SWEEP_COMPILER_OPTIONS = base
    n = len(keys)
    return {"first_call_s": first_s, "call_s": calls, "pushes_per_s": n / min(calls),
            "rows_differing": diffs, "fell_rate": float(np.mean(np.asarray(first["fell"])))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--batch", type=int, default=16384)
    ap.add_argument("--variants", default="compact,mjx",
                    help="comma list of TREE_PASSES[+det] (+det: XLA's deterministic ops)")
    args = ap.parse_args()
    spec = load_spec("specs/sweep/stability_map.toml")
    rec = chunk_program.record_inputs(spec)
    pick = np.random.default_rng(0).permutation(len(rec["impulse_ns"]))[:args.batch]
    batch = {k: np.asarray(v)[pick].astype(np.float32) for k, v in rec.items()
             if k not in ("push_id", "from_grid")}
    keys = chunk_program.chunk_keys(spec.seed, 0, len(pick))
    params = chunk_program.traced_params(dataclasses.replace(ControllerParams.paper(),
                                                             lateral_steps=1))
    out = {"device": jax.devices()[0].device_kind, "batch": len(pick), "runs": {}}
    for variant in args.variants.split(","):
        passes, _, det = variant.partition("+")
        out["runs"][variant] = run_variant(spec, batch, keys, params, passes, det == "det")
        print(variant, json.dumps(out["runs"][variant]), flush=True)
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
