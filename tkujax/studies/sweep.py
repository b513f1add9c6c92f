"""`tkujax sweep`: thousands of pushes in batches, written in chunks, resumable.

Records are columnar `.npz` chunks (numpy's own format: readable with plain numpy, no extra
dependency, one file per chunk so a crash loses at most the chunk in flight). The chunk store
(`tkujax.studies.chunks`) writes each chunk atomically, records its sha256 and row count in the
manifest, and lets several writers share one folder through claims; a rerun verifies every
chunk, recomputes a missing, truncated or corrupted one, and recomputes nothing else.

Devices: each chunk is sharded along the push axis over this process's local devices
(`jax.sharding`: a 1-D mesh, NamedSharding P("push")); the rollout is embarrassingly parallel,
so XLA partitions it with no communication. Several processes (hosts): call with
`process_id`/`num_processes`/`coordinator` (or the TKUJAX_* environment variables), which runs
`jax.distributed.initialize`; process k computes chunks k, k + n, k + 2n, ... into the same
output folder (a shared file system across hosts).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from tkujax.control.controller import StepOverride
from tkujax.control.fixed import FixedPointConfig, check_supported
# The ControllerParams JSON loader and the spec-style overrides live in tkujax.control.io;
# re-exported here under the names sweeps have used.
from tkujax.control.io import controller_params_from
from tkujax.control.io import load_controller_params_json as load_params_json  # noqa: F401
from tkujax.control.params import ControllerParams
from tkujax.control.policy import Schedule, schedule_to_dict
from tkujax.model import ModelParams
from tkujax.sim.metrics import CAPTURE_KEYS, capture_outcomes
from tkujax.sim.metrics import outcomes as rollout_outcomes
from tkujax.sim.push import Push
from tkujax.sim.randomize import randomize_model
from tkujax.sim.rollout_mjx import Episode, ProgramOptions, RolloutConfig, rollout
from tkujax.sim.setup import init
from tkujax.studies import chunks
from tkujax.studies.progress import Progress
from tkujax.studies.provenance import git_commit, versions
from tkujax.studies.spec import (FPGA_COLUMN, ROBOT_ID_COLUMN, EnsembleRef, SpecError, SweepSpec,
                                 fixed_point_config, load_spec)

# lax.scan unrolling of each control tick's physics substeps in the sweeps' program
# (RolloutConfig.unroll_substeps; 1: a rolled loop). Same arithmetic, another loop structure.
# Rolled, because on an H200 x3 gained 2 % pushes/s for ~2x the compile and x15 (the whole
# tick) took 10x the compile (results/bench/README.md); `tkujax bench --unroll-substeps 1,3`
# times the choices again.
SWEEP_UNROLL_SUBSTEPS = 1
# The sweeps' loop structure (RolloutConfig.loop) and XLA options. One flat scan over physics
# steps, with the control tick and the records in lax.conds, and CUDA graphs (command buffers)
# for runs of any length between loops and library calls (XLA's default leaves runs shorter
# than 5 kernels out): on an H100 at batch 1,024 the closed loop then costs 12.8 ms per control
# tick against 14.4 nested with XLA's defaults, and raw MJX 11.9 either way; neither change
# alone gains (results/bench/README.md, session 12). XLA options are per program here, not
# process-wide; on a CPU the GPU option is ignored.
SWEEP_LOOP = "flat"
SWEEP_COMPILER_OPTIONS = {"xla_gpu_graph_min_graph_size": 1}

OUTCOME_KEYS = ("fell", "diverged", "recovery_time_s", "step_length_m", "step_width_m",
                "peak_incl_deg", "capture_point_m", "capture_point_y_m", "zmp_excursion_m")
MANIFEST = chunks.MANIFEST
# ControllerParams fields added after sweeps were first written, at their defaults (their "off"
# values, read from the dataclass so the two cannot drift apart): a sweep that leaves them off
# keeps its hash.
_LATER_FIELDS = {f.name: f.default for f in dataclasses.fields(ControllerParams) if f.name in (
    "accel_gate", "cp_excess", "cp_update_window",
    # the recovery extensions
    "cp_rate_blend", "cp_lookahead_s", "cp_trigger", "cp_trigger_forward_m",
    "cp_trigger_backward_m", "cp_trigger_lateral_m", "stance_ankle_kp", "stance_ankle_kd",
    "stance_hip_kp", "stance_hip_kd", "stance_roll_kp", "stance_roll_kd", "stance_limit",
    "max_steps")}
# The same for ModelParams: the IMU filter fields enter the hash only when a filter is on.
_LATER_MODEL_FIELDS = {"accel_lowpass_hz": 0.0, "gyro_lowpass_hz": 0.0}


def step_override(rec: dict) -> StepOverride:
    """The StepOverride of record(s) with step_* columns (onset_s is filled by the rollout)."""
    return StepOverride(active=rec["step_active"], x_m=rec["step_x_m"], y_m=rec["step_y_m"],
                        start_delay_s=rec["step_start_delay_s"],
                        from_detection=rec["step_from_detection"], period_s=rec["step_period_s"],
                        onset_s=rec["onset_s"],
                        **{k: rec[f"step_{k}"] for k in ("steps", "x2_m", "y2_m", "delay2_s")
                           if f"step_{k}" in rec})


def outcome_keys(steps: bool) -> tuple[str, ...]:
    """Columns a chunk writes: the outcomes, plus the capture-region ones for [step] sweeps."""
    return OUTCOME_KEYS + (CAPTURE_KEYS if steps else ())


def traced_params(params: ControllerParams) -> ControllerParams:
    """Every leaf as a float32 array: a new parameter set is a new *input* of the compiled chunk,
    never a new constant (Python floats would be weakly typed; jnp arrays keep one signature)."""
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), params)


def make_chunk_fn(varied: tuple[str, ...], duration_s: float,
                  model_params: ModelParams | None = None, with_qpos: bool = False,
                  steps: bool = False, fixed: FixedPointConfig | None = None,
                  ensemble: EnsembleRef | None = None, unroll_substeps: int | None = None):
    """jit(vmap) of push records -> outcomes: f(batch, keys, params) with `params` a
    ControllerParams shared by the batch (pass it through `traced_params`), and `varied` the
    controller fields given per record instead (a [controller.grid]).

    The controller parameters are traced inputs, so one compile serves every parameter set of a
    batch shape (tuned sets, the paper's, a grid); cached per (varied, duration, model), so
    sweeps, `tkujax paper`-style evaluations and the bench in one process share it.
    with_qpos: also return the state at every control period ("qpos", for replay).
    steps: records carry a commanded step (step_* columns, a [step] sweep).
    fixed: run the fixed-point controller with this (static) FixedPointConfig; one compiled
    program per distinct config (word lengths change the program; `fpga_groups`).
    ensemble: [randomize] ensemble: each record runs on member rec["robot_id"] of the ensemble's
    RobotSet (`ensemble_robots`, built once per ensemble content), its model and settled stand
    picked inside the program; model_params must then be None. The controller parameters stay
    the batch's (the controller does not know which robot it runs on).
    The returned f also takes an optional 4th argument, a `tkujax.control.policy.Schedule`
    shared by the batch (a scheduled policy, `tkujax sweep --params POLICY.json`): its numbers
    are traced inputs; None (the default) is the plain controller's program.
    unroll_substeps: the loop structure (RolloutConfig.unroll_substeps); None: the sweeps'
    SWEEP_UNROLL_SUBSTEPS. The outcomes do not depend on it (tests/test_perf_equivalence)."""
    if ensemble is not None and model_params is not None:
        raise SpecError("[randomize] ensemble gives the robots: pass no model_params with it")
    unroll = SWEEP_UNROLL_SUBSTEPS if unroll_substeps is None else int(unroll_substeps)
    if unroll < 1:
        raise ValueError(f"unroll_substeps must be >= 1, got {unroll_substeps!r}")
    # Positional call into the cache: lru_cache keys f(a, b) and f(a, b, steps=False) apart,
    # which would compile the same program twice.
    return _make_chunk_fn(tuple(varied), duration_s, model_params, with_qpos, steps, fixed,
                          ensemble, unroll)


@functools.lru_cache(maxsize=4)
def ensemble_robots(ensemble: EnsembleRef):
    """The RobotSet of an ensemble's members (`tkujax.sim.robots`), cached by the file's content
    (EnsembleRef compares by sha256)."""
    from tkujax.sim.robots import robot_set
    try:
        return robot_set(ensemble.members)
    except ValueError as err:
        raise SpecError(f"randomize.ensemble: {ensemble.path}: {err}") from None


@functools.lru_cache(maxsize=16)
def _make_chunk_fn(varied, duration_s, model_params, with_qpos, steps, fixed, ensemble, unroll):
    from tkujax.sim.robots import put_leaves

    if ensemble is None:
        _, model, index, state = init(model_params)
    else:
        robots = ensemble_robots(ensemble)
        model, index, state = robots.base_model, robots.index, robots.base_state
    config = RolloutConfig(duration_s=duration_s, record_qpos=with_qpos, fixed=fixed,
                           program=ProgramOptions(unroll_substeps=unroll, loop=SWEEP_LOOP))

    def one(rec, key, base_params, schedule, robot_values=None):
        push = Push(rec["impulse_ns"], jnp.radians(rec["azimuth_deg"]), rec["height_m"],
                    rec["duration_s"], rec["onset_s"])
        params = controller_params_from(base_params, {k: rec[k] for k in varied})
        m, s = model, state
        if robot_values is not None:   # this record's ensemble member
            rid = rec[ROBOT_ID_COLUMN].astype(jnp.int32)
            m = put_leaves(model, robots.model_leaf_ids, robot_values[0], rid)
            s = put_leaves(state, robots.state_leaf_ids, robot_values[1], rid)
        m = randomize_model(m, index.chest_body, mass_scale=rec["link_mass_scale"],
                            torso_com_dx_m=rec["torso_com_offset_x_m"],
                            friction=rec["floor_friction"], kp_scale=rec["servo_kp_scale"])
        series = rollout(m, s, Episode(push, rec["control"], key, rec["gyro_noise_std"],
                         rec["accel_noise_std"]), params, config, index,
                         step_override(rec) if steps else None, schedule)
        out = rollout_outcomes(series, push.onset_s)
        res = {k: out[k] for k in OUTCOME_KEYS} | ({"qpos": series.qpos} if with_qpos else {})
        return res | (capture_outcomes(series, push.onset_s, params.gravity) if steps else {})

    if ensemble is None:
        def chunk(batch, keys, params, schedule=None):
            return jax.vmap(one, in_axes=(0, 0, None, None))(batch, keys, params, schedule)

        return jax.jit(chunk, compiler_options=SWEEP_COMPILER_OPTIONS)
    # The members' values are arguments of the program, not constants baked into it.
    fn = jax.jit(jax.vmap(one, in_axes=(0, 0, None, None, None)),
                 compiler_options=SWEEP_COMPILER_OPTIONS)
    values = robots.values()
    return lambda batch, keys, params, schedule=None: fn(batch, keys, params, schedule, values)


BACKENDS = ("auto", "mjx", "mujoco")


def choose_backend(requested: str, spec: SweepSpec) -> str:
    """"auto": MJX on a GPU/TPU; on a CPU, MuJoCo C (about 5x faster there) when the spec
    allows it. The MuJoCo C path takes one model per sweep: per-push model randomisation needs
    MJX. A [controller.grid] runs on both (MuJoCo C: one batch per grid point of a chunk), and
    so does a [randomize] ensemble (MuJoCo C: one batch per member present in a chunk)."""
    if requested not in BACKENDS:
        raise SpecError(f"backend must be one of {BACKENDS}, got {requested!r}")
    needs_mjx = [k for k in spec.randomize if k not in ("gyro_noise_std", "accel_noise_std")
                 or isinstance(spec.randomize[k], tuple)]
    if requested == "mujoco" and needs_mjx:
        raise SpecError(f"backend 'mujoco' cannot vary {needs_mjx} per push; use backend 'mjx'")
    if requested != "auto":
        return requested
    return "mjx" if jax.default_backend() != "cpu" or needs_mjx else "mujoco"


@jax.jit
def _capture_outcomes_batch(series, onset_s, gravity):
    return jax.vmap(capture_outcomes, in_axes=(0, 0, None))(series, onset_s, gravity)


def mujoco_chunk(batch: dict, seed: int, base: ControllerParams, duration_s: float,
                 model_params: ModelParams | None, with_qpos: bool = False,
                 varied: tuple[str, ...] = (), steps: bool = False,
                 fpga: dict | None = None, fpga_varied: tuple[str, ...] = (),
                 ensemble: EnsembleRef | None = None, schedule=None) -> dict:
    """One chunk on MuJoCo C (tkujax.sim.rollout_mujoco), outcomes (and qpos) as numpy: one
    batch per controller-grid point present in the chunk (`varied` names the grid's fields; the
    controller's parameters are shared by a batch there). steps: records carry a commanded step
    (step_* columns, a [step] sweep) and get the capture-region columns too. fpga: the [fpga]
    values of a fixed-point sweep (None: float controller), fpga_varied: its gridded keys
    (columns fpga_<key>): one batch per (controller-grid point, FixedPointConfig). ensemble: a
    [randomize] ensemble: one batch per member too (column robot_id; model_params is then
    unused: each batch runs its member's ModelParams). schedule: a scheduled policy's Schedule
    (None: the plain controller)."""
    from tkujax.sim.rollout_mujoco import simulate_mujoco

    n = len(batch["impulse_ns"])
    cols = list(varied) + [FPGA_COLUMN + k for k in fpga_varied]
    if ensemble is not None:
        cols.append(ROBOT_ID_COLUMN)            # last: the member of each batch
    grid = np.stack([batch[k] for k in cols], 1) if cols else np.zeros((n, 0))
    points, which = np.unique(grid, axis=0, return_inverse=True)
    res = {}
    for j, point in enumerate(points):
        sel = np.flatnonzero(which.ravel() == j)
        # Python floats: one compiled controller tick for every grid point (values are traced).
        params = controller_params_from(base, {k: float(v) for k, v in zip(varied, point)})
        fixed = None if fpga is None else fixed_point_config(
            fpga | dict(zip(fpga_varied, point[len(varied):len(varied) + len(fpga_varied)])))
        robot = model_params if ensemble is None else ensemble.members[int(point[-1])]
        pushes = Push(*(jnp.asarray(v[sel], jnp.float32) for v in (
            batch["impulse_ns"], np.radians(batch["azimuth_deg"]), batch["height_m"],
            batch["duration_s"], batch["onset_s"])))
        overrides = step_override({k: jnp.asarray(v[sel], jnp.float32) for k, v in batch.items()}
                                  ) if steps else None
        series, out = simulate_mujoco(
            pushes, batch["control"][sel].astype(np.float32), params, seed=seed,
            gyro_noise_std=float(batch["gyro_noise_std"][0]),
            accel_noise_std=float(batch["accel_noise_std"][0]), model_params=robot,
            config=RolloutConfig(duration_s=duration_s, record_qpos=with_qpos, fixed=fixed),
            overrides=overrides, schedule=schedule)
        fields = {k: np.asarray(out[k]) for k in OUTCOME_KEYS}
        if with_qpos:
            fields["qpos"] = np.asarray(series.qpos)
        if steps:
            cap = _capture_outcomes_batch(jax.tree_util.tree_map(jnp.asarray, series),
                                          pushes.onset_s, float(params.gravity))
            fields |= {k: np.asarray(v) for k, v in cap.items()}
        for k, v in fields.items():
            res.setdefault(k, np.empty((n,) + v.shape[1:], v.dtype))[sel] = v
    return res


def shares_robot_draws(spec: SweepSpec) -> bool:
    """Whether the spec's records changed when one robot draw per push became shared by its
    settings: random [randomize] draws and more than one setting (control or grid point)."""
    n_settings = len(spec.control) * math.prod(
        len(v) for v in (spec.controller_grid | spec.fpga_grid).values())
    return any(isinstance(v, tuple) for v in spec.randomize.values()) and n_settings > 1


def _spec_hash(spec: SweepSpec, params: ControllerParams, model_params: ModelParams,
               schedule=None) -> str:
    # Fields added later enter the hash only when set, so older sweeps still resume. The model
    # enters in full: a changed default robot (e.g. the calibration) is a different sweep.
    p = {k: v for k, v in dataclasses.asdict(params).items()
         if not (k in _LATER_FIELDS and v == _LATER_FIELDS[k])}
    m = {k: v for k, v in dataclasses.asdict(model_params).items()
         if not (k in _LATER_MODEL_FIELDS and v == _LATER_MODEL_FIELDS[k])}
    parts = [spec.raw, p, m]
    if spec.arithmetic == "fixed":   # the FixedPointConfig defaults fill every unset [fpga] key
        parts.append({"fixed_point_defaults": dataclasses.asdict(FixedPointConfig())})
    if spec.phase_default:   # random onsets changed meaning when the phase axis came in
        parts.append("push.random.onset_phase: uniform [0, 1) by default")
    if spec.ensemble is not None:   # the robots themselves, by the file's content
        parts.append({"randomize.ensemble sha256": spec.ensemble.sha256})
    if schedule is not None:        # a scheduled policy: its layout and numbers
        parts.append({"schedule": schedule_to_dict(schedule)})
    if shares_robot_draws(spec):
        # The robot draws became shared by the settings of a push (records of older sweeps
        # differ): such a sweep is a new one.
        parts.append("randomize: one draw per push, shared by its control and grid settings")
    blob = json.dumps(parts, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def record_inputs(spec: SweepSpec) -> dict[str, np.ndarray]:
    recs = spec.records()
    from tkujax.studies.spec import RANDOMIZE_DEFAULTS
    n = len(recs["push_id"])
    for k, v in RANDOMIZE_DEFAULTS.items():
        if k not in recs:
            recs[k] = np.full(n, -1.0 if v is None else v)   # friction -1: keep the model's
    return recs


def _processes(process_id, num_processes, coordinator) -> tuple[int, int]:
    """(process_id, num_processes) from the arguments or the TKUJAX_* environment variables;
    several processes: jax.distributed is initialised here."""
    process_id = int(os.environ.get("TKUJAX_PROCESS_ID", 0)) if process_id is None else process_id
    num_processes = (int(os.environ.get("TKUJAX_NUM_PROCESSES", 1)) if num_processes is None
                     else num_processes)
    coordinator = coordinator or os.environ.get("TKUJAX_COORDINATOR")
    if num_processes > 1:
        if not coordinator:
            raise SpecError("num_processes > 1 needs a coordinator address HOST:PORT")
        jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                                   process_id=process_id)
    return process_id, num_processes


@dataclasses.dataclass(frozen=True)
class _ChunkJob:
    """Everything a chunk's computation needs (the same for every chunk of a sweep)."""

    spec: SweepSpec
    recs: dict
    base: ControllerParams
    model_params: ModelParams | None
    backend: str
    schedule: Schedule | None
    padded: int
    sharding: NamedSharding

    @property
    def input_keys(self) -> list[str]:
        return [k for k in self.recs if k not in ("push_id", "from_grid", "case_id")]

    def compute(self, i: int) -> dict:
        """The records of chunk i with their outcome columns."""
        spec, recs, n = self.spec, self.recs, len(self.recs["push_id"])
        lo, hi = i * spec.chunk_size, min((i + 1) * spec.chunk_size, n)
        varied = tuple(sorted(spec.controller_grid))
        steps = bool(spec.step_grid)
        if self.backend == "mujoco":
            res = mujoco_chunk({k: recs[k][lo:hi] for k in self.input_keys}, spec.seed + i,
                               self.base, spec.duration_s, self.model_params, varied=varied,
                               steps=steps, fpga=spec.fpga if spec.arithmetic == "fixed" else None,
                               fpga_varied=tuple(sorted(spec.fpga_grid)), ensemble=spec.ensemble,
                               schedule=self.schedule)
            return {k: recs[k][lo:hi] for k in recs} | res
        keys = chunk_keys(spec.seed, i, self.padded)
        res = {}
        for fixed, sel in fpga_groups(spec, {k: recs[k][lo:hi] for k in recs}):
            # Each FixedPointConfig is its own program, compiled once for the padded chunk
            # shape; a chunk straddling configs runs once per config present (specs whose
            # chunk_size divides the pushes per config avoid that). Each record keeps its own
            # noise key.
            rows = np.resize(sel, self.padded)
            batch = {k: jax.device_put(recs[k][lo:hi][rows].astype(np.float32), self.sharding)
                     for k in self.input_keys}
            fn = make_chunk_fn(varied, spec.duration_s, self.model_params, steps=steps,
                               fixed=fixed, ensemble=spec.ensemble)
            part = fn(batch, jax.device_put(keys[rows], self.sharding), traced_params(self.base),
                      self.schedule)
            for k, v in part.items():
                v = np.asarray(v)[:len(sel)]
                res.setdefault(k, np.empty((hi - lo,) + v.shape[1:], v.dtype))[sel] = v
        return {k: recs[k][lo:hi] for k in recs} | res


def _compute_pending(out: Path, job: _ChunkJob, pending: list[int], n_chunks: int,
                     progress: Progress, max_chunks: int | None, deadline: float) -> int:
    """Claim and compute the pending chunks (another writer may hold some); once only chunks
    claimed by others remain, poll until they are done or their claims go stale (bounded by
    `deadline`, time.monotonic). Returns the number of chunks computed here."""
    n = len(job.recs["push_id"])
    computed = 0
    while pending and (max_chunks is None or computed < max_chunks):
        waiting = []
        for i in pending:
            if (max_chunks is not None and computed >= max_chunks) or not chunks.try_claim(out, i):
                waiting.append(i)
                continue
            try:
                entries = chunks.read_manifest(out).get("chunks", {})
                if chunks.check_chunk(out, i, entries.get(chunks.chunk_name(i))) is None:
                    continue                      # another writer finished it meanwhile
                if computed == 0:
                    progress.note("compiling the rollout (first chunk; minutes on a CPU) ...")
                chunks.write_chunk(out, i, job.compute(i))
            finally:
                chunks.release(out, i)
            computed += 1
            progress.update(min((i + 1) * job.spec.chunk_size, n) - i * job.spec.chunk_size)
            if computed == 1:
                progress.restart()   # later rates and ETAs exclude the compile
        if max_chunks is not None and computed >= max_chunks:
            break
        pending = [i for i in waiting if i not in chunks.done_chunks(out, n_chunks)]
        if pending:
            if time.monotonic() > deadline:
                break
            time.sleep(0.5)
    return computed


def _describe(spec: SweepSpec, digest: str, n: int, n_chunks: int, padded: int,
              params: ControllerParams, model_params: ModelParams | None, num_processes: int,
              backend: str, schedule=None) -> dict:
    """The manifest's description of the sweep (every writer restates it)."""
    manifest = dict(name=spec.name, spec=spec.raw, spec_hash=digest, n_pushes=n,
                    chunk_size=spec.chunk_size, n_chunks=n_chunks, padded_chunk=padded,
                    controller_params=dataclasses.asdict(params),
                    model_params=dataclasses.asdict(model_params or ModelParams()),
                    versions=versions(), git_commit=git_commit(),
                    devices=[str(d) for d in jax.devices()], num_processes=num_processes,
                    backend=backend, format="npz chunks, one record per push")
    if spec.arithmetic == "fixed":
        manifest["fixed_point_defaults"] = dataclasses.asdict(FixedPointConfig())
    if spec.ensemble is not None:
        manifest["ensemble"] = spec.ensemble.describe()
    if schedule is not None:
        manifest["schedule"] = schedule_to_dict(schedule)
    return manifest


def run_sweep(spec: SweepSpec | str | Path, out: str | Path, params: ControllerParams | None = None,
              model_params: ModelParams | None = None, max_chunks: int | None = None,
              process_id: int | None = None, num_processes: int | None = None,
              coordinator: str | None = None, quiet: bool = False,
              wait_for_others_s: float = 3600.0, backend: str = "auto",
              schedule: Schedule | None = None) -> dict:
    """Run (or resume) a sweep into `out`. Returns the manifest.

    max_chunks: stop after computing this many new chunks (for tests and partial runs).
    Multi-process: process 0 waits up to `wait_for_others_s` for the other processes' chunks
    before writing the final manifest. backend: "auto" (see `choose_backend`), "mjx" or
    "mujoco"; the manifest records which ran (the spec hash does not include it, so a sweep
    can be resumed on another machine; outcomes agree across backends except near the fall
    boundary). schedule: a scheduled policy's Schedule (`tkujax.control.io.load_policy_json`),
    applied with `params` in every control-on run; the manifest and the spec hash record it.
    """
    if max_chunks is not None and (isinstance(max_chunks, bool) or not isinstance(max_chunks, int)
                                   or max_chunks < 1):
        raise ValueError(f"max_chunks must be an integer >= 1 (or None: all), got {max_chunks!r}")
    spec = spec if isinstance(spec, SweepSpec) else load_spec(spec)
    if spec.ensemble is not None and model_params is not None:
        raise SpecError("[randomize] ensemble gives the sweep's robots: give either it or a "
                        "model (--model), not both")
    params = params or ControllerParams.paper()
    if schedule is not None and spec.arithmetic == "fixed":
        raise SpecError("a scheduled policy (--params with a 'schedule') has no fixed-point "
                        "controller twin: use a plain parameter file with arithmetic = 'fixed'")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    process_id, num_processes = _processes(process_id, num_processes, coordinator)

    backend = choose_backend(backend, spec)
    digest = _spec_hash(spec, params, model_params or ModelParams(), schedule)
    old = chunks.read_manifest(out)
    if old and old.get("spec_hash") != digest:
        raise SpecError(f"{out} holds a different sweep (spec hash {old.get('spec_hash')} != "
                        f"{digest}); choose another --out")

    recs = record_inputs(spec)
    n = len(recs["push_id"])
    n_chunks = math.ceil(n / spec.chunk_size)
    devices = jax.local_devices()
    # Pad every chunk to one shape (a multiple of the device count): one compile for all.
    padded = math.ceil(spec.chunk_size / len(devices)) * len(devices)
    manifest = _describe(spec, digest, n, n_chunks, padded, params, model_params,
                         num_processes, backend, schedule)
    chunks.clean_temporaries(out)
    # Every writer (re)states the description; the chunk entries are kept (see chunks.py).
    chunks.update_manifest(out, lambda m: {**manifest, "complete": False,
                                           "wall_s": float(m.get("wall_s", 0.0)),
                                           "chunks": m.get("chunks", {})})
    mine = [i for i in range(n_chunks) if i % num_processes == process_id]
    done = chunks.done_chunks(out, n_chunks)
    pending = [i for i in mine if i not in done]

    base = controller_params_from(params, spec.controller)
    if spec.arithmetic == "fixed":   # the twin lacks some float options: refuse, do not ignore
        check_supported(base)
    job = _ChunkJob(spec=spec, recs=recs, base=base,
                    model_params=model_params, backend=backend, schedule=schedule, padded=padded,
                    sharding=NamedSharding(Mesh(np.array(devices), ("push",)),
                                           PartitionSpec("push")))
    progress = Progress(len(mine) * spec.chunk_size, (len(mine) - len(pending)) * spec.chunk_size,
                        open(os.devnull, "w") if quiet else sys.stderr)
    t_start = time.perf_counter()
    deadline = time.monotonic() + wait_for_others_s
    computed = _compute_pending(out, job, pending, n_chunks, progress, max_chunks, deadline)
    progress.close()
    wall = time.perf_counter() - t_start

    if process_id == 0 and num_processes > 1 and max_chunks is None:
        # The other processes write their chunks into the same folder: wait for them (bounded)
        # so that the manifest says whether the sweep as a whole is complete.
        while (time.monotonic() < deadline
               and len(chunks.done_chunks(out, n_chunks)) < n_chunks):
            time.sleep(1.0)

    def finish(m: dict) -> dict:
        # Judged under the lock from the files themselves, so the last writer to finish
        # states the final truth.
        entries = m.get("chunks", {})
        recorded = [chunks.chunk_name(i) for i in range(n_chunks)
                    if chunks.check_chunk(out, i, entries.get(chunks.chunk_name(i))) is None]
        return {**m, "complete": len(recorded) == n_chunks,
                "wall_s": round(float(m.get("wall_s", 0.0)) + wall, 2),
                "chunks_computed_last_run": computed,
                "n_diverged": sum(entries[c].get("n_diverged", 0) for c in recorded)}

    return chunks.update_manifest(out, finish)


def fpga_groups(spec: SweepSpec, rec: dict) -> list[tuple[FixedPointConfig | None, np.ndarray]]:
    """The records' (FixedPointConfig, row indices) groups: one static config per compiled
    program. A float sweep, or one without an fpga grid, is a single group of every row."""
    n = len(rec["impulse_ns"])
    if not spec.fpga_grid:
        return [(spec.fixed_point_config(), np.arange(n))]
    cols = [FPGA_COLUMN + k for k in spec.fpga_grid]
    points, which = np.unique(np.stack([rec[c] for c in cols], 1), axis=0, return_inverse=True)
    return [(spec.fixed_point_config(dict(zip(cols, p))), np.flatnonzero(which.ravel() == j))
            for j, p in enumerate(points)]


def chunk_keys(seed: int, chunk: int, padded: int) -> jax.Array:
    """The MJX noise keys of one chunk: one per (padded) record."""
    return jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), chunk), padded)


def load(out: str | Path, as_frame: bool = False):
    """All verified records of a sweep folder as a dict of columns (chunks in order), or a
    pandas DataFrame with as_frame=True (pandas is optional: not a tkujax dependency).

    Every chunk is checked against its manifest entry (sha256, rows); a missing, truncated or
    corrupted one raises ChunkError naming the file. Chunks still in flight are not loaded."""
    out = Path(out)
    parts = chunks.read_chunks(out, chunks.read_manifest(out))
    if not parts:
        raise FileNotFoundError(f"no sweep chunks in {out}")
    cols = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    if not as_frame:
        return cols
    try:
        import pandas as pd
    except ImportError as err:
        raise ImportError("load(..., as_frame=True) needs pandas, which tkujax does not "
                          "install: pip install pandas") from err
    return pd.DataFrame(cols)
