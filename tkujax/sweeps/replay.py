"""`tkujax replay RUN_DIR --index N`: re-simulate one record of a sweep, exactly as it ran.

Everything comes from the run folder: the spec (the push, the per-record controller-grid values
and model randomisation, all re-expanded from it), the controller and model parameters, and the
backend that wrote the record's chunk (its manifest entry; `record_backend`). The noise is the
sweep's too:

  MuJoCo C: the whole chunk is re-run (seed = spec seed + chunk; the numpy noise of one robot
    depends on the batch it was drawn with), so the replay is the sweep's own computation.
  MJX: the record alone, with its key from the sweep's per-chunk derivation:
    split(fold_in(PRNGKey(seed), chunk), padded_chunk)[position]. A batch of one compiles
    differently from the sweep's batch, so floats may differ in the last bits (and, after a
    fall, by more: the tumbling is chaotic); fell and diverged are what must agree. With
    exact=True the outcomes come from the sweep's own program at its shape instead
    (`tkujax.sweeps.replay_exact`), compared bit for bit.

A manifest written by an older tkujax lacks the parameter fields added since: each takes the
value that reproduces the code from before it existed (`tkujax.sweeps.record_schema`), and the
result names them (fields_missing).

The state at every control period comes back for rendering (`tkujax.render`, in the CLI: this
layer does not draw).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tkujax.control.params_files import controller_params_from
from tkujax.control.policy import schedule_from_dict
from tkujax.sim.rollout_mjx import RolloutConfig
from tkujax.sweeps import chunks
from tkujax.sweeps.chunk_program import (OUTCOME_KEYS, chunk_keys, make_chunk_fn, record_inputs,
                                         traced_params)
from tkujax.sweeps.early import TRUNCATED_WHEN_FALLEN
from tkujax.sweeps.mujoco_chunk import mujoco_chunk
from tkujax.sweeps.sweep_robot import check_robot
from tkujax.sweeps.record_schema import (fields_missing, manifest_controller_params,
                                         manifest_model_params, manifest_spec)
from tkujax.dialects.floor_table import spec_floor
from tkujax.dialects.walk_table import walk_base

RTOL, ATOL = 1e-4, 1e-5     # "identical" numbers; fell and diverged must be equal exactly


def _stored_record(run_dir: Path, manifest: dict, chunk: int, pos: int) -> dict:
    entry = manifest.get("chunks", {}).get(chunks.chunk_name(chunk))
    why = chunks.check_chunk(run_dir, chunk, entry) if "chunks" in manifest else None
    if why:
        raise chunks.ChunkError(f"{why}; rerun the sweep command to recompute it")
    with np.load(run_dir / chunks.chunk_name(chunk)) as z:
        return {k: z[k][pos] for k in z.files}


def record_backend(manifest: dict, chunk: int) -> str:
    """The backend that wrote `chunk`: its manifest entry's (record schema 6 on), else the
    manifest's (one backend per folder before), else MJX (the first sweeps')."""
    entry = manifest.get("chunks", {}).get(chunks.chunk_name(chunk)) or {}
    return entry.get("backend") or manifest.get("backend", "mjx")


def _differences(stored: dict, replayed: dict) -> dict:
    """{column: (stored, replayed)} of the columns that differ (booleans exactly, numbers
    beyond RTOL/ATOL)."""
    out = {}
    for k, v in replayed.items():
        a, b = np.asarray(stored[k]), np.asarray(v)
        same = (a == b) if a.dtype.kind == "b" else np.allclose(a, b, RTOL, ATOL, equal_nan=True)
        if not same:
            out[k] = (a.item(), b.item())
    return out


def replay(run_dir: str | Path, index: int, robot=None, exact: bool = False,
           backend: str | None = None) -> dict:
    """Re-simulate record `index` (its push_id) of the sweep in `run_dir`.

    Returns dict(index, chunk, backend, stored, replayed (outcome columns), same_outcome
    (fell and diverged equal), identical (every column within RTOL/ATOL), differences
    {column: (stored, replayed)}, qpos (n_ticks, nq), control_period_s, model_params (the
    record's robot: its ensemble member, or the sweep's model; None: the default),
    fields_missing (`tkujax.sweeps.record_schema.fields_missing`: what an older
    manifest lacks, and the value used)). robot: the Robot a robot sweep ran on (checked
    against the manifest's sha256; `tkujax.studies.robot_inputs.sweep_robot` loads it). exact (MJX):
    the outcomes by the sweep's own program (`tkujax.sweeps.replay_exact`); identical then
    means equal bit for bit, in every outcome column the chunk stores. backend: None, the one
    that wrote the record's chunk (`record_backend`); "mujoco" or "mjx" re-runs it there instead
    (a record another backend wrote then gets this backend's floats and noise: its outcome may
    differ near a fall boundary)."""
    if backend not in (None, "mujoco", "mjx"):
        raise ValueError(f"backend must be 'mujoco' or 'mjx' (None: the record's), "
                         f"got {backend!r}")
    run_dir = Path(run_dir)
    manifest = chunks.read_manifest(run_dir)
    if not manifest:
        raise FileNotFoundError(f"{run_dir} holds no sweep ({chunks.MANIFEST} not found)")
    n = int(manifest["n_pushes"])
    if not 0 <= index < n:
        raise ValueError(f"--index must be in [0, {n - 1}] (the sweep's push_id), got {index}")
    spec = manifest_spec(manifest)   # a [randomize] ensemble is read again from its path
    recorded = manifest.get("ensemble", {}).get("sha256")
    if spec.ensemble is not None and recorded and recorded != spec.ensemble.sha256:
        raise ValueError(f"the ensemble file {spec.ensemble.resolved} has changed since the sweep "
                         f"ran (sha256 {spec.ensemble.sha256[:12]}... != {recorded[:12]}...): "
                         "replay needs the sweep's robots")
    size = int(manifest["chunk_size"])
    chunk, pos = divmod(index, size)
    stored = _stored_record(run_dir, manifest, chunk, pos)
    # Fields the manifest lacks (an older tkujax wrote it) take their values from before they
    # existed (tkujax.sweeps.record_schema).
    params = manifest_controller_params(manifest,
                                        f"{run_dir / chunks.MANIFEST}: controller_params")
    # An ensemble sweep's robots are its members (the manifest's model_params is then unused).
    model_params = (None if spec.ensemble is not None else
                    check_robot(manifest, robot, str(run_dir))
                    or manifest_model_params(manifest))
    base = controller_params_from(params, spec.controller)
    # A scheduled policy's sweep (`--params POLICY.json` / `recommended`) replays with its schedule.
    schedule = (schedule_from_dict(manifest["schedule"],
                                   f"{run_dir / chunks.MANIFEST}: schedule")
                if manifest.get("schedule") is not None else None)
    recs = record_inputs(spec)
    lo, hi = chunk * size, min((chunk + 1) * size, n)
    inputs = {k: recs[k][lo:hi] for k in recs if k not in ("push_id", "from_grid")}
    backend = backend or record_backend(manifest, chunk)
    res = _rerun(spec, manifest, inputs, chunk, pos, base, model_params, schedule, backend)
    exact = exact and backend != "mujoco"      # MuJoCo C re-runs the whole chunk anyway
    replayed, differences = _compared(spec, manifest, stored, res, inputs, chunk, pos, base,
                                      model_params, schedule, exact)
    return dict(index=index, chunk=chunk, backend=backend, exact=exact,
                stored={k: stored[k].item() for k in stored},
                replayed={k: np.asarray(v).item() for k, v in replayed.items()},
                same_outcome=not ({"fell", "diverged"} & set(differences)),
                identical=not differences, differences=differences,
                fields_missing=fields_missing(manifest),
                qpos=np.asarray(res["qpos"], np.float64),
                model_params=(model_params if spec.ensemble is None else
                              spec.ensemble.members[int(stored["robot_id"])]),
                control_period_s=RolloutConfig().control_period_s)


def _rerun(spec, manifest: dict, inputs: dict, chunk: int, pos: int, base, model_params,
           schedule, backend: str) -> dict:
    """The record's outcome columns and qpos: MuJoCo C re-runs its whole chunk; MJX runs the
    record alone (with qpos, for rendering)."""
    if backend == "mujoco":
        res = mujoco_chunk(inputs, spec.seed + chunk, base, spec.duration_s, model_params,
                           with_qpos=True, varied=tuple(sorted(spec.controller_grid)),
                           steps=bool(spec.step_grid),
                           fpga=spec.fpga if spec.arithmetic == "fixed" else None,
                           fpga_varied=tuple(sorted(spec.fpga_grid)), ensemble=spec.ensemble,
                           schedule=schedule, walk=walk_base(spec),
                           floor=spec_floor(spec))
        return {k: v[pos] for k, v in res.items()}
    import jax

    padded = int(manifest.get("padded_chunk", spec.chunk_size))
    fn = make_chunk_fn(tuple(sorted(spec.controller_grid)), spec.duration_s,
                       model_params, with_qpos=True, steps=bool(spec.step_grid),
                       fixed=spec.fixed_point_config({k: v[pos] for k, v in inputs.items()}),
                       ensemble=spec.ensemble, tree_passes=spec.tree_passes,
                       walk=walk_base(spec), floor=spec_floor(spec))
    one = {k: np.asarray(v[pos:pos + 1], np.float32) for k, v in inputs.items()}
    key = chunk_keys(spec.seed, chunk, padded)[pos:pos + 1]
    return jax.tree_util.tree_map(lambda x: np.asarray(x)[0],
                                  fn(one, key, traced_params(base), schedule))


def _compared(spec, manifest, stored: dict, res: dict, inputs, chunk, pos, base, model_params,
              schedule, exact: bool) -> tuple[dict, dict]:
    """(replayed outcome columns, {column: (stored, replayed)} that differ). exact: the
    columns of the sweep's own program, compared bit for bit."""
    if exact:
        from tkujax.sweeps.replay_exact import bitwise_differences, exact_outcomes

        out = exact_outcomes(spec, manifest, inputs, chunk, pos, base, model_params, schedule)
        replayed = {k: v for k, v in out.items() if k in stored}
        return replayed, bitwise_differences(stored, replayed)
    replayed = {k: res[k] for k in OUTCOME_KEYS if k in stored}
    if spec.decisions.early and bool(stored["fell"]):
        # The replay runs the full horizon; an early record read these up to its fall.
        replayed = {k: v for k, v in replayed.items() if k not in TRUNCATED_WHEN_FALLEN}
    return replayed, _differences(stored, replayed)
