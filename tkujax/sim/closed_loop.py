"""The pieces of one control tick of the MJX closed loop, each a pure function.

  physics_substep   one physics step: the push's wrench, MJX's forward pass (MuJoCo's sensor
                    stage off), the IMU alone, the Euler integrator, the IMU's low-pass;
  noisy_imu         the IMU reading with the episode's Gaussian noise;
  controller_tick   the controller (float or fixed-point) on that reading: the actuator
                    command of the tick (and the earlier one of a fractional servo latency);
  record_row        the tick's Series row (sole sensors, ZMP, lowest point, controller state).

`tick_pieces` binds the model, episode and controller into a `TickPieces` whose functions take
the traced state alone; `tkujax.sim.loops` runs them. The benchmark's profile
(`tkujax.bench.profile`) builds its stand-in loops by replacing some of these pieces.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from tkujax.control.controller import StepOverride
from tkujax.control.fixed import servo_switch_substep
from tkujax.control.controller_params import ControllerParams
from tkujax.sim.leg_chain import chain_targets
from tkujax.sim import physics, recording, tree_passes
from tkujax.sim.mjx_import import mjx
from tkujax.sim.options import Episode, RolloutConfig, checkpoints
from tkujax.sim.push import Push, force_at, kick_velocity
from tkujax.sim.setup import ModelIndex
from tkujax.sim.tick import control_tick, control_tick_fx


@dataclasses.dataclass(frozen=True)
class TickPieces:
    """One control tick's pieces, the static model, episode and controller bound in.

    substep((d, imu)) -> (d, imu): one physics step (checkpointed as ProgramOptions.remat asks).
    control(imu, ctrl_state, key) -> (ctrl_state, command, earlier command, controller output):
      `earlier` holds for the first `switch` substeps (the fixed-point twin's fractional servo
      latency; switch 0: none, earlier is command).
    record(d, out, ctrl_state) -> the tick's Series row.
    """

    substep: Callable
    control: Callable
    record: Callable
    substeps: int          # physics steps per control tick
    switch: int            # the substep at which `command` replaces `earlier` (0: none)


def push_wrench(idx: ModelIndex, d: mjx.Data, push: Push) -> jax.Array:
    """(nbody, 6) xfrc_applied for the push at time d.time (force and moment about the CoM)."""
    force = force_at(push, d.time)
    local = jnp.stack([0.0, 0.0, (push.height_m - idx.chest_stand_z) / idx.chest_stand_cos])
    point = d.xpos[idx.chest_body] + d.xmat[idx.chest_body] @ local
    torque = jnp.cross(point - d.xipos[idx.chest_body], force)
    # A select on a static one-hot row rather than a scatter into zeros: the same values (and
    # a NaN wrench stays on its body), as elementwise code that XLA can fuse with its readers.
    row = (np.arange(d.xfrc_applied.shape[0]) == idx.chest_body)[:, None]
    return jnp.where(row, jnp.concatenate([force, torque])[None, :],
                     jnp.zeros_like(d.xfrc_applied))


def imu_read(idx: ModelIndex, d: mjx.Data) -> tuple[jax.Array, jax.Array]:
    """The (gyro, accel) entries of a state's sensordata: the loop's initial IMU carry."""
    return (d.sensordata[idx.gyro_adr:idx.gyro_adr + 3],
            d.sensordata[idx.accel_adr:idx.accel_adr + 3])


def physics_substep(lean_model: mjx.Model, idx: ModelIndex, forward: Callable,
                    push: Push | None, carry):
    """One physics step of (d, imu): mjx.step's forward pass and Euler integrator with MuJoCo's
    sensor stage off (`lean_model`), the two IMU sensors computed alone between them
    (physics.imu_reading: the same values up to float rounding). The sole touch sensors, which
    the sensor stage would compute every step, are computed once per tick by `record_row`: on
    an H100 at batch 1,024, stepping that computes every sensor ran 15 % slower.

    The IMU's own low-pass (ModelParams.accel_lowpass_hz, gyro_lowpass_hz) advances every step;
    its state rides in the carry. Off (idx.imu_filtered false), the carry holds the last step's
    instantaneous reading. push None: no wrench (xfrc_applied as it is)."""
    d, imu = carry
    if push is not None and push.kick_mps is not None:   # a velocity kick (Push.kick_mps)
        with jax.named_scope("push_kick"):
            dv = kick_velocity(push, d.time, idx.timestep_s).astype(d.qvel.dtype)
            d = d.replace(qvel=d.qvel.at[:2].add(dv))
    elif push is not None:
        with jax.named_scope("push_wrench"):
            d = d.replace(xfrc_applied=push_wrench(idx, d, push))
    with jax.named_scope("mjx_step"):     # mjx.step, less the sensors the loop reads apart
        d = forward(lean_model, d)
        with jax.named_scope("imu"):
            reading = physics.imu_reading(lean_model, d, idx)
        d = mjx.euler(lean_model, d)
    if idx.imu_filtered:
        dtype = d.qpos.dtype
        imu = tuple(y + jnp.asarray(a, dtype) * (x - y)
                    for y, x, a in zip(imu, reading, idx.imu_gains))
    else:
        imu = reading
    return d, imu


def noisy_imu(imu, key: jax.Array, episode: Episode):
    """The (gyro, accel) reading with the episode's Gaussian noise (one draw per tick)."""
    gyro, accel = imu
    kg, ka = jax.random.split(key)
    gyro = gyro + episode.gyro_noise_std * jax.random.normal(kg, (3,), gyro.dtype)
    accel = accel + episode.accel_noise_std * jax.random.normal(ka, (3,), accel.dtype)
    return gyro, accel


def legs_slice(idx: ModelIndex) -> slice:
    """The leg actuators, as a static slice: they are contiguous (tkujax.model.JOINT_NAMES ends
    with them); an index array's integer dtype would follow the x64 mode at trace time."""
    first = int(idx.leg_actuators[0])
    assert np.array_equal(idx.leg_actuators, np.arange(first, first + len(idx.leg_actuators)))
    return slice(first, first + len(idx.leg_actuators))


def controller_tick(idx: ModelIndex, episode: Episode, params: ControllerParams,
                    config: RolloutConfig, override: StepOverride | None, schedule, switch: int,
                    sense: Callable, imu, ctrl_state, key: jax.Array):
    """One control tick: the IMU reading through `sense(imu, key, episode)` (`noisy_imu`; the
    bench's profile gives a stand-in) and the controller. Returns (ctrl_state, command,
    earlier command, out): with a fractional servo latency (the fixed-point twin, switch > 0)
    the earlier command holds until substep `switch`."""
    with jax.named_scope("sensors"):
        gyro, accel = sense(imu, key, episode)
    with jax.named_scope("controller"):
        if config.fixed is None:
            ctrl_state, legs, out = control_tick(ctrl_state, gyro, accel, params,
                                                 episode.enabled, config.quantise_targets,
                                                 override, schedule, episode.walk)
        else:
            ctrl_state, legs, prev, out = control_tick_fx(ctrl_state, gyro, accel, params,
                                                          episode.enabled,
                                                          config.quantise_targets, config.fixed)
    stand_ctrl = jnp.asarray(idx.stand_ctrl, gyro.dtype)
    command = set_legs(idx, stand_ctrl, legs.astype(gyro.dtype))
    earlier = set_legs(idx, stand_ctrl, prev.astype(gyro.dtype)) if switch > 0 else command
    return ctrl_state, command, earlier, out


def map_legs(idx: ModelIndex, legs: jax.Array) -> jax.Array:
    """The controller's leg targets (TKU-X's joint conventions) as the robot's: each slot's
    sign and offset (ModelIndex.leg_signs, leg_offsets), or another chain's linear map
    (leg_chain: its IK; tkujax.sim.leg_chain); TKU-X's model: unchanged."""
    dtype = legs.dtype
    if idx.leg_chain is not None:
        return chain_targets(idx.leg_chain, legs)
    if idx.leg_matrix is not None:
        # HIGHEST: no reduced-precision (TF32) matmul on GPUs for the servo targets.
        return (jnp.matmul(legs, jnp.asarray(idx.leg_matrix.T, dtype),
                           precision=jax.lax.Precision.HIGHEST)
                + jnp.asarray(idx.leg_offsets, dtype))
    if idx.leg_signs is None:
        return legs
    return legs * jnp.asarray(idx.leg_signs, dtype) + jnp.asarray(idx.leg_offsets, dtype)


def set_legs(idx: ModelIndex, ctrl: jax.Array, legs: jax.Array) -> jax.Array:
    """`ctrl` with the leg actuators set to `legs` (controller slot order, mapped by
    `map_legs`). TKU-X's leg actuators are one block; a robot file's may be in any order (OP3
    lists its left leg first): one static slice per run of consecutive actuator ids."""
    legs = map_legs(idx, legs)
    if idx.leg_signs is None and idx.leg_matrix is None:
        return ctrl.at[legs_slice(idx)].set(legs)
    ids = [int(i) for i in idx.leg_actuators]
    k = 0
    for a, b in _runs(ids):
        ctrl = ctrl.at[a:b].set(legs[k:k + b - a])
        k += b - a
    return ctrl


def _runs(ids) -> list[tuple[int, int]]:
    """Static ids as (start, stop) runs of consecutive ids, in order."""
    runs: list[tuple[int, int]] = []
    for i in (int(i) for i in ids):
        if runs and runs[-1][1] == i:
            runs[-1] = (runs[-1][0], i + 1)
        else:
            runs.append((i, i + 1))
    return runs


def _rows(x: jax.Array, ids) -> jax.Array:
    """x[ids] for static ids, as static slices, one per run of consecutive ids (the eight sole
    sensors are one slice): no integer index array is traced, so nothing depends on the x64
    mode (index arrays traced under x64 after being cached under x32 gave int32/int64
    mismatches)."""
    parts = [x[a:b] for a, b in _runs(ids)]
    return parts[0] if len(parts) == 1 else jnp.concatenate(parts)


def lowest_body_point(idx: ModelIndex, d: mjx.Data) -> jax.Array:
    """Height of the lowest point of any non-foot collision geom, m (spheres, boxes, capsules,
    cylinders and, for a robot file's model, meshes: their lowest vertex)."""
    # Model constants cast to the state's dtype explicitly (never left to the x64 mode).
    dtype = d.geom_xpos.dtype
    boxes = {}
    if idx.box_geoms.size:
        boxes = dict(box_z=_rows(d.geom_xpos, idx.box_geoms)[:, 2],
                     box_zrow=_rows(d.geom_xmat, idx.box_geoms)[:, 2, :],  # world z row
                     box_half_sizes=jnp.asarray(idx.box_half_sizes, dtype))
    sphere_z = (_rows(d.geom_xpos, idx.sphere_geoms)[:, 2] if idx.sphere_geoms.size
                else jnp.zeros((0,), dtype))
    points = [jnp.stack([jnp.min(d.geom_xpos[g, 2] + jnp.asarray(pts, dtype) @ d.geom_xmat[g, 2])
                         for g, pts in zip(idx.mesh_geoms, idx.mesh_points)])
              ] if idx.mesh_geoms else []
    for geoms, sizes, capsule in ((idx.capsule_geoms, idx.capsule_sizes, True),
                                  (idx.cylinder_geoms, idx.cylinder_sizes, False)):
        if geoms.size:      # the axis's world z: the geom frame's z column's z, xmat[2, 2]
            points.append(recording.axial_lows(jnp, _rows(d.geom_xpos, geoms)[:, 2],
                                               _rows(d.geom_xmat, geoms)[:, 2, 2],
                                               jnp.asarray(sizes, dtype), capsule))
    return recording.lowest_point(jnp, sphere_z, jnp.asarray(idx.sphere_radii, dtype),
                                  point_z=jnp.concatenate(points) if points else None, **boxes)


def _zmp(idx: ModelIndex, d: mjx.Data) -> tuple[jax.Array, jax.Array]:
    """Centre of pressure of the eight sole sensors (world x, y), and their total force (N)."""
    return recording.zmp(jnp, _rows(d.sensordata, idx.fsr_adr),
                         _rows(d.site_xpos, idx.fsr_sites)[:, :2])


def record_row(model: mjx.Model, idx: ModelIndex, record_qpos: bool, d: mjx.Data, out,
               ctrl_state):
    """The Series row at the end of a tick: the sole sensors computed once
    (physics.touch_sensordata), inclinations, ZMP, feet, lowest body point, the controller's."""
    r_ankle, l_ankle = idx.ankle_sites
    with jax.named_scope("records"):
        d = d.replace(sensordata=physics.touch_sensordata(model, d))   # the sole sensors
        pitch, roll = physics.pitch_roll_from_quat(d.qpos[3:7])
        zmp, fsr_total = _zmp(idx, d)
        return recording.tick_series(
            t=d.time, pitch=pitch, roll=roll, zmp_xy=zmp, fsr_total=fsr_total,
            com=d.subtree_com[1], r_ankle=d.site_xpos[r_ankle], l_ankle=d.site_xpos[l_ankle],
            pelvis_z=d.qpos[2], lowest_body_z=lowest_body_point(idx, d), out=out,
            ctrl_state=ctrl_state, qpos=d.qpos if record_qpos else None)


def check_walk(config: RolloutConfig, override, schedule) -> None:
    """Walking (Episode.walk) runs the float controller alone: no fixed-point twin, commanded
    step or schedule."""
    for name, value in (("a fixed-point controller (RolloutConfig.fixed)", config.fixed),
                        ("commanded steps (override)", override),
                        ("a scheduled policy (schedule)", schedule)):
        if value is not None:
            raise ValueError(f"walking (WalkCommand) does not run with {name}")


def tick_pieces(model: mjx.Model, idx: ModelIndex, episode: Episode, params: ControllerParams,
                config: RolloutConfig, override: StepOverride | None = None,
                schedule=None) -> TickPieces:
    """The closed loop's TickPieces for one episode. `params` as the controller runs them
    (control_period set); `override`, `schedule`: as `rollout` takes them."""
    if model.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER:
        raise ValueError(f"the MJX rollout steps with the Euler integrator; the model has "
                         f"integrator {model.opt.integrator}")
    if config.fixed is not None and schedule is not None:
        raise ValueError("scheduled parameters have no fixed-point controller twin; "
                         "use RolloutConfig(fixed=None)")
    if config.fixed is not None and override is not None:
        raise ValueError("commanded steps (override) have no fixed-point controller twin; "
                         "use RolloutConfig(fixed=None)")
    if episode.walk is not None:
        check_walk(config, override, schedule)
    substeps = int(round(config.control_period_s / idx.timestep_s))
    switch = 0 if config.fixed is None else servo_switch_substep(config.fixed, substeps)
    forward = tree_passes.forward if config.program.tree_passes == "compact" else mjx.forward
    _, wrap_substep = checkpoints(config.program.remat)
    substep = functools.partial(physics_substep, physics.without_sensors(model), idx, forward,
                                episode.push)
    return TickPieces(
        substep=wrap_substep(substep),
        control=functools.partial(controller_tick, idx, episode, params, config, override,
                                  schedule, switch, noisy_imu),
        record=functools.partial(record_row, model, idx, config.record_qpos),
        substeps=substeps, switch=switch)
