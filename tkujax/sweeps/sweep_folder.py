"""A sweep folder's identity and provenance.

- The claim of a folder (`claim_folder`): the check that the folder holds no other sweep and the
  manifest's description of this one are one read-modify-write under the folder's lock, so of
  two writers of different sweeps started at once into one folder exactly one gets it; the
  other is refused, naming the folder and what differs (`tkujax.sweeps.sweep_hash.INPUT_NAMES`:
  every input a record depends on, by content).
- Provenance: each run appends an entry to the manifest's `runs` (run id, backend, devices, git
  commit, versions, process), and earlier entries are never rewritten; each chunk's manifest
  entry names the run, backend, device and commit that wrote it (`chunk_provenance`).
- The output folder and the process arguments, checked before anything runs (`prepare_out`,
  `processes`): errors name the path or the key and its range.
"""

from __future__ import annotations

import dataclasses
import errno
import math
import os
import secrets
import socket
import time
from pathlib import Path

import jax

from tkujax.control.fixed import FixedPointConfig
from tkujax.control.controller_params import ControllerParams
from tkujax.control.policy import Schedule, schedule_to_dict
from tkujax.model import ModelParams
from tkujax.sim.robot import Robot, as_robot
from tkujax.sweeps import chunks
from tkujax.sweeps.provenance import git_commit, versions
from tkujax.sweeps.record_schema import SCHEMA_KEY, SCHEMA_VERSION, TREE_PASSES_KEY
from tkujax.dialects.sweep_spec import SpecError, SweepSpec
from tkujax.sweeps.sweep_hash import changed_inputs

RUNS_KEY = "runs"
INPUTS_KEY = "inputs"
# The manifest's top-level provenance: the first run's, kept as it was (a manifest written
# before `runs` holds its only run's there); every run's is in `runs`.
PROVENANCE_KEYS = ("versions", "git_commit", "devices", "num_processes", "backend")
# Processes of one sweep: the most `num_processes` may be (a sanity bound on a typo).
MAX_PROCESSES = 65_536


def _integer_arg(key: str, value, lo: int, hi: int) -> int:
    if isinstance(value, str):
        try:
            value = int(value.strip())
        except ValueError:
            raise SpecError(f"{key}: expected an integer in [{lo}, {hi}], got {value!r}") from None
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise SpecError(f"{key}: expected an integer in [{lo}, {hi}], got {value!r}")
    return value


def processes(process_id, num_processes, coordinator) -> tuple[int, int, str | None]:
    """(process_id, num_processes, coordinator) from the arguments or the TKUJAX_* environment
    variables, checked: num_processes in [1, MAX_PROCESSES], process_id in [0, num_processes);
    more than one process needs a coordinator HOST:PORT. SpecError names the key."""
    n_key = "num_processes" if num_processes is not None else "TKUJAX_NUM_PROCESSES"
    id_key = "process_id" if process_id is not None else "TKUJAX_PROCESS_ID"
    n = _integer_arg(n_key, os.environ.get("TKUJAX_NUM_PROCESSES", "1")
                     if num_processes is None else num_processes, 1, MAX_PROCESSES)
    k = _integer_arg(id_key, os.environ.get("TKUJAX_PROCESS_ID", "0")
                     if process_id is None else process_id, 0, n - 1)
    coordinator = coordinator or os.environ.get("TKUJAX_COORDINATOR")
    if n > 1 and not coordinator:
        raise SpecError("coordinator: num_processes > 1 needs a coordinator address HOST:PORT")
    return k, n, coordinator


def prepare_out(out: Path) -> Path:
    """`out` created (with its parents) as a folder; an OSError names the path and what is
    wrong (a file in the way, no permission, a name too long)."""
    for parent in (out, *out.parents):
        if parent.exists() and not parent.is_dir():
            raise NotADirectoryError(errno.ENOTDIR, "not a folder (a file has that name)",
                                     str(parent))
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK | os.X_OK):
        raise PermissionError(errno.EACCES, "the folder is not writable", str(out))
    return out


def model_record(robot: Robot | ModelParams | None) -> dict:
    """The manifest's model: TKU-X's ModelParams fields, or a robot file's name, path and
    sha256 (`Robot.record`)."""
    return as_robot(robot).record()


def describe(spec: SweepSpec, digest: str, n: int, n_chunks: int, padded: int,
             params: ControllerParams, robot: Robot | None, num_processes: int,
             backend: str, schedule: Schedule | None = None) -> dict:
    """The manifest's description of the sweep (every writer restates it, the provenance keys
    only when absent), in the record schema's newest version
    (`tkujax.sweeps.record_schema`)."""
    manifest = {SCHEMA_KEY: SCHEMA_VERSION} | dict(
        name=spec.name, spec=spec.raw, spec_hash=digest, n_pushes=n,
        chunk_size=spec.chunk_size, n_chunks=n_chunks, padded_chunk=padded,
        controller_params=dataclasses.asdict(params),
        model_params=model_record(robot),
        versions=versions(), git_commit=git_commit(),
        devices=[str(d) for d in jax.devices()], num_processes=num_processes,
        backend=backend, format="npz chunks, one record per push",
        **{TREE_PASSES_KEY: spec.tree_passes}, **spec.decisions.describe())
    if spec.arithmetic == "fixed":
        manifest["fixed_point_defaults"] = dataclasses.asdict(FixedPointConfig())
    if spec.ensemble is not None:
        manifest["ensemble"] = spec.ensemble.describe()
    if schedule is not None:
        manifest["schedule"] = schedule_to_dict(schedule)
    return manifest


def run_record(backend: str, process_id: int, num_processes: int) -> dict:
    """This run's entry of the manifest's `runs`: a run id unique to it, where and on what it
    ran."""
    host = socket.gethostname()
    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    devices = ["cpu (MuJoCo C)"] if backend == "mujoco" else [str(d) for d in jax.local_devices()]
    return dict(run_id=f"{stamp}-{host}-{os.getpid()}-{secrets.token_hex(3)}", started=stamp,
                host=host, pid=os.getpid(), backend=backend, devices=devices,
                device_kind=device_kind(backend),
                git_commit=git_commit(), versions=versions(), process_id=process_id,
                num_processes=num_processes)


def device_kind(backend: str = "mjx") -> str:
    """The device a run computes on, in words (e.g. "NVIDIA H200", "cpu (MuJoCo C)"): the first
    device JAX computes on, or MuJoCo C's CPU."""
    if backend == "mujoco":
        return "cpu (MuJoCo C)"
    d = jax.local_devices()[0]
    return getattr(d, "device_kind", "") or d.platform


def computed_on(manifest: dict) -> str:
    """The devices, in words, of the runs that computed a sweep folder's chunks (a resumed
    sweep's chunks may come from another machine than the process reading it); "" when its
    runs predate the record."""
    kinds = [r["device_kind"] for r in computing_runs(manifest) if r.get("device_kind")]
    return ", ".join(dict.fromkeys(kinds))


def computing_runs(manifest: dict) -> list[dict]:
    """A sweep manifest's runs that computed chunks (a run recorded before `chunks_computed`
    counts as one that did)."""
    return [r for r in manifest.get("runs", []) if r.get("chunks_computed", 1)]


def computed_with(out: Path) -> str | None:
    """The engine ("mjx" or "mujoco") that computed the chunks of the sweep folder `out`: the
    backend of its runs that computed chunks (else its manifest's); None for no sweep there,
    or for one whose chunks came from both engines."""
    manifest = chunks.read_manifest(out)
    engines = {r["backend"] for r in computing_runs(manifest) if r.get("backend")}
    if not engines and manifest.get("backend"):
        engines = {manifest["backend"]}
    return engines.pop() if len(engines) == 1 else None


def chunk_provenance(run: dict) -> dict:
    """What a chunk's manifest entry records of the run that wrote it."""
    return dict(run_id=run["run_id"], backend=run["backend"], device=", ".join(run["devices"]),
                git_commit=run["git_commit"])


# How far a kept sweep's controller parameters may differ from a resuming run's and still be
# that sweep's: the last bits of a robot file's geometry, which its stand's kinematics give
# machine by machine (the Berkeley Humanoid's hip offset, 0.06713400932671565 m on one
# H200's host, 0.0671340093267157 m on this project's CPU). tests/test_sweep_resume_machine.py
PARAMS_REL_TOL = 1e-12


def params_as_held(out: Path, params: ControllerParams, digest_of) -> ControllerParams:
    """The controller parameters a sweep in `out` ran with, when they differ from `params` by
    rounding only (every field within PARAMS_REL_TOL) and make its spec hash
    (`digest_of(params) -> hash`): a run resumed on another machine goes on with them. Else
    `params` (and a changed sweep is refused as before, `claim_folder`)."""
    held = chunks.read_manifest(out)
    stored = held.get("controller_params")
    mine = dataclasses.asdict(params)
    if not stored or set(stored) != set(mine) or digest_of(params) == held.get("spec_hash"):
        return params
    for k, v in mine.items():
        w = stored[k]
        if not (isinstance(w, (int, float)) and not isinstance(w, bool)
                and math.isclose(float(v), float(w), rel_tol=PARAMS_REL_TOL, abs_tol=1e-15)):
            return params
    candidate = ControllerParams(**{k: float(w) for k, w in stored.items()})
    return candidate if digest_of(candidate) == held.get("spec_hash") else params


def refusal(out: Path, held: dict, description: dict, inputs: dict) -> str:
    """The message refusing to write sweep `description` into `out`, which holds `held`."""
    changed = changed_inputs(held.get(INPUTS_KEY), inputs)
    what = (f"changed since it ran: {'; '.join(changed)}" if changed else
            f"it holds sweep {held.get('name')!r}, this is {description.get('name')!r}")
    return (f"{out} holds another spec's sweep (spec hash {held.get('spec_hash')} != "
            f"{description['spec_hash']}): {what}. Nothing was written: choose another --out, "
            "or restore the inputs to resume it")


def claim_folder(out: Path, description: dict, inputs: dict, run: dict) -> dict:
    """Check and claim `out` for the sweep `description` under one lock: SpecError (naming the
    folder and what differs) when its manifest holds another sweep; else the manifest
    (re)states the description, keeps the first run's provenance and its chunk entries, and
    appends `run` to `runs`."""
    def claim(held: dict) -> dict:
        if held and held.get("spec_hash") != description["spec_hash"]:
            raise SpecError(refusal(out, held, description, inputs))
        runs = list(held.get(RUNS_KEY, []))
        if held and not runs:   # written before `runs`: its top level is its one run
            runs.append({"run_id": "before-run-history"} | {
                k: held.get(k) for k in PROVENANCE_KEYS})
        first = {k: held[k] for k in PROVENANCE_KEYS if k in held}
        return {**description, **first, INPUTS_KEY: inputs, RUNS_KEY: runs + [run],
                "complete": False, "wall_s": float(held.get("wall_s", 0.0)),
                "chunks": held.get("chunks", {})}
    return chunks.update_manifest(out, claim)
