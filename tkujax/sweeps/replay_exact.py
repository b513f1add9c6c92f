"""A sweep record re-run by the sweep's own MJX program (`tkujax replay --exact`).

`tkujax.sweeps.replay` re-simulates an MJX record alone, in a batch of one: another compiled
program, so its floats may differ from the stored ones in the last bits. Here the record runs
in the program the sweep ran, at the sweep's shape:

  full horizon  the chunk program at the padded chunk's batch, on the same devices, every
                entry of the batch the record itself (one entry's computation does not read
                another's, so which records sit beside it does not matter);
  early         the lanes of `[sweep] decisions = "early"` (`tkujax.sweeps.early`), as many
                as the sweep had, the record in the first lane and the others idle; a lane's
                record does not depend on its lane or its neighbours (tests/test_early.py).

On the device kind the sweep ran on, the outcomes then equal the stored ones bit for bit
(tests/test_replay.py on a CPU). The cost is a chunk's (or a batch of lanes'): seconds on a
GPU, minutes on a CPU for large chunks.
"""

from __future__ import annotations

import math

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from tkujax.sweeps.chunk_program import chunk_keys, make_chunk_fn, traced_params
from tkujax.sweeps.early import make_lane_fns, run_lanes
from tkujax.dialects.floor_table import spec_floor
from tkujax.dialects.walk_table import walk_base


def _sharding() -> NamedSharding:
    devices = jax.local_devices()     # as `tkujax.sweeps.sweep.run_sweep` shards a chunk
    return NamedSharding(Mesh(np.array(devices), ("push",)), PartitionSpec("push"))


def exact_outcomes(spec, manifest: dict, inputs: dict, chunk: int, pos: int, base,
                   model_params, schedule) -> dict:
    """{column: value} of record `pos` of chunk `chunk` (inputs: the chunk's input columns)
    by the sweep's own program and shape. base: the sweep's ControllerParams with its
    [controller] values; model_params and schedule as the sweep ran them."""
    sharding = _sharding()
    n_devices = len(sharding.mesh.devices.flat)
    padded = int(manifest.get("padded_chunk", spec.chunk_size))
    # The sweep's input columns (`tkujax.sweeps.sweep._ChunkJob.input_keys`): the same
    # arguments, so the same program.
    one = {k: np.asarray(v[pos:pos + 1]) for k, v in inputs.items() if k != "case_id"}
    fixed = spec.fixed_point_config({k: v[0] for k, v in one.items()})
    varied, steps = tuple(sorted(spec.controller_grid)), bool(spec.step_grid)
    keys = np.asarray(chunk_keys(spec.seed, chunk, padded))[pos:pos + 1]
    if spec.decisions.early:
        fns = make_lane_fns(varied, spec.duration_s, model_params, steps, fixed, spec.ensemble,
                            spec.tree_passes, spec.decisions.segment_ticks, walk_base(spec))
        n_lanes = math.ceil(spec.decisions.lanes / n_devices) * n_devices
        out = run_lanes(fns, {k: v.astype(np.float32) for k, v in one.items()}, keys,
                        traced_params(base), schedule, n_lanes, sharding, snapshot=False,
                        steps=steps)
        return {k: np.asarray(v)[0] for k, v in out.items()}
    fn = make_chunk_fn(varied, spec.duration_s, model_params, steps=steps, fixed=fixed,
                       ensemble=spec.ensemble, tree_passes=spec.tree_passes,
                       walk=walk_base(spec), floor=spec_floor(spec))
    rows = np.zeros(padded, np.int64)
    batch = {k: jax.device_put(v[rows].astype(np.float32), sharding) for k, v in one.items()}
    out = fn(batch, jax.device_put(keys[rows], sharding), traced_params(base), schedule)
    return {k: np.asarray(v)[0] for k, v in out.items()}


def bitwise_differences(stored: dict, replayed: dict) -> dict:
    """{column: (stored, replayed)} of the columns whose bits differ (NaN equals NaN)."""
    out = {}
    for k, v in replayed.items():
        a, b = np.asarray(stored[k]), np.asarray(v).astype(np.asarray(stored[k]).dtype)
        if a.tobytes() != b.tobytes():
            out[k] = (a.item(), b.item())
    return out
