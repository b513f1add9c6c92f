"""`tkujax sweep`: thousands of pushes in batches, written in chunks, resumable.

Records are columnar `.npz` chunks (numpy's own format: readable with plain numpy, no extra
dependency, one file per chunk so a crash loses at most the chunk in flight). The chunk store
(`tkujax.sweeps.chunks`) writes each chunk atomically, records its sha256 and row count in the
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
import math
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from tkujax.control.fixed import check_supported
from tkujax.control.params_files import controller_params_from
from tkujax.control.controller_params import ControllerParams
from tkujax.control.policy import Schedule
from tkujax.model import ModelParams
from tkujax.robot import Robot, as_robot, robot_from_file
from tkujax.sweeps import chunks
from tkujax.sweeps.chunk_program import (chunk_keys, fpga_groups, make_chunk_fn, record_inputs,
                                         traced_params)
from tkujax.sweeps.early import make_lane_fns
from tkujax.sweeps.lane_stream import LaneStream
from tkujax.sweeps.mujoco_chunk import mujoco_chunk
from tkujax.sweeps.progress import Progress
from tkujax.sim.push import CONTROL_PERIOD_S
from tkujax.dialects.sweep_spec import SpecError, SweepSpec, load_spec
from tkujax.dialects.program_keys import with_decisions
from tkujax.sweeps.sweep_folder import (chunk_provenance, claim_folder, describe,
                                        params_as_held, prepare_out, processes, run_record)
from tkujax.sweeps.sweep_hash import input_digests, spec_hash
from tkujax.dialects.push_limits import check_push_window
from tkujax.dialects.floor_table import spec_floor
from tkujax.dialects.walk_table import check_walk_sweep, walk_base, walk_for_robot
from tkujax.sweeps.sweep_state import SweepRecords, sweep_state

# Names other modules have imported from here; each lives in the module named.
from tkujax.control.params_files import load_controller_params_json as load_params_json  # noqa: F401
from tkujax.sweeps.chunk_program import (OUTCOME_KEYS, SWEEP_COMPILER_OPTIONS,  # noqa: F401
                                         SWEEP_LOOP, SWEEP_UNROLL_SUBSTEPS, outcome_keys,
                                         step_override)
from tkujax.sweeps.sweep_hash import shares_robot_draws  # noqa: F401
from tkujax.sweeps.sweep_folder import model_record  # noqa: F401

MANIFEST = chunks.MANIFEST

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
    if requested == "mujoco" and spec.decisions.early:
        raise SpecError("sweep.decisions: 'early' runs on MJX only; use backend 'mjx' or 'auto'")
    if spec.decisions.early:
        needs_mjx.append("decisions")
    if requested == "mujoco" and needs_mjx:
        raise SpecError(f"backend 'mujoco' cannot vary {needs_mjx} per push; use backend 'mjx'")
    if requested != "auto":
        return requested
    return "mjx" if jax.default_backend() != "cpu" or needs_mjx else "mujoco"


@dataclasses.dataclass(frozen=True)
class _ChunkJob:
    """Everything a chunk's computation needs (the same for every chunk of a sweep)."""

    spec: SweepSpec
    recs: dict
    base: ControllerParams
    robot: Robot | None              # None: a [randomize] ensemble gives the robots
    backend: str
    schedule: Schedule | None
    padded: int
    sharding: NamedSharding
    spec_hash: str = ""
    provenance: dict = dataclasses.field(default_factory=dict)   # of the run (chunk entries)

    def write(self, out: Path, i: int, record: dict) -> None:
        """Chunk i written with this run's provenance, only while `out` holds this sweep."""
        chunks.write_chunk(out, i, record, self.provenance, self.spec_hash or None)

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
                               self.base, spec.duration_s, self.robot, varied=varied,
                               steps=steps, fpga=spec.fpga if spec.arithmetic == "fixed" else None,
                               fpga_varied=tuple(sorted(spec.fpga_grid)), ensemble=spec.ensemble,
                               schedule=self.schedule, walk=walk_base(spec),
                               floor=spec_floor(spec))
            return {k: recs[k][lo:hi] for k in recs} | res
        keys = chunk_keys(spec.seed, i, self.padded)   # (early decisions: early_parts)
        res = {}
        for fixed, sel in fpga_groups(spec, {k: recs[k][lo:hi] for k in recs}):
            # Each FixedPointConfig is its own program, compiled once for the padded chunk
            # shape; a chunk straddling configs runs once per config present (specs whose
            # chunk_size divides the pushes per config avoid that). Each record keeps its own
            # noise key.
            rows = np.resize(sel, self.padded)
            batch = {k: jax.device_put(recs[k][lo:hi][rows].astype(np.float32), self.sharding)
                     for k in self.input_keys}
            fn = make_chunk_fn(varied, spec.duration_s, self.robot, steps=steps,
                               fixed=fixed, ensemble=spec.ensemble, tree_passes=spec.tree_passes,
                               walk=walk_base(spec), floor=spec_floor(spec))
            part = fn(batch, jax.device_put(keys[rows], self.sharding), traced_params(self.base),
                      self.schedule)
            for k, v in part.items():
                v = np.asarray(v)[:len(sel)]
                res.setdefault(k, np.empty((hi - lo,) + v.shape[1:], v.dtype))[sel] = v
        return {k: recs[k][lo:hi] for k in recs} | res

    def lane_stream(self) -> LaneStream:
        """The batch of lanes the early chunks of this process stream through."""
        n_lanes = math.ceil(self.spec.decisions.lanes / self.n_devices) * self.n_devices
        return LaneStream(n_lanes, traced_params(self.base), self.schedule, self.sharding,
                          steps=bool(self.spec.step_grid))

    def early_parts(self, stream: LaneStream, i: int) -> list:
        """Chunk i's pushes as parts of `stream`, one per FixedPointConfig present, labelled
        (i, rows of the chunk); each record keeps its own noise key."""
        spec, n = self.spec, len(self.recs["push_id"])
        lo, hi = i * spec.chunk_size, min((i + 1) * spec.chunk_size, n)
        keys = np.asarray(chunk_keys(spec.seed, i, self.padded))
        parts = []
        for fixed, sel in fpga_groups(spec, {k: self.recs[k][lo:hi] for k in self.recs}):
            fns = make_lane_fns(tuple(sorted(spec.controller_grid)), spec.duration_s,
                                self.robot, bool(spec.step_grid), fixed, spec.ensemble,
                                spec.tree_passes, spec.decisions.segment_ticks,
                                walk_base(spec))
            parts.append(stream.part((i, sel), fns, {k: self.recs[k][lo:hi][sel]
                                                     for k in self.input_keys}, keys[sel]))
        return parts

    @property
    def n_devices(self) -> int:
        return len(self.sharding.mesh.devices.flat)


def _compute_pending(out: Path, job: _ChunkJob, pending: list[int], n_chunks: int,
                     progress: Progress, max_chunks: int | None, deadline: float) -> int:
    """Claim and compute the pending chunks (another writer may hold some); once only chunks
    claimed by others remain, poll until they are done or their claims go stale (bounded by
    `deadline`, time.monotonic). Returns the number of chunks computed here."""
    claims = chunks.Claims(out, pending, n_chunks, max_chunks, deadline)
    if job.spec.decisions.early and job.backend != "mujoco":
        return _compute_early(out, job, claims, progress)
    n, computed = len(job.recs["push_id"]), 0
    while (i := claims.next()) is not None:
        try:
            if computed == 0:
                progress.note("compiling the rollout (first chunk; minutes on a CPU) ...")
            job.write(out, i, job.compute(i))
        finally:
            chunks.release(out, i)
        computed += 1
        progress.update(min((i + 1) * job.spec.chunk_size, n) - i * job.spec.chunk_size)
        if computed == 1:
            progress.restart()   # later rates and ETAs exclude the compile
    return computed


def _compute_early(out: Path, job: _ChunkJob, claims: chunks.Claims, progress: Progress) -> int:
    """Early decisions (`tkujax.sweeps.lane_stream`): the claimed chunks' pushes streamed
    through one batch of lanes, the next chunk claimed as soon as lanes are free and no push
    of the chunks claimed is left to start; each chunk written (and released) as soon as all
    its pushes are decided. A chunk whose claim is held at an exception is released."""
    stream = job.lane_stream()
    held: dict[int, list] = {}      # chunk -> [parts left, outcome columns]
    written = []

    def more(idle: bool) -> list:
        i = claims.next(wait=idle)
        if i is None:
            return []
        if not written and not held:
            progress.note("compiling the rollout (first chunk; minutes on a CPU) ...")
        held[i] = [0, {}]                 # held (released at an exception) from here on
        parts = job.early_parts(stream, i)
        held[i][0] = len(parts)
        return parts

    def finished(part) -> None:
        i, sel = part.label
        left = held[i]
        left[0] -= 1
        hi = min((i + 1) * job.spec.chunk_size, len(job.recs["push_id"]))
        for k, v in part.out.items():
            left[1].setdefault(k, np.empty((hi - i * job.spec.chunk_size,) + v.shape[1:],
                                           v.dtype))[sel] = v
        if left[0] == 0:
            rows = slice(i * job.spec.chunk_size, hi)
            job.write(out, i, {k: job.recs[k][rows] for k in job.recs} | left[1])
            chunks.release(out, i)
            del held[i]
            written.append(i)
            progress.update(hi - rows.start)
            if len(written) == 1:
                progress.restart()

    try:
        stream.run(more, finished)
    finally:
        for i in held:
            chunks.release(out, i)
    return len(written)


def _checked_inputs(spec: SweepSpec | str | Path, params: ControllerParams | None,
                    robot: Robot | None, model_params: Robot | ModelParams | None,
                    max_chunks: int | None,
                    schedule: Schedule | None
                    ) -> tuple[SweepSpec, ControllerParams, Robot, Schedule | None]:
    """The spec (loaded from its path), the controller parameters and schedule (default: the
    robot's; a robot file's policy runs standing only) and the Robot (`model_params`, else the
    spec's [robot] file, else TKU-X), after refusing the combinations a sweep cannot run."""
    if max_chunks is not None and (isinstance(max_chunks, bool) or not isinstance(max_chunks, int)
                                   or max_chunks < 1):
        raise ValueError(f"max_chunks must be an integer >= 1 (or None: all), got {max_chunks!r}")
    spec = spec if isinstance(spec, SweepSpec) else load_spec(spec)
    check_control_period(params)
    if spec.ensemble is not None and (robot is not None or model_params is not None):
        raise SpecError("[randomize] ensemble gives the sweep's robots: give either it or a "
                        "model (--model), not both")
    if schedule is not None and spec.arithmetic == "fixed":
        raise SpecError("a scheduled policy (--params with a 'schedule') has no fixed-point "
                        "controller twin: use a plain parameter file with arithmetic = 'fixed'")
    if robot is None and model_params is None and spec.robot_file is not None:
        robot = robot_from_file(spec.robot_file)          # [robot] file, as the command line
    robot = as_robot(robot, model_params)
    if spec.walk is not None and schedule is not None:
        raise SpecError("[walk]: a scheduled policy (--params with a 'schedule') does not run "
                        "while walking; give a plain parameter file")
    if robot.builtin:
        check_tkux_pushes(spec)
        return spec, params or robot.params, robot, schedule
    spec = walk_for_robot(spec, robot)
    check_push_window(spec)
    check_robot_sweep(spec, robot)
    if params is not None:
        return spec, params, robot, schedule
    if spec.walk is not None:
        return spec, robot.walking_params, robot, None
    return spec, robot.params, robot, robot.schedule


TKUX_HEIGHT_M = (0.25, 0.46)   # TKU-X's trunk, from the hips to the shoulders


def check_tkux_pushes(spec: SweepSpec) -> None:
    """Refuse push heights off TKU-X (the spec's own limits hold any humanoid's)."""
    heights = record_inputs(spec)["height_m"]
    bad = heights[(heights < TKUX_HEIGHT_M[0]) | (heights > TKUX_HEIGHT_M[1])]
    if bad.size:
        raise SpecError(f"push.height_m: {float(bad[0]):g} m is off TKU-X (allowed "
                        f"{TKUX_HEIGHT_M[0]}-{TKUX_HEIGHT_M[1]} m; another robot: [robot] file)")


def check_control_period(params: ControllerParams | None) -> None:
    """Refuse parameters whose control_period is not the robot's: the rollout ticks at
    RolloutConfig.control_period_s (CONTROL_PERIOD_S), the one source of the period, so a
    parameter file's own value would be recorded but never run."""
    if params is not None and not math.isclose(float(params.control_period), CONTROL_PERIOD_S,
                                               rel_tol=0.0, abs_tol=1e-12):
        raise SpecError(f"control_period: the controller parameters give {params.control_period!r}"
                        f" s, but the robot's controller ticks every {CONTROL_PERIOD_S} s (the "
                        f"rollout's one control period); allowed: {CONTROL_PERIOD_S} s or leave "
                        "the key out")


def check_robot_sweep(spec: SweepSpec, robot: Robot) -> None:
    """Refuse a sweep a robot file cannot run: another [robot] file, an ensemble, the
    fixed-point twin, or push heights off the robot (outside 0.3-1.6 x its CoM height)."""
    if spec.robot_file is not None and spec.robot_file != robot.source:
        raise SpecError(f"robot.file: the spec names {spec.robot_file}, the sweep was given "
                        f"{robot.source}")
    if spec.ensemble is not None or spec.arithmetic == "fixed":
        raise SpecError("a robot file's sweep takes no [randomize] ensemble and no fixed-point "
                        "controller")
    heights = record_inputs(spec)["height_m"]
    h = float(robot.params.com_height)
    lo, hi = 0.3 * h, 1.6 * h
    bad = heights[(heights < lo) | (heights > hi)]
    if bad.size:
        raise SpecError(f"push.height_m: {float(bad[0]):g} m is off {robot.name} (its CoM is "
                        f"{h:.3f} m high; allowed {lo:.3f}-{hi:.3f} m)")


def _finish(out: Path, n_chunks: int, wall: float, computed: int, run: dict):
    """The manifest update closing a run: complete or not, wall time, divergences; this run's
    entry of `runs` gets its chunks computed and wall time."""
    def finish(m: dict) -> dict:
        # Judged under the lock from the files themselves, so the last writer to finish
        # states the final truth.
        entries = m.get("chunks", {})
        recorded = [chunks.chunk_name(i) for i in range(n_chunks)
                    if chunks.check_chunk(out, i, entries.get(chunks.chunk_name(i))) is None]
        runs = [dict(r, chunks_computed=computed, wall_s=round(wall, 2))
                if r.get("run_id") == run["run_id"] else r for r in m.get("runs", [])]
        return {**m, "runs": runs, "complete": len(recorded) == n_chunks,
                "wall_s": round(float(m.get("wall_s", 0.0)) + wall, 2),
                "chunks_computed_last_run": computed,
                "n_diverged": sum(entries[c].get("n_diverged", 0) for c in recorded)}
    return finish


def _wait_for_others(out: Path, n_chunks: int, deadline: float) -> None:
    """Process 0 of several: the others write their chunks into the same folder; wait for them
    (until `deadline`, time.monotonic) so that the manifest says whether the sweep as a whole
    is complete."""
    while time.monotonic() < deadline and len(chunks.done_chunks(out, n_chunks)) < n_chunks:
        time.sleep(1.0)


def run_sweep(spec: SweepSpec | str | Path, out: str | Path, params: ControllerParams | None = None,
              model_params: Robot | ModelParams | None = None, max_chunks: int | None = None,
              process_id: int | None = None, num_processes: int | None = None,
              coordinator: str | None = None, quiet: bool = False,
              wait_for_others_s: float = 3600.0, backend: str = "auto",
              schedule: Schedule | None = None, decisions: str | None = None,
              robot: Robot | None = None) -> dict:
    """Run (or resume) a sweep into `out`. Returns the manifest.

    robot: the Robot (`tkujax.robot.robot_from_file`, `tkujax.robot.builtin_robot`); model_params:
    TKU-X's ModelParams instead (or a Robot, the older keyword); neither: the spec's [robot]
    file, else the default TKU-X. params: the controller's (None: the robot's own).
    max_chunks: stop after computing this many new chunks (for tests and partial runs).
    Multi-process: process 0 waits up to `wait_for_others_s` for the other processes' chunks
    before writing the final manifest. backend: "auto" (see `choose_backend`), "mjx" or
    "mujoco"; each chunk's manifest entry records the run, backend, device and commit that
    wrote it, and `runs` every run (`tkujax.sweeps.sweep_folder`; the spec hash does not
    include the backend, so a sweep can be resumed on another machine; outcomes agree across
    backends except near the fall boundary). The returned manifest's `this_run` is this
    run's entry of `runs`. schedule: a scheduled policy's Schedule
    (`tkujax.control.params_files.load_policy_json`), applied with `params` in every control-on run;
    the manifest and the spec hash record it.
    decisions: "full" or "early" in place of the spec's [sweep] decisions (None: the spec's);
    early decisions run on MJX (docs/sweeps.md).
    """
    process_id, num_processes, coordinator = processes(process_id, num_processes, coordinator)
    if num_processes > 1:   # before any JAX call (the robot's model goes onto a device)
        jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                                   process_id=process_id)
    spec, params, robot, schedule = _checked_inputs(spec, params, robot, model_params,
                                                    max_chunks, schedule)
    spec = with_decisions(spec, decisions)
    check_walk_sweep(spec)
    backend = choose_backend(backend, spec)
    out = prepare_out(Path(out))
    params = params_as_held(out, params, lambda p: spec_hash(spec, p, robot, schedule))
    digest = spec_hash(spec, params, robot, schedule)
    recs = record_inputs(spec)
    n = len(recs["push_id"])
    n_chunks = math.ceil(n / spec.chunk_size)
    devices = jax.local_devices()
    # Pad every chunk to one shape (a multiple of the device count): one compile for all.
    padded = math.ceil(spec.chunk_size / len(devices)) * len(devices)
    run = run_record(backend, process_id, num_processes)
    # The check that the folder holds no other sweep and the claim of it: one locked update.
    claim_folder(out, describe(spec, digest, n, n_chunks, padded, params, robot,
                               num_processes, backend, schedule),
                 input_digests(spec, params, robot, schedule), run)
    chunks.clean_temporaries(out)
    mine = [i for i in range(n_chunks) if i % num_processes == process_id]
    done = chunks.done_chunks(out, n_chunks)
    pending = [i for i in mine if i not in done]

    base = controller_params_from(params, spec.controller)
    if spec.arithmetic == "fixed":   # the twin lacks some float options: refuse, do not ignore
        check_supported(base)
    job = _ChunkJob(spec=spec, recs=recs, base=base,
                    robot=None if spec.ensemble is not None else robot, backend=backend,
                    schedule=schedule, padded=padded,
                    sharding=NamedSharding(Mesh(np.array(devices), ("push",)),
                                           PartitionSpec("push")),
                    spec_hash=digest, provenance=chunk_provenance(run))
    progress = Progress(len(mine) * spec.chunk_size, (len(mine) - len(pending)) * spec.chunk_size,
                        open(os.devnull, "w") if quiet else sys.stderr)
    t_start = time.perf_counter()
    deadline = time.monotonic() + wait_for_others_s
    computed = _compute_pending(out, job, pending, n_chunks, progress, max_chunks, deadline)
    progress.close()
    wall = time.perf_counter() - t_start
    if process_id == 0 and num_processes > 1 and max_chunks is None:
        _wait_for_others(out, n_chunks, deadline)
    return chunks.update_manifest(out, _finish(out, n_chunks, wall, computed, run)) | {
        "this_run": run}


def load(out: str | Path, as_frame: bool = False):
    """All verified records of a sweep folder as a dict of columns (chunks in order), or a
    pandas DataFrame with as_frame=True (pandas is optional: not a tkujax dependency).

    Every chunk is checked against its manifest entry (sha256, rows); a missing, truncated or
    corrupted one raises ChunkError naming the file. Chunks still in flight are not loaded: the
    result says how complete the sweep was (`tkujax.sweeps.sweep_state`): the dict's `state`
    and `complete`, the DataFrame's attrs complete, chunks_done and n_chunks."""
    out = Path(out)
    manifest = chunks.read_manifest(out)
    parts = chunks.read_chunks(out, manifest)
    if not parts:
        raise FileNotFoundError(f"no sweep chunks in {out}")
    cols = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return as_frame_if(SweepRecords(cols, sweep_state(out) if manifest else None), as_frame)


def as_frame_if(cols: dict, as_frame: bool):
    """`cols`, or with as_frame=True the same as a pandas DataFrame (pandas is optional)."""
    if not as_frame:
        return cols
    try:
        import pandas as pd
    except ImportError as err:
        raise ImportError("load(..., as_frame=True) needs pandas, which tkujax does not "
                          "install: pip install pandas") from err
    frame = pd.DataFrame(dict(cols))
    state = getattr(cols, "state", None)
    if state is not None:
        frame.attrs.update(state.describe())
    return frame
