"""The compiled program of a sweep chunk on MJX, and the records it takes.

`make_chunk_fn` builds jit(vmap) of push records -> outcomes; `record_inputs` expands a spec
into the records' input columns; `fpga_groups` splits records by fixed-point config (one
program each); `chunk_keys` derives a chunk's noise keys. The sweep runner
(`tkujax.sweeps.sweep`), the replay and the benchmark share these, so they run one program.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.controller import StepOverride
from tkujax.control.fixed import FixedPointConfig
from tkujax.control.params_files import controller_params_from
from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim.metrics import CAPTURE_KEYS, WALK_KEYS, capture_outcomes, walk_outcomes
from tkujax.sim.metrics import outcomes as rollout_outcomes
from tkujax.sim.push import Push, first_onset
from tkujax.sim.randomize import randomize_model
from tkujax.sim.rollout_mjx import Episode, ProgramOptions, RolloutConfig, rollout
from tkujax.sim.robot import Robot, as_robot
from tkujax.sim.slope import LEVEL_FLOOR, Floor
from tkujax.dialects.sweep_spec import (FPGA_COLUMN, RANDOMIZE_DEFAULTS, ROBOT_ID_COLUMN,
                                        SWEEP_TREE_PASSES, EnsembleRef, SpecError, SweepSpec)
from tkujax.dialects.sequence_table import pulse_fields
from tkujax.dialects.walk_table import walk_commands

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
# alone gains (results/bench/README.md). XLA options are per program here, not
# process-wide; on a CPU the GPU option is ignored.
SWEEP_LOOP = "flat"
SWEEP_COMPILER_OPTIONS = {"xla_gpu_graph_min_graph_size": 1}

OUTCOME_KEYS = ("fell", "diverged", "recovery_time_s", "step_length_m", "step_width_m",
                "peak_incl_deg", "capture_point_m", "capture_point_y_m", "zmp_excursion_m")


def step_override(rec: dict) -> StepOverride:
    """The StepOverride of record(s) with step_* columns (onset_s is filled by the rollout)."""
    return StepOverride(active=rec["step_active"], x_m=rec["step_x_m"], y_m=rec["step_y_m"],
                        start_delay_s=rec["step_start_delay_s"],
                        from_detection=rec["step_from_detection"], period_s=rec["step_period_s"],
                        onset_s=rec["onset_s"],
                        **{k: rec[f"step_{k}"] for k in ("steps", "x2_m", "y2_m", "delay2_s")
                           if f"step_{k}" in rec})


def outcome_keys(steps: bool, walking: bool = False) -> tuple[str, ...]:
    """Columns a chunk writes: the outcomes, plus the capture-region ones for [step] sweeps
    and the walking ones (WALK_KEYS) for [walk] sweeps."""
    return OUTCOME_KEYS + (CAPTURE_KEYS if steps else ()) + (WALK_KEYS if walking else ())


def traced_params(params: ControllerParams) -> ControllerParams:
    """Every leaf as a float32 array: a new parameter set is a new *input* of the compiled chunk,
    never a new constant (Python floats would be weakly typed; jnp arrays keep one signature)."""
    return jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), params)


def make_chunk_fn(varied: tuple[str, ...], duration_s: float,
                  model_params: ModelParams | None = None, with_qpos: bool = False,
                  steps: bool = False, fixed: FixedPointConfig | None = None,
                  ensemble: EnsembleRef | None = None, unroll_substeps: int | None = None,
                  tree_passes: str = SWEEP_TREE_PASSES[0], walk=None,
                  floor: Floor = LEVEL_FLOOR):
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
    SWEEP_UNROLL_SUBSTEPS. The outcomes do not depend on it (tests/test_perf_equivalence).
    tree_passes: ProgramOptions.tree_passes (SweepSpec.tree_passes; the sweeps' default sums
    the tree in a fixed order, repeatable on a GPU).
    walk: a [walk] sweep's base WalkCommand (python floats: part of the cache key; the
    records' walk_* columns set its speeds, step period and recovery, traced), with the
    WALK_KEYS outcomes; None: the robots stand. floor: a slope (tkujax.sim.slope.Floor; part of
    the cache key)."""
    if ensemble is not None and model_params is not None:
        raise SpecError("[randomize] ensemble gives the robots: pass no model_params with it")
    unroll = SWEEP_UNROLL_SUBSTEPS if unroll_substeps is None else int(unroll_substeps)
    if unroll < 1:
        raise ValueError(f"unroll_substeps must be >= 1, got {unroll_substeps!r}")
    # Positional call into the cache: lru_cache keys f(a, b) and f(a, b, steps=False) apart,
    # which would compile the same program twice.
    return _make_chunk_fn(tuple(varied), duration_s, model_params, with_qpos, steps, fixed,
                          ensemble, unroll, tree_passes, walk, floor)


@functools.lru_cache(maxsize=4)
def ensemble_robots(ensemble: EnsembleRef):
    """The RobotSet of an ensemble's members (`tkujax.sim.robots`), cached by the file's content
    (EnsembleRef compares by sha256)."""
    from tkujax.sim.robots import robot_set
    try:
        return robot_set(ensemble.members)
    except ValueError as err:
        raise SpecError(f"randomize.ensemble: {ensemble.path}: {err}") from None


def sweep_base(model_params: Robot | ModelParams | None, ensemble: EnsembleRef | None):
    """(model, index, stand state, RobotSet or None) of a sweep: its one robot (a Robot, or
    TKU-X's ModelParams: `as_robot`), or an ensemble's base model with its members'
    RobotSet."""
    if ensemble is None:
        robot = as_robot(model_params)
        return robot.device_model, robot.index, robot.stand_state, None
    robots = ensemble_robots(ensemble)
    return robots.base_model, robots.index, robots.base_state, robots


def record_episode(base, rec: dict, key, base_params: ControllerParams, varied: tuple[str, ...],
                   steps: bool, robot_values=None, walk=None):
    """One record's (model, stand state, Episode, ControllerParams, StepOverride or None):
    its push, its controller-grid values over `base_params`, its ensemble member (with
    `robot_values`, the RobotSet's values) and its [randomize] draws; with `walk` (a [walk]
    sweep's base WalkCommand) its walk. `base` from `sweep_base`."""
    from tkujax.sim.robots import put_leaves

    model, index, state, robots = base
    pulses = pulse_fields(rec, jnp)   # a [push.sequence]: (k,) fields
    kick = pulses.get("kick_mps")     # velocity kicks: no force pulse
    push = Push(pulses["impulse_ns"] if kick is None else jnp.zeros_like(kick),
                jnp.radians(pulses["azimuth_deg"]), rec["height_m"], rec["duration_s"],
                pulses["onset_s"], kick)
    params = controller_params_from(base_params, {k: rec[k] for k in varied})
    m, s = model, state
    if robot_values is not None:   # this record's ensemble member
        rid = rec[ROBOT_ID_COLUMN].astype(jnp.int32)
        m = put_leaves(model, robots.model_leaf_ids, robot_values[0], rid)
        s = put_leaves(state, robots.state_leaf_ids, robot_values[1], rid)
    m = randomize_model(m, index.chest_body, mass_scale=rec["link_mass_scale"],
                        torso_com_dx_m=rec["torso_com_offset_x_m"],
                        friction=rec["floor_friction"], kp_scale=rec["servo_kp_scale"])
    command = None if walk is None else walk_commands(walk, rec)
    episode = Episode(push, rec["control"], key, rec["gyro_noise_std"], rec["accel_noise_std"],
                      command)
    return m, s, episode, params, (step_override(rec) if steps else None)


@functools.lru_cache(maxsize=16)
def _make_chunk_fn(varied, duration_s, model_params, with_qpos, steps, fixed, ensemble, unroll,
                   tree_passes, walk, floor):
    base = sweep_base(model_params, ensemble)
    index, robots = base[1], base[3]
    config = RolloutConfig(duration_s=duration_s, record_qpos=with_qpos, fixed=fixed,
                           program=ProgramOptions(unroll_substeps=unroll, loop=SWEEP_LOOP,
                                                  tree_passes=tree_passes),
                           floor_pitch_deg=floor.pitch_deg, floor_roll_deg=floor.roll_deg)

    def one(rec, key, base_params, schedule, robot_values=None):
        m, s, episode, params, override = record_episode(base, rec, key, base_params, varied,
                                                         steps, robot_values, walk)
        series = rollout(m, s, episode, params, config, index, override, schedule)
        out = rollout_outcomes(series, first_onset(episode.push))
        res = {k: out[k] for k in OUTCOME_KEYS} | ({"qpos": series.qpos} if with_qpos else {})
        if walk is not None:
            res |= walk_outcomes(series, walk.start_s)
        return res | (capture_outcomes(series, episode.push.onset_s, params.gravity)
                      if steps else {})

    if ensemble is None:
        def chunk(batch, keys, params, schedule=None):
            return jax.vmap(one, in_axes=(0, 0, None, None))(batch, keys, params, schedule)

        return jax.jit(chunk, compiler_options=SWEEP_COMPILER_OPTIONS)
    # The members' values are arguments of the program, not constants baked into it.
    fn = jax.jit(jax.vmap(one, in_axes=(0, 0, None, None, None)),
                 compiler_options=SWEEP_COMPILER_OPTIONS)
    values = robots.values()
    return lambda batch, keys, params, schedule=None: fn(batch, keys, params, schedule, values)


def record_inputs(spec: SweepSpec) -> dict[str, np.ndarray]:
    """The spec's records with every [randomize] column (an unrandomised one at its default)."""
    recs = spec.records()
    n = len(recs["push_id"])
    for k, v in RANDOMIZE_DEFAULTS.items():
        if k not in recs:
            recs[k] = np.full(n, -1.0 if v is None else v)   # friction -1: keep the model's
    return recs


def fpga_groups(spec: SweepSpec, rec: dict) -> list[tuple[FixedPointConfig | None, np.ndarray]]:
    """The records' (FixedPointConfig, row indices) groups: one static config per compiled
    program. A float sweep, or one without an fpga grid, is a single group of every row."""
    n = len(rec["onset_s"])
    if not spec.fpga_grid:
        return [(spec.fixed_point_config(), np.arange(n))]
    cols = [FPGA_COLUMN + k for k in spec.fpga_grid]
    points, which = np.unique(np.stack([rec[c] for c in cols], 1), axis=0, return_inverse=True)
    return [(spec.fixed_point_config(dict(zip(cols, p))), np.flatnonzero(which.ravel() == j))
            for j, p in enumerate(points)]


def chunk_keys(seed: int, chunk: int, padded: int) -> jax.Array:
    """The MJX noise keys of one chunk: one per (padded) record."""
    return jax.random.split(jax.random.fold_in(jax.random.PRNGKey(seed), chunk), padded)
