"""`tkujax sweep`: thousands of pushes in batches, written in chunks, resumable.

Records are columnar `.npz` chunks (numpy's own format: readable with plain numpy, no extra
dependency, one file per chunk so a crash loses at most the chunk in flight). Each chunk is
written to a temporary name and renamed, so a chunk file either is complete or does not exist;
a rerun skips the chunks that exist and a finished sweep is not recomputed.

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
import platform
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from tkujax.sim import physics
from tkujax.control.params import ControllerParams
from tkujax.control.controller import StepOverride
from tkujax.sim.metrics import CAPTURE_KEYS, capture_outcomes
from tkujax.sim.metrics import outcomes as rollout_outcomes
from tkujax.model import ModelParams
from tkujax.sim.push import Push
from tkujax.sim.rollout_mjx import RolloutConfig, model_index, rollout
from tkujax.studies.spec import SpecError, SweepSpec, load_spec

OUTCOME_KEYS = ("fell", "recovery_time_s", "step_length_m", "step_width_m", "peak_incl_deg",
                "capture_point_m", "capture_point_y_m", "zmp_excursion_m")
MANIFEST = "manifest.json"


def controller_params_from(base: ControllerParams, overrides: dict) -> ControllerParams:
    """Apply spec-style overrides (`*_deg` keys in degrees) to `base`."""
    values = {}
    for k, v in overrides.items():
        if k.endswith("_deg"):
            values[k[:-4]] = v * (math.pi / 180.0)   # v may be traced: no math.radians
        else:
            values[k] = v
    return dataclasses.replace(base, **values)


def load_params_json(path: str | Path) -> ControllerParams:
    """ControllerParams from a JSON object {field: value} (SI units, radians), as tune writes."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise SpecError(f"--params {path}: cannot read JSON: {err}") from err
    fields = {f.name for f in dataclasses.fields(ControllerParams)}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise SpecError(f"--params {path}: unknown field(s) {unknown}; allowed: {sorted(fields)}")
    return dataclasses.replace(ControllerParams.paper(), **{k: float(v) for k, v in data.items()}
                               ).validate()


def step_override(rec: dict) -> StepOverride:
    """The StepOverride of record(s) with step_* columns (onset_s is filled by the rollout)."""
    return StepOverride(active=rec["step_active"], x_m=rec["step_x_m"], y_m=rec["step_y_m"],
                        start_delay_s=rec["step_start_delay_s"],
                        from_detection=rec["step_from_detection"], period_s=rec["step_period_s"],
                        onset_s=rec["onset_s"])


def outcome_keys(steps: bool) -> tuple[str, ...]:
    """Columns a chunk writes: the outcomes, plus the capture-region ones for [step] sweeps."""
    return OUTCOME_KEYS + (CAPTURE_KEYS if steps else ())


def randomize_model(model, mass_scale, torso_com_dx, friction, kp_scale, chest_body: int):
    """The MJX model with per-push randomisation applied (all traced jax-array fields)."""
    gain = model.actuator_gainprm.at[:, 0].multiply(kp_scale)
    bias = model.actuator_biasprm.at[:, 1].multiply(kp_scale)
    pair_friction = jnp.where(friction > 0, model.pair_friction.at[:, :2].set(friction),
                              model.pair_friction)
    return model.replace(
        body_mass=model.body_mass * mass_scale,
        body_inertia=model.body_inertia * mass_scale,
        body_ipos=model.body_ipos.at[chest_body, 0].add(torso_com_dx),
        actuator_gainprm=gain, actuator_biasprm=bias, pair_friction=pair_friction)


@functools.lru_cache(maxsize=8)
def make_chunk_fn(base_params: ControllerParams, varied: tuple[str, ...],
                  duration_s: float, model_params: ModelParams | None = None,
                  steps: bool = False):
    """jit(vmap) of one push record -> outcomes. `varied`: controller fields given per record;
    steps: records carry a commanded step (step_* columns, a [step] sweep).

    Cached, so sweeps run in one process share the compiled function."""
    host = physics.host_model(model_params)
    model, index = physics.device_model(model_params), model_index(model_params)
    state = physics.stand_state(host, 1.0)
    config = RolloutConfig(duration_s=duration_s)
    chest = index.chest_body

    def one(rec, key):
        push = Push(rec["impulse_ns"], jnp.radians(rec["azimuth_deg"]), rec["height_m"],
                    rec["duration_s"], rec["onset_s"])
        params = controller_params_from(base_params, {k: rec[k] for k in varied})
        m = randomize_model(model, rec["link_mass_scale"], rec["torso_com_offset_x_m"],
                            rec["floor_friction"], rec["servo_kp_scale"], chest)
        series = rollout(m, state, push, params, rec["control"], key, rec["gyro_noise_std"],
                         rec["accel_noise_std"], config, index,
                         step_override(rec) if steps else None)
        out = rollout_outcomes(series, push.onset_s)
        res = {k: out[k] for k in OUTCOME_KEYS}
        return res | (capture_outcomes(series, push.onset_s, params.gravity) if steps else {})

    return jax.jit(jax.vmap(one))


BACKENDS = ("auto", "mjx", "mujoco")


def choose_backend(requested: str, spec: SweepSpec) -> str:
    """"auto": MJX on a GPU/TPU; on a CPU, MuJoCo C (about 5x faster there) when the spec
    allows it. The MuJoCo C path takes one controller parameter set and one model per sweep:
    [controller.grid] and per-push model randomisation need MJX."""
    if requested not in BACKENDS:
        raise SpecError(f"backend must be one of {BACKENDS}, got {requested!r}")
    needs_mjx = [k for k in spec.randomize if k not in ("gyro_noise_std", "accel_noise_std")
                 or isinstance(spec.randomize[k], tuple)]
    if spec.controller_grid:
        needs_mjx.append("controller.grid")
    if requested == "mujoco" and needs_mjx:
        raise SpecError(f"backend 'mujoco' cannot vary {needs_mjx} per push; use backend 'mjx'")
    if requested != "auto":
        return requested
    return "mjx" if jax.default_backend() != "cpu" or needs_mjx else "mujoco"


@jax.jit
def _capture_outcomes_batch(series, onset_s, gravity):
    return jax.vmap(capture_outcomes, in_axes=(0, 0, None))(series, onset_s, gravity)


def _mujoco_chunk(batch: dict, seed: int, base: ControllerParams, duration_s: float,
                  model_params: ModelParams | None, steps: bool = False) -> dict:
    """One chunk on MuJoCo C (tkujax.backend_mujoco), outcomes as numpy."""
    from tkujax.sim.rollout_mujoco import simulate_mujoco

    pushes = Push(*(jnp.asarray(v, jnp.float32) for v in (
        batch["impulse_ns"], np.radians(batch["azimuth_deg"]), batch["height_m"],
        batch["duration_s"], batch["onset_s"])))
    overrides = step_override({k: jnp.asarray(v, jnp.float32) for k, v in batch.items()}
                              ) if steps else None
    series, out = simulate_mujoco(pushes, batch["control"].astype(np.float32), base, seed=seed,
                                  gyro_noise_std=float(batch["gyro_noise_std"][0]),
                                  accel_noise_std=float(batch["accel_noise_std"][0]),
                                  model_params=model_params,
                                  config=RolloutConfig(duration_s=duration_s), overrides=overrides)
    res = {k: np.asarray(out[k]) for k in OUTCOME_KEYS}
    if steps:
        cap = _capture_outcomes_batch(jax.tree_util.tree_map(jnp.asarray, series),
                                      pushes.onset_s, float(base.gravity))
        res |= {k: np.asarray(v) for k, v in cap.items()}
    return res


def _spec_hash(spec: SweepSpec, params: ControllerParams) -> str:
    blob = json.dumps([spec.raw, dataclasses.asdict(params)], sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _versions() -> dict:
    out = {"python": platform.python_version()}
    for pkg in ("tkujax", "jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def _git_commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, timeout=5).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def _record_inputs(spec: SweepSpec) -> dict[str, np.ndarray]:
    recs = spec.records()
    from tkujax.studies.spec import RANDOMIZE_DEFAULTS
    n = len(recs["push_id"])
    for k, v in RANDOMIZE_DEFAULTS.items():
        if k not in recs:
            recs[k] = np.full(n, -1.0 if v is None else v)   # friction -1: keep the model's
    return recs


class Progress:
    """A one-line progress report on stderr: pushes done, pushes/s, ETA."""

    def __init__(self, total: int, done: int, stream=sys.stderr):
        self.total, self.done, self.stream = total, done, stream
        self.t0, self.done0 = time.perf_counter(), done

    def restart(self) -> None:
        self.t0, self.done0 = time.perf_counter(), self.done

    def note(self, text: str) -> None:
        print(f"\r{text}", end="", file=self.stream, flush=True)

    def update(self, n: int) -> None:
        self.done += n
        dt = time.perf_counter() - self.t0
        rate = (self.done - self.done0) / dt if dt > 0 and self.done > self.done0 else 0.0
        eta = (self.total - self.done) / rate if rate > 0 else float("nan")
        pct = 100.0 * self.done / max(self.total, 1)
        print(f"\rpushes {self.done}/{self.total} ({pct:5.1f}%)  {rate:8.1f} pushes/s  "
              f"ETA {eta:6.0f} s   ", end="", file=self.stream, flush=True)

    def close(self) -> None:
        print(file=self.stream, flush=True)


def _chunk_path(out: Path, i: int) -> Path:
    return out / f"chunk_{i:06d}.npz"


def run_sweep(spec: SweepSpec | str | Path, out: str | Path, params: ControllerParams | None = None,
              model_params: ModelParams | None = None, max_chunks: int | None = None,
              process_id: int | None = None, num_processes: int | None = None,
              coordinator: str | None = None, quiet: bool = False,
              wait_for_others_s: float = 3600.0, backend: str = "auto") -> dict:
    """Run (or resume) a sweep into `out`. Returns the manifest.

    max_chunks: stop after computing this many new chunks (for tests and partial runs).
    Multi-process: process 0 waits up to `wait_for_others_s` for the other processes' chunks
    before writing the final manifest. backend: "auto" (see `choose_backend`), "mjx" or
    "mujoco"; the manifest records which ran (the spec hash does not include it, so a sweep
    can be resumed on another machine; outcomes agree across backends except near the fall
    boundary).
    """
    spec = spec if isinstance(spec, SweepSpec) else load_spec(spec)
    params = params or ControllerParams.paper()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)

    process_id = int(os.environ.get("TKUJAX_PROCESS_ID", 0)) if process_id is None else process_id
    num_processes = (int(os.environ.get("TKUJAX_NUM_PROCESSES", 1)) if num_processes is None
                     else num_processes)
    coordinator = coordinator or os.environ.get("TKUJAX_COORDINATOR")
    if num_processes > 1:
        if not coordinator:
            raise SpecError("num_processes > 1 needs a coordinator address HOST:PORT")
        jax.distributed.initialize(coordinator_address=coordinator, num_processes=num_processes,
                                   process_id=process_id)

    backend = choose_backend(backend, spec)
    digest = _spec_hash(spec, params)
    manifest_path = out / MANIFEST
    old = json.loads(manifest_path.read_text()) if manifest_path.exists() else {}
    if old:
        if old.get("spec_hash") != digest:
            raise SpecError(f"{out} holds a different sweep (spec hash {old.get('spec_hash')} != "
                            f"{digest}); choose another --out")

    recs = _record_inputs(spec)
    n = len(recs["push_id"])
    n_chunks = math.ceil(n / spec.chunk_size)
    mine = [i for i in range(n_chunks) if i % num_processes == process_id]
    todo = [i for i in mine if not _chunk_path(out, i).exists()]
    manifest = dict(name=spec.name, spec=spec.raw, spec_hash=digest, n_pushes=n,
                    chunk_size=spec.chunk_size, n_chunks=n_chunks,
                    controller_params=dataclasses.asdict(params), versions=_versions(),
                    git_commit=_git_commit(), devices=[str(d) for d in jax.devices()],
                    num_processes=num_processes, backend=backend,
                    format="npz chunks, one record per push")
    previous_wall = float(old.get("wall_s", 0.0))
    if process_id == 0:
        manifest_path.write_text(json.dumps({**manifest, "complete": False, "wall_s": previous_wall},
                                            indent=1, default=str))

    devices = jax.local_devices()
    mesh = Mesh(np.array(devices), ("push",))
    sharding = NamedSharding(mesh, PartitionSpec("push"))
    # Pad every chunk to one shape (a multiple of the device count): one compile for all.
    padded = math.ceil(spec.chunk_size / len(devices)) * len(devices)
    varied = tuple(sorted(spec.controller_grid))
    base = controller_params_from(params, spec.controller)
    steps = bool(spec.step_grid)
    fn = (make_chunk_fn(base, varied, spec.duration_s, model_params, steps) if backend == "mjx"
          else None)
    input_keys = [k for k in recs if k not in ("push_id", "from_grid", "case_id")]

    progress = Progress(len(mine) * spec.chunk_size, (len(mine) - len(todo)) * spec.chunk_size,
                        open(os.devnull, "w") if quiet else sys.stderr)
    t_start = time.perf_counter()
    computed = 0
    for i in todo:
        if max_chunks is not None and computed >= max_chunks:
            break
        lo, hi = i * spec.chunk_size, min((i + 1) * spec.chunk_size, n)
        if computed == 0:
            progress.note("compiling the rollout (first chunk; minutes on a CPU) ...")
        if backend == "mujoco":
            res = _mujoco_chunk({k: recs[k][lo:hi] for k in input_keys}, spec.seed + i, base,
                                spec.duration_s, model_params, steps)
        else:
            batch = {k: np.resize(recs[k][lo:hi], padded).astype(np.float32) for k in input_keys}
            batch = {k: jax.device_put(v, sharding) for k, v in batch.items()}
            keys = jax.device_put(jax.random.split(jax.random.fold_in(
                jax.random.PRNGKey(spec.seed), i), padded), sharding)
            res = jax.tree_util.tree_map(lambda x: np.asarray(x)[:hi - lo], fn(batch, keys))
        record = {k: recs[k][lo:hi] for k in recs} | res
        tmp = out / f".chunk_{i:06d}.tmp.npz"
        np.savez(tmp, **record)
        os.replace(tmp, _chunk_path(out, i))
        computed += 1
        progress.update(hi - lo)
        if computed == 1:
            progress.restart()   # later rates and ETAs exclude the compile
    progress.close()
    wall = time.perf_counter() - t_start

    if process_id == 0 and num_processes > 1 and (max_chunks is None):
        # The other processes write their chunks into the same folder: wait for them (bounded)
        # so that the manifest says whether the sweep as a whole is complete.
        deadline = time.monotonic() + wait_for_others_s
        while (time.monotonic() < deadline
               and not all(_chunk_path(out, i).exists() for i in range(n_chunks))):
            time.sleep(1.0)
    complete = all(_chunk_path(out, i).exists() for i in range(n_chunks))
    manifest.update(complete=complete, wall_s=round(previous_wall + wall, 2),
                    chunks_computed_last_run=computed)
    if process_id == 0:
        manifest_path.write_text(json.dumps(manifest, indent=1, default=str))
    return manifest


def load(out: str | Path) -> dict[str, np.ndarray]:
    """All records of a sweep folder as a dict of columns (chunks in order)."""
    out = Path(out)
    files = sorted(out.glob("chunk_*.npz"))
    if not files:
        raise FileNotFoundError(f"no sweep chunks in {out}")
    parts = []
    for f in files:
        with np.load(f) as z:
            parts.append({k: z[k] for k in z.files})
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
