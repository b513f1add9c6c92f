"""The closed loop: MJX physics + sensors + the paper's controller, as one pure rollout.

Per control period (30 ms): read the IMU (optional Gaussian noise), run `controller_step`,
quantise the leg targets to the servos' 0.088 deg resolution (straight-through gradient), hold
them for `substeps` physics steps while the push's force acts through `xfrc_applied`. A
`lax.scan` over periods; `jax.vmap` over pushes, controller parameters and model parameters.

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

from tkujax.sim import physics
from tkujax.control.controller import StepOverride, controller_init
from tkujax.control.fixed import (FixedPointConfig, check_supported, controller_init_fx,
                                  servo_switch_substep)
from tkujax.control.params import ControllerParams
from tkujax.sim.mjx_import import mjx
from tkujax.model import ModelParams
from tkujax.sim import recording
from tkujax.sim.push import CONTROL_PERIOD_S, Push, force_at
from tkujax.sim.records import Outcomes, Series
from tkujax.sim.setup import ModelIndex, init, model_index
from tkujax.sim.tick import (SERVO_RESOLUTION_RAD, control_tick, control_tick_fx,  # noqa: F401
                             quantise_targets)


@dataclasses.dataclass(frozen=True)
class RolloutConfig:
    """Static settings (changing them recompiles)."""

    duration_s: float = 2.4
    control_period_s: float = CONTROL_PERIOD_S
    quantise_targets: bool = True
    record_qpos: bool = False      # add the full qpos to the series (for rendering)
    remat: bool = False            # jax.checkpoint the control tick (less memory under grad)
    # The FPGA twin of the controller (issue 15); None: the float controller (its program is
    # unchanged by this field: the choice is a Python branch on None at trace time).
    fixed: FixedPointConfig | None = None


_quantise = quantise_targets   # the name the C backend and older code use


def _push_wrench(idx: ModelIndex, d: mjx.Data, push: Push) -> jax.Array:
    """(nbody, 6) xfrc_applied for the push at time d.time (force and moment about the CoM)."""
    force = force_at(push, d.time)
    local = jnp.stack([0.0, 0.0, (push.height_m - idx.chest_stand_z) / idx.chest_stand_cos])
    point = d.xpos[idx.chest_body] + d.xmat[idx.chest_body] @ local
    torque = jnp.cross(point - d.xipos[idx.chest_body], force)
    return jnp.zeros_like(d.xfrc_applied).at[idx.chest_body].set(jnp.concatenate([force, torque]))


def _rows(x: jax.Array, ids) -> jax.Array:
    """x[ids] for static ids, as static slices: no integer index array is traced, so nothing
    depends on the x64 mode (index arrays traced under x64 after being cached under x32 gave
    int32/int64 mismatches)."""
    return jnp.stack([x[int(i)] for i in ids])


def _lowest_body_point(idx: ModelIndex, d: mjx.Data) -> jax.Array:
    """Height of the lowest point of any non-foot collision geom, m."""
    # Model constants cast to the state's dtype explicitly (never left to the x64 mode).
    dtype = d.geom_xpos.dtype
    boxes = {}
    if idx.box_geoms.size:
        boxes = dict(box_z=_rows(d.geom_xpos, idx.box_geoms)[:, 2],
                     box_zrow=_rows(d.geom_xmat, idx.box_geoms)[:, 2, :],  # world z row
                     box_half_sizes=jnp.asarray(idx.box_half_sizes, dtype))
    return recording.lowest_point(jnp, _rows(d.geom_xpos, idx.sphere_geoms)[:, 2],
                                  jnp.asarray(idx.sphere_radii, dtype), **boxes)


def _zmp(idx: ModelIndex, d: mjx.Data) -> tuple[jax.Array, jax.Array]:
    """Centre of pressure of the eight sole sensors (world x, y), and their total force (N)."""
    return recording.zmp(jnp, _rows(d.sensordata, idx.fsr_adr),
                         _rows(d.site_xpos, idx.fsr_sites)[:, :2])


def rollout(model: mjx.Model, state: mjx.Data, push: Push, params: ControllerParams,
            enabled: jax.Array, key: jax.Array, gyro_noise_std: jax.Array = 0.0,
            accel_noise_std: jax.Array = 0.0, config: RolloutConfig = RolloutConfig(),
            index: ModelIndex | None = None, override: StepOverride | None = None) -> Series:
    """Simulate one robot under one push with the controller in the loop.

    Args:
      model, state: MJX model and initial state (the settled `stand` keyframe:
        `tkujax.sim.setup.init`).
      push: the Push (scalars). params: ControllerParams. enabled: 1 = balance control on.
      key: PRNG key for sensor noise. gyro_noise_std (rad/s), accel_noise_std (m/s^2).
      config: static settings. index: static model indices (default model when None).
      override: a commanded recovery step (tkujax.control.StepOverride; its onset_s is taken
        from the push); None = the controller's own step.
    Returns:
      the Series (tkujax.sim.records), fields (n_ticks, ...), sampled at the end of each
      control period.
    """
    idx = index or model_index()
    substeps = int(round(config.control_period_s / idx.timestep_s))
    n_ticks = int(round(config.duration_s / config.control_period_s))
    params = dataclasses.replace(params, control_period=config.control_period_s)
    dtype = state.qpos.dtype
    if override is not None:
        override = dataclasses.replace(override, onset_s=push.onset_s)
    stand_ctrl = jnp.asarray(idx.stand_ctrl, dtype)
    r_ankle, l_ankle = idx.ankle_sites
    # The leg actuators are contiguous (tkujax.model.JOINT_NAMES ends with them): a static slice
    # rather than an index array, whose integer dtype would follow the x64 mode at trace time.
    first = int(idx.leg_actuators[0])
    assert np.array_equal(idx.leg_actuators, np.arange(first, first + len(idx.leg_actuators)))
    legs_slice = slice(first, first + len(idx.leg_actuators))
    fixed = config.fixed
    if fixed is not None and override is not None:
        raise ValueError("commanded steps (override) have no fixed-point controller twin; "
                         "use RolloutConfig(fixed=None)")
    switch = 0 if fixed is None else servo_switch_substep(fixed, substeps)

    def physics_step(d, _):
        d = d.replace(xfrc_applied=_push_wrench(idx, d, push))
        return mjx.step(model, d), None

    def tick(carry, tick_key):
        d, ctrl_state = carry
        gyro = d.sensordata[idx.gyro_adr:idx.gyro_adr + 3]
        accel = d.sensordata[idx.accel_adr:idx.accel_adr + 3]
        kg, ka = jax.random.split(tick_key)
        gyro = gyro + gyro_noise_std * jax.random.normal(kg, (3,), dtype)
        accel = accel + accel_noise_std * jax.random.normal(ka, (3,), dtype)
        if fixed is None:
            ctrl_state, legs, out = control_tick(ctrl_state, gyro, accel, params, enabled,
                                                 config.quantise_targets, override)
        else:
            ctrl_state, legs, prev, out = control_tick_fx(ctrl_state, gyro, accel, params,
                                                          enabled, config.quantise_targets, fixed)
            # Fractional latency: the previous command holds until the static switch substep.
            if switch > 0:
                d = d.replace(ctrl=stand_ctrl.at[legs_slice].set(prev.astype(dtype)))
                d, _ = jax.lax.scan(physics_step, d, None, length=switch)
        d = d.replace(ctrl=stand_ctrl.at[legs_slice].set(legs.astype(dtype)))
        d, _ = jax.lax.scan(physics_step, d, None, length=substeps - switch)
        pitch, roll = physics.pitch_roll_from_quat(d.qpos[3:7])
        zmp, fsr_total = _zmp(idx, d)
        series = recording.tick_series(
            t=d.time, pitch=pitch, roll=roll, zmp_xy=zmp, fsr_total=fsr_total,
            com=d.subtree_com[1], r_ankle=d.site_xpos[r_ankle], l_ankle=d.site_xpos[l_ankle],
            pelvis_z=d.qpos[2], lowest_body_z=_lowest_body_point(idx, d), out=out,
            ctrl_state=ctrl_state, qpos=d.qpos if config.record_qpos else None)
        return (d, ctrl_state), series

    carry = (state, controller_init(params, dtype) if fixed is None else
             controller_init_fx(params, fixed, dtype))
    tick_fn = jax.checkpoint(tick) if config.remat else tick
    _, series = jax.lax.scan(tick_fn, carry, jax.random.split(key, n_ticks))
    return series


@functools.lru_cache(maxsize=8)
def batched_rollout(model_params: ModelParams | None = None,
                    config: RolloutConfig = RolloutConfig(), settle_s: float = 1.0):
    """jit(vmap(rollout)) over (push, enabled, key) for one model, plus outcomes.

    Returns f(pushes, enabled, keys, params, gyro_noise_std, accel_noise_std) ->
    (series, outcomes), batched along axis 0; params is shared by the batch. Compiled once
    per batch shape; cached per model and config.
    """
    from tkujax.sim.metrics import outcomes

    _, model, index, state = init(model_params, settle_s)

    def one(push, enabled, key, params, gyro_std, accel_std):
        series = rollout(model, state, push, params, enabled, key, gyro_std, accel_std,
                         config, index)
        return series, outcomes(series, push.onset_s)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, 0, None, None, None)))


def simulate(pushes: Push, enabled, params: ControllerParams, seed: int = 0,
             gyro_noise_std: float = 0.0, accel_noise_std: float = 0.0,
             model_params: ModelParams | None = None,
             config: RolloutConfig = RolloutConfig()) -> tuple[Series, Outcomes]:
    """Run a batch of pushes (stacked Push, leading axis) and return numpy (series, outcomes)."""
    if config.fixed is not None:   # options the fixed-point twin lacks: refused, not ignored
        check_supported(params)
    n = int(np.shape(pushes.impulse_ns)[0])
    enabled = jnp.broadcast_to(jnp.asarray(enabled, jnp.float32), (n,))
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    f = batched_rollout(model_params, config)
    out = f(pushes, enabled, keys, params, jnp.float32(gyro_noise_std),
            jnp.float32(accel_noise_std))
    return jax.tree_util.tree_map(np.asarray, out)
