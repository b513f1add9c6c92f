"""The closed loop: MJX physics + sensors + the paper's controller, as one pure rollout.

Per control period (30 ms): read the IMU (through its low-pass when the model has one;
optional Gaussian noise), run `controller_step`, quantise the leg targets to the servos'
0.088 deg resolution (straight-through gradient), hold them for `substeps` physics steps while
the push's force acts through `xfrc_applied`. `jax.vmap` over episodes, controller parameters
and model parameters.

  tkujax.sim.options      RolloutConfig (the physics), ProgramOptions (the program), Episode
  tkujax.sim.closed_loop  the tick's pieces: physics_substep, controller_tick, record_row
  tkujax.sim.loops        nested_loop, flat_loop: the two loop structures that run them
  this module             rollout (one episode), batched_rollout (jit(vmap)), simulate

With `RolloutConfig.fixed` set, the fixed-point controller (`tkujax.control.fixed`) runs
instead, through `tick.control_tick_fx`; its fractional latency splits each tick's substep scan
at a static substep (the previous command before it, the new one after).

Time series come back at control rate; `tkujax.sim.metrics.outcomes` turns them into per-push
outcomes.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.controller import StepOverride, controller_init
from tkujax.control.fixed import check_supported, controller_init_fx
from tkujax.control.gait import WalkCommand, batch_walk
from tkujax.control.controller_params import ControllerParams
from tkujax.control.walking import walking_init
from tkujax.model import ModelParams
from tkujax.sim.closed_loop import TickPieces, imu_read, tick_pieces
from tkujax.sim.loops import flat_loop, flat_loop_carry, nested_loop
from tkujax.sim.mjx_import import mjx
from tkujax.sim.options import (LOOPS, REMAT_MODES, TREE_PASSES, Episode,  # noqa: F401
                                ProgramOptions, RolloutConfig)
from tkujax.sim.push import Push
from tkujax.sim.records import Outcomes, Series
from tkujax.sim.robot import Robot, as_robot
from tkujax.sim.setup import SETTLE_S, ModelIndex, model_index
from tkujax.sim.slope import tilt_mjx_model


def _is_float(x) -> bool:
    return jnp.issubdtype(jnp.result_type(x), jnp.floating)


def seed_carry(carry, inputs):
    """The scan's initial carry, with an exact zero computed from `inputs` subtracted from each
    of its float leaves.

    Under vmap and under differentiation, lax.scan finds which carry leaves are batched (and
    which have nonzero tangents) by a fixpoint: it processes the whole body again for every
    pass in which more leaves turn batched or differentiated. The stand state and the
    controller's initial state depend on no push and no parameter, so without this the tick
    body (and the substep scan inside it, with its own fixpoint) is processed more than once:
    the gradient's trace took 27 s instead of 16 s on a 2-core CPU. Tied to the inputs,
    the carry is batched and differentiated from the first pass, which is where the fixpoint
    ends anyway (the first tick's physics makes every state leaf depend on the push and the
    controller). The values are unchanged, bit for bit: x - zero with zero = +0.0 (0 times the
    absolute sum of the inputs' finite values) is x, the sign of a zero included."""
    total = sum(jnp.sum(jnp.where(jnp.isfinite(x), x, 0.0)) for x in jax.tree.leaves(inputs)
                if _is_float(x))
    zero = 0.0 * jnp.abs(jnp.where(jnp.isfinite(total), total, 0.0))     # +0.0, never NaN
    return jax.tree.map(lambda x: x - zero.astype(x.dtype) if _is_float(x) else x, carry)


def rollout(model: mjx.Model, state: mjx.Data, episode: Episode, params: ControllerParams,
            config: RolloutConfig = RolloutConfig(), index: ModelIndex | None = None,
            override: StepOverride | None = None, schedule=None) -> Series:
    """Simulate one robot through one episode with the controller in the loop.

    Args:
      model, state: MJX model and initial state (the settled `stand` keyframe:
        `tkujax.sim.setup.init`).
      episode: the Episode (push, enabled, noise key and levels; scalars).
      params: ControllerParams. config: static settings (its `program`: the loop's layout).
      index: static model indices (default model when None).
      override: a commanded recovery step (tkujax.control.StepOverride; its onset_s is taken
        from the push); None = the controller's own step.
      schedule: gains and thresholds as functions of the filtered state
        (`tkujax.control.policy.Schedule`, traced leaves); None = the plain controller (a
        Python branch at trace time: the default program is unchanged).
    Returns:
      the Series (tkujax.sim.records), fields (n_ticks, ...), sampled at the end of each
      control period.
    """
    idx = index or model_index()
    params = dataclasses.replace(params, control_period=config.control_period_s)
    if override is not None:
        override = dataclasses.replace(override, onset_s=episode.push.onset_s)
    model = tilt_mjx_model(model, config.floor)   # a slope
    pieces = tick_pieces(model, idx, episode, params, config, override, schedule)
    return run_tick_pieces(pieces, state, episode, params, config, idx, schedule)


def run_tick_pieces(pieces: TickPieces, state: mjx.Data, episode: Episode,
                    params: ControllerParams, config: RolloutConfig, index: ModelIndex,
                    schedule=None) -> Series:
    """Run a closed loop's TickPieces (`tkujax.sim.closed_loop.tick_pieces`, or the bench's
    stand-ins) from `state` for config.duration_s, in config.program's loop structure. `params`
    as the controller runs them (control_period set); the rows come back stacked."""
    n_ticks = int(round(config.duration_s / config.control_period_s))
    dtype = state.qpos.dtype
    init_ctrl = (controller_init(params, dtype) if config.fixed is None else
                 controller_init_fx(params, config.fixed, dtype))
    if episode.walk is not None:
        init_ctrl = walking_init(params, episode.walk, dtype)
    seeds = (episode.push, params, schedule, episode.enabled, episode.gyro_noise_std,
             episode.accel_noise_std, episode.walk)
    tick_keys = jax.random.split(episode.key, n_ticks)
    carry = (state, imu_read(index, state), init_ctrl)
    if config.program.loop == "nested":
        return nested_loop(pieces, config.program, seed_carry(carry, seeds), tick_keys)
    carry = seed_carry(flat_loop_carry(pieces, carry, tick_keys), seeds)
    return flat_loop(pieces, config.program, carry, tick_keys)


def batched_rollout(robot: Robot | ModelParams | None = None,
                    config: RolloutConfig = RolloutConfig(), settle_s: float = SETTLE_S):
    """jit(vmap(rollout)) over episodes (push, enabled, key) for one robot, plus outcomes.

    robot: a Robot (`tkujax.robot.builtin_robot`, `tkujax.robot.robot_from_file`), or a ModelParams
    or None for TKU-X (`as_robot`). Returns f(pushes, enabled, keys, params, gyro_noise_std,
    accel_noise_std, schedule=None, walk=None) -> (series, outcomes), batched along axis 0;
    params (and a scheduled policy's Schedule, `tkujax.control.policy`) shared by the batch;
    walk (a WalkCommand, batched along axis 0; None: standing). Compiled once per batch shape
    (and schedule layout, and walking or not); cached per robot and config. settle_s: the
    stand's settling before t = 0 (`Robot.sim_setup`; a robot file's: SETTLE_S only).
    """
    return robot_rollout(as_robot(robot), config, float(settle_s))


@functools.lru_cache(maxsize=8)
def robot_rollout(robot: Robot, config: RolloutConfig = RolloutConfig(),
                  settle_s: float = SETTLE_S):
    """`batched_rollout` of a Robot (cached per robot, by identity, config and settle_s)."""
    from tkujax.sim.metrics import outcomes

    _, model, index, state = robot.sim_setup(settle_s)

    def one(push, enabled, key, params, gyro_std, accel_std, schedule, walk):
        series = rollout(model, state, Episode(push, enabled, key, gyro_std, accel_std, walk),
                         params, config, index, schedule=schedule)
        return series, outcomes(series, push.onset_s)

    f = jax.jit(jax.vmap(one, in_axes=(0, 0, 0, None, None, None, None, 0)))
    return lambda pushes, enabled, keys, params, gyro, accel, schedule=None, walk=None: f(
        pushes, enabled, keys, params, gyro, accel, schedule, walk)


def simulate(pushes: Push, enabled, params: ControllerParams, seed: int = 0,
             gyro_noise_std: float = 0.0, accel_noise_std: float = 0.0,
             model_params: ModelParams | None = None,
             config: RolloutConfig = RolloutConfig(), schedule=None,
             robot: Robot | None = None,
             walk: WalkCommand | None = None) -> tuple[Series, Outcomes]:
    """Run a batch of pushes (stacked Push, leading axis) and return numpy (series, outcomes).
    schedule: a scheduled policy's Schedule (`tkujax.recommended_policy()` gives one with its
    params); None: the plain controller. robot: the Robot (`tkujax.robot.builtin_robot`,
    `tkujax.robot.robot_from_file`; its `params` are the controller's for it); model_params:
    TKU-X's ModelParams instead (None and None: the default TKU-X). walk: the robots walk
    (`tkujax.control.gait.WalkCommand`, one for the batch or stacked along axis 0); None:
    they stand."""
    robot = as_robot(robot, model_params)
    if config.fixed is not None:   # options the fixed-point twin lacks: refused, not ignored
        check_supported(params)
    n = int(np.shape(pushes.impulse_ns)[0])
    enabled = jnp.broadcast_to(jnp.asarray(enabled, jnp.float32), (n,))
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    f = robot_rollout(robot, config, SETTLE_S)
    if walk is not None:
        walk = batch_walk(walk, n)
    out = f(pushes, enabled, keys, params, jnp.float32(gyro_noise_std),
            jnp.float32(accel_noise_std), schedule, walk)
    return jax.tree_util.tree_map(np.asarray, out)
