"""A sweep chunk on MuJoCo C: one batch per setting present in the chunk, outcomes as numpy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.params_files import controller_params_from
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim.metrics import capture_outcomes, walk_outcomes
from tkujax.sim.push import Push
from tkujax.sim.rollout_mjx import RolloutConfig
from tkujax.sim.slope import LEVEL_FLOOR, Floor
from tkujax.sweeps.chunk_program import OUTCOME_KEYS, step_override
from tkujax.dialects.sweep_spec import FPGA_COLUMN, ROBOT_ID_COLUMN, EnsembleRef, fixed_point_config
from tkujax.dialects.sequence_table import pulse_fields
from tkujax.dialects.walk_table import WALK_COLUMNS, walk_commands


@jax.jit
def _walk_outcomes_batch(series, start_s):
    return jax.vmap(walk_outcomes, in_axes=(0, None))(series, start_s)


@jax.jit
def _capture_outcomes_batch(series, onset_s, gravity):
    return jax.vmap(capture_outcomes, in_axes=(0, 0, None))(series, onset_s, gravity)


def mujoco_chunk(batch: dict, seed: int, base: ControllerParams, duration_s: float,
                 model_params: ModelParams | None, with_qpos: bool = False,
                 varied: tuple[str, ...] = (), steps: bool = False,
                 fpga: dict | None = None, fpga_varied: tuple[str, ...] = (),
                 ensemble: EnsembleRef | None = None, schedule=None, walk=None,
                 floor: Floor = LEVEL_FLOOR) -> dict:
    """One chunk on MuJoCo C (tkujax.sim.rollout_mujoco), outcomes (and qpos) as numpy: one
    batch per controller-grid point present in the chunk (`varied` names the grid's fields; the
    controller's parameters are shared by a batch there). steps: records carry a commanded step
    (step_* columns, a [step] sweep) and get the capture-region columns too. fpga: the [fpga]
    values of a fixed-point sweep (None: float controller), fpga_varied: its gridded keys
    (columns fpga_<key>): one batch per (controller-grid point, FixedPointConfig). ensemble: a
    [randomize] ensemble: one batch per member too (column robot_id; model_params is then
    unused: each batch runs its member's ModelParams). schedule: a scheduled policy's Schedule
    (None: the plain controller). walk: a [walk] sweep's base WalkCommand (the records'
    walk_* columns set each robot's walk) with the WALK_KEYS outcomes; None: standing.
    floor: a slope (tkujax.sim.slope.Floor)."""
    from tkujax.sim.rollout_mujoco import simulate_mujoco

    n = len(batch["onset_s"])
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
        pulses = pulse_fields(batch)     # a [push.sequence]: (n, k) fields
        kick = pulses.get("kick_mps")    # velocity kicks: no force pulse
        size = pulses["impulse_ns"] if kick is None else np.zeros_like(kick)
        pushes = Push(*(jnp.asarray(v[sel], jnp.float32) for v in (
            size, np.radians(pulses["azimuth_deg"]), batch["height_m"], batch["duration_s"],
            pulses["onset_s"])), kick_mps=None if kick is None else jnp.asarray(
                kick[sel], jnp.float32))
        overrides = step_override({k: jnp.asarray(v[sel], jnp.float32) for k, v in batch.items()}
                                  ) if steps else None
        walks = None if walk is None else walk_commands(walk, {
            k: np.asarray(batch[k][sel], np.float32) for k in WALK_COLUMNS})
        series, out = simulate_mujoco(
            pushes, batch["control"][sel].astype(np.float32), params, seed=seed,
            gyro_noise_std=float(batch["gyro_noise_std"][0]),
            accel_noise_std=float(batch["accel_noise_std"][0]), model_params=robot,
            config=RolloutConfig(duration_s=duration_s, record_qpos=with_qpos, fixed=fixed,
                                 floor_pitch_deg=floor.pitch_deg,
                                 floor_roll_deg=floor.roll_deg),
            overrides=overrides, schedule=schedule, walk=walks)
        fields = {k: np.asarray(out[k]) for k in OUTCOME_KEYS}
        if with_qpos:
            fields["qpos"] = np.asarray(series.qpos)
        if walk is not None:
            moved = _walk_outcomes_batch(jax.tree_util.tree_map(jnp.asarray, series),
                                         float(walk.start_s))
            fields |= {k: np.asarray(v) for k, v in moved.items()}
        if steps:
            cap = _capture_outcomes_batch(jax.tree_util.tree_map(jnp.asarray, series),
                                          pushes.onset_s, float(params.gravity))
            fields |= {k: np.asarray(v) for k, v in cap.items()}
        for k, v in fields.items():
            res.setdefault(k, np.empty((n,) + v.shape[1:], v.dtype))[sel] = v
    return res
