"""The closed loop: MJX physics + sensors + the paper's controller, as one pure rollout.

Per control period (30 ms): read the IMU (through its low-pass when the model has one;
optional Gaussian noise), run `controller_step`,
quantise the leg targets to the servos' 0.088 deg resolution (straight-through gradient), hold
them for `substeps` physics steps while the push's force acts through `xfrc_applied`. A
`lax.scan` over periods, each with a scan over its substeps (`RolloutConfig.loop="nested"`), or
one scan over physics steps with the period's work in `lax.cond`s (`"flat"`, the sweeps');
`jax.vmap` over pushes, controller parameters and model parameters.

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
import mujoco
import numpy as np

from tkujax.sim import physics, tree_passes
from tkujax.control.controller import ControllerOutput, StepOverride, controller_init
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
    # jax.checkpoint (less memory under grad): False / "none": off; True / "tick": each control
    # tick (the program True always gave); "tick_nocse": the same with prevent_cse=False (JAX's
    # advice inside scan); "tick_dots": each tick, saving the results of matrix products
    # (jax.checkpoint_policies.dots_with_no_batch_dims_saveable); "substep": each physics
    # substep instead; "nested": each tick and each substep. See REMAT_MODES.
    remat: bool | str = False
    # The FPGA twin of the controller (issue 15); None: the float controller (its program is
    # unchanged by this field: the choice is a Python branch on None at trace time).
    fixed: FixedPointConfig | None = None
    # lax.scan unrolling of the control-tick scan and of each tick's physics-substep scan
    # (1: a rolled loop, the default program); in the flat loop, unroll_substeps unrolls its
    # scan over physics steps and unroll_ticks is unused. Same arithmetic, another structure.
    unroll_ticks: int = 1
    unroll_substeps: int = 1
    # The loop structure (LOOPS): "nested", a scan over control ticks, each with a scan over
    # its physics substeps; "flat", one scan over physics steps, the control tick and the
    # Series row in `lax.cond`s on the step counter (not batched, so vmap keeps them branches;
    # remat's tick checkpoint then wraps the control tick alone). The same arithmetic: the
    # Series agree to float rounding (XLA fuses the two programs differently). The sweeps run
    # "flat" (tkujax.studies.sweep.SWEEP_LOOP, with its XLA options: faster at batch 1,024 on
    # a GPU); gradients and `simulate` keep "nested".
    loop: str = "nested"
    # MJX's passes over the body tree inside each physics step (TREE_PASSES): "mjx", MJX's own
    # (`mjx.forward`); "compact", tkujax.sim.tree_passes: the kinematics, com_vel and rne with
    # MJX's formulas traced once for all bodies (MJX traces each per body group): one step's
    # program a third smaller, its gradient's 41 %; equal to float rounding. The tuner runs
    # "compact" (TUNE_TREE_PASSES); the sweeps keep "mjx", so their committed results replay
    # bit for bit on the same device.
    tree_passes: str = "mjx"
    # Benchmark-only stand-ins (`tkujax bench --profile`; () everywhere else), each a Python
    # branch at trace time, see ABLATIONS: "noise": no sensor-noise draws; "controller": no
    # controller, the leg targets hold the stand pose; "wrench": no push wrench (xfrc_applied
    # stays 0); "records": no Series, the rollout returns the pelvis height per tick instead.
    ablate: tuple[str, ...] = ()


_quantise = quantise_targets   # the name the C backend and older code use

REMAT_MODES = (False, True, "none", "tick", "tick_nocse", "tick_dots", "substep", "nested")
ABLATIONS = ("noise", "controller", "wrench", "records")
LOOPS = ("nested", "flat")
TREE_PASSES = ("mjx", "compact")


def _checkpoints(remat: bool | str):
    """(wrap for the tick function, wrap for the substep function) of a RolloutConfig.remat."""
    if remat not in REMAT_MODES:
        raise ValueError(f"RolloutConfig.remat must be one of {REMAT_MODES}, got {remat!r}")
    same = lambda f: f   # noqa: E731
    if remat in (False, "none"):
        return same, same
    if remat in (True, "tick"):
        return jax.checkpoint, same
    if remat == "tick_nocse":
        return functools.partial(jax.checkpoint, prevent_cse=False), same
    if remat == "tick_dots":
        return functools.partial(
            jax.checkpoint, policy=jax.checkpoint_policies.dots_with_no_batch_dims_saveable), same
    if remat == "substep":
        return same, functools.partial(jax.checkpoint, prevent_cse=False)
    return jax.checkpoint, functools.partial(jax.checkpoint, prevent_cse=False)   # nested


def _is_float(x) -> bool:
    return jnp.issubdtype(jnp.result_type(x), jnp.floating)


def _seed_carry(carry, inputs):
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


def _push_wrench(idx: ModelIndex, d: mjx.Data, push: Push) -> jax.Array:
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
            index: ModelIndex | None = None, override: StepOverride | None = None,
            schedule=None) -> Series:
    """Simulate one robot under one push with the controller in the loop.

    Args:
      model, state: MJX model and initial state (the settled `stand` keyframe:
        `tkujax.sim.setup.init`).
      push: the Push (scalars). params: ControllerParams. enabled: 1 = balance control on.
      key: PRNG key for sensor noise. gyro_noise_std (rad/s), accel_noise_std (m/s^2).
      config: static settings. index: static model indices (default model when None).
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
    if fixed is not None and schedule is not None:
        raise ValueError("scheduled parameters have no fixed-point controller twin; "
                         "use RolloutConfig(fixed=None)")
    if fixed is not None and override is not None:
        raise ValueError("commanded steps (override) have no fixed-point controller twin; "
                         "use RolloutConfig(fixed=None)")
    switch = 0 if fixed is None else servo_switch_substep(fixed, substeps)
    ablate = frozenset(config.ablate)
    if not ablate <= set(ABLATIONS):
        raise ValueError(f"RolloutConfig.ablate: unknown {sorted(ablate - set(ABLATIONS))}; "
                         f"allowed {ABLATIONS}")
    if config.loop not in LOOPS:
        raise ValueError(f"RolloutConfig.loop must be one of {LOOPS}, got {config.loop!r}")
    if config.tree_passes not in TREE_PASSES:
        raise ValueError(f"RolloutConfig.tree_passes must be one of {TREE_PASSES}, "
                         f"got {config.tree_passes!r}")
    wrap_tick, wrap_substep = _checkpoints(config.remat)
    scan_substeps = functools.partial(jax.lax.scan, unroll=config.unroll_substeps)

    def imu_read(d):
        return (d.sensordata[idx.gyro_adr:idx.gyro_adr + 3],
                d.sensordata[idx.accel_adr:idx.accel_adr + 3])

    # The IMU's own low-pass (ModelParams.accel_lowpass_hz, gyro_lowpass_hz), advanced every
    # physics step; its state rides in the carry. Off (both cutoffs 0), the carry holds the last
    # step's instantaneous reading (a Python branch: no filter in the program).
    imu_filtered = idx.imu_filtered
    # Each physics step is mjx.step's forward pass and Euler integrator with MuJoCo's sensor
    # stage off, and the two IMU sensors computed alone between them (physics.imu_reading: the
    # same values up to float rounding). The sole touch sensors, which the sensor stage would
    # compute every step, are computed once per tick, for the records
    # (physics.touch_sensordata): on an H100 at batch 1,024, stepping that computes every
    # sensor ran 15 % slower than stepping that computes none.
    lean_model = physics.without_sensors(model)
    forward = tree_passes.forward if config.tree_passes == "compact" else mjx.forward
    if model.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER:
        raise ValueError(f"the MJX rollout steps with the Euler integrator; the model has "
                         f"integrator {model.opt.integrator}")

    def physics_step(carry, _):
        d, imu = carry
        if "wrench" not in ablate:
            with jax.named_scope("push_wrench"):
                d = d.replace(xfrc_applied=_push_wrench(idx, d, push))
        with jax.named_scope("mjx_step"):     # mjx.step, less the sensors the loop reads apart
            d = forward(lean_model, d)
            with jax.named_scope("imu"):
                reading = physics.imu_reading(lean_model, d, idx)
            d = mjx.euler(lean_model, d)
        if imu_filtered:
            imu = tuple(y + jnp.asarray(a, dtype) * (x - y)
                        for y, x, a in zip(imu, reading, idx.imu_gains))
        else:
            imu = reading
        return (d, imu), None

    physics_step = wrap_substep(physics_step)

    def control(imu, ctrl_state, tick_key):
        """One control tick: the IMU reading (with noise) through the controller. Returns
        (ctrl_state, command, earlier command, out): with a fractional servo latency (the
        fixed-point twin, switch > 0) the earlier command holds until substep `switch`."""
        with jax.named_scope("sensors"):
            gyro, accel = imu
            if "noise" not in ablate:
                kg, ka = jax.random.split(tick_key)
                gyro = gyro + gyro_noise_std * jax.random.normal(kg, (3,), dtype)
                accel = accel + accel_noise_std * jax.random.normal(ka, (3,), dtype)
        with jax.named_scope("controller"):
            if "controller" in ablate:
                legs = stand_ctrl[legs_slice]
                zero = jnp.zeros((), dtype)
                out = ControllerOutput(legs, zero, zero, zero, zero, zero)
            elif fixed is None:
                ctrl_state, legs, out = control_tick(ctrl_state, gyro, accel, params, enabled,
                                                     config.quantise_targets, override,
                                                     schedule)
            else:
                ctrl_state, legs, prev, out = control_tick_fx(ctrl_state, gyro, accel, params,
                                                              enabled, config.quantise_targets,
                                                              fixed)
        command = stand_ctrl.at[legs_slice].set(legs.astype(dtype))
        earlier = (stand_ctrl.at[legs_slice].set(prev.astype(dtype)) if switch > 0
                   else command)
        return ctrl_state, command, earlier, out

    def records(d, out, ctrl_state):
        """The Series row at the end of a tick (the pelvis height alone when ablated)."""
        if "records" in ablate:
            return d.qpos[2]
        with jax.named_scope("records"):
            d = d.replace(sensordata=physics.touch_sensordata(model, d))   # the sole sensors
            pitch, roll = physics.pitch_roll_from_quat(d.qpos[3:7])
            zmp, fsr_total = _zmp(idx, d)
            return recording.tick_series(
                t=d.time, pitch=pitch, roll=roll, zmp_xy=zmp, fsr_total=fsr_total,
                com=d.subtree_com[1], r_ankle=d.site_xpos[r_ankle], l_ankle=d.site_xpos[l_ankle],
                pelvis_z=d.qpos[2], lowest_body_z=_lowest_body_point(idx, d), out=out,
                ctrl_state=ctrl_state, qpos=d.qpos if config.record_qpos else None)

    def tick(carry, tick_key):
        d, imu, ctrl_state = carry
        ctrl_state, command, earlier, out = control(imu, ctrl_state, tick_key)
        with jax.named_scope("physics"):
            if switch > 0:
                # Fractional latency: the previous command holds until the static switch substep.
                d = d.replace(ctrl=earlier)
                (d, imu), _ = scan_substeps(physics_step, (d, imu), None, length=switch)
            d = d.replace(ctrl=command)
            (d, imu), _ = scan_substeps(physics_step, (d, imu), None, length=substeps - switch)
        return (d, imu, ctrl_state), records(d, out, ctrl_state)

    init_ctrl = (controller_init(params, dtype) if fixed is None else
                 controller_init_fx(params, fixed, dtype))
    seeds = (push, params, schedule, enabled, gyro_noise_std, accel_noise_std)
    tick_keys = jax.random.split(key, n_ticks)
    if config.loop == "nested":
        carry = _seed_carry((state, imu_read(state), init_ctrl), seeds)
        _, series = jax.lax.scan(wrap_tick(tick), carry, tick_keys, unroll=config.unroll_ticks)
        return series

    # The flat loop: one scan over n_ticks * substeps physics steps. Step i opens tick
    # i // substeps when i % substeps == 0 (the controller) and closes it when
    # i % substeps == substeps - 1 (its Series row, written into a buffer in the carry). The
    # conds' predicates come from the scan counter alone, so under vmap they stay branches
    # (a batched predicate would make vmap run both sides and select).
    control_branch = wrap_tick(control)
    shapes = jax.eval_shape(control_branch, imu_read(state), init_ctrl, tick_keys[0])
    out0 = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes[3])
    row = jax.eval_shape(records, state, out0, init_ctrl)
    buffer0 = jax.tree.map(lambda a: jnp.zeros((n_ticks,) + a.shape, a.dtype), row)

    def flat_step(carry, i):
        d, imu, ctrl_state, out, command, buffer = carry
        k, j = i // substeps, i % substeps

        def open_tick(imu, ctrl_state, out, command, ctrl):
            ctrl_state, command, earlier, out = control_branch(imu, ctrl_state, tick_keys[k])
            return ctrl_state, out, command, earlier

        def keep(imu, ctrl_state, out, command, ctrl):
            return ctrl_state, out, command, ctrl

        ctrl_state, out, command, ctrl = jax.lax.cond(j == 0, open_tick, keep,
                                                      imu, ctrl_state, out, command, d.ctrl)
        if switch > 0:
            ctrl = jnp.where(j == switch, command, ctrl)
        (d, imu), _ = physics_step((d.replace(ctrl=ctrl), imu), None)

        def close_tick(buffer):
            new = records(d, out, ctrl_state)
            return jax.tree.map(lambda b, x: jax.lax.dynamic_update_index_in_dim(b, x, k, 0),
                                buffer, new)

        buffer = jax.lax.cond(j == substeps - 1, close_tick, lambda b: b, buffer)
        return (d, imu, ctrl_state, out, command, buffer), None

    carry = _seed_carry((state, imu_read(state), init_ctrl, out0, state.ctrl, buffer0), seeds)
    (*_, series), _ = jax.lax.scan(flat_step, carry,
                                   jnp.arange(n_ticks * substeps, dtype=jnp.int32),
                                   unroll=config.unroll_substeps)
    return series


@functools.lru_cache(maxsize=8)
def batched_rollout(model_params: ModelParams | None = None,
                    config: RolloutConfig = RolloutConfig(), settle_s: float = 1.0):
    """jit(vmap(rollout)) over (push, enabled, key) for one model, plus outcomes.

    Returns f(pushes, enabled, keys, params, gyro_noise_std, accel_noise_std, schedule=None)
    -> (series, outcomes), batched along axis 0; params (and a scheduled policy's Schedule,
    `tkujax.control.policy`) shared by the batch. Compiled once per batch shape (and schedule
    layout); cached per model and config.
    """
    from tkujax.sim.metrics import outcomes

    _, model, index, state = init(model_params, settle_s)

    def one(push, enabled, key, params, gyro_std, accel_std, schedule):
        series = rollout(model, state, push, params, enabled, key, gyro_std, accel_std,
                         config, index, schedule=schedule)
        return series, outcomes(series, push.onset_s)

    f = jax.jit(jax.vmap(one, in_axes=(0, 0, 0, None, None, None, None)))
    return lambda pushes, enabled, keys, params, gyro, accel, schedule=None: f(
        pushes, enabled, keys, params, gyro, accel, schedule)


def simulate(pushes: Push, enabled, params: ControllerParams, seed: int = 0,
             gyro_noise_std: float = 0.0, accel_noise_std: float = 0.0,
             model_params: ModelParams | None = None,
             config: RolloutConfig = RolloutConfig(), schedule=None) -> tuple[Series, Outcomes]:
    """Run a batch of pushes (stacked Push, leading axis) and return numpy (series, outcomes).
    schedule: a scheduled policy's Schedule (`tkujax.recommended_policy()` gives one with its
    params); None: the plain controller."""
    if config.fixed is not None:   # options the fixed-point twin lacks: refused, not ignored
        check_supported(params)
    n = int(np.shape(pushes.impulse_ns)[0])
    enabled = jnp.broadcast_to(jnp.asarray(enabled, jnp.float32), (n,))
    keys = jax.random.split(jax.random.PRNGKey(seed), n)
    f = batched_rollout(model_params, config)
    out = f(pushes, enabled, keys, params, jnp.float32(gyro_noise_std),
            jnp.float32(accel_noise_std), schedule)
    return jax.tree_util.tree_map(np.asarray, out)
