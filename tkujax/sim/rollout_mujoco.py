"""CPU backend: MuJoCo C physics, the JAX controller vectorised over all pushes.

`simulate_mujoco` has the semantics and outputs of `tkujax.sim.rollout_mjx.simulate` (MJX), so
callers can switch backends. Per control period:

  1. read every robot's IMU (gyro, accelerometer) from the sensordata of the previous physics
     step (or, with the model's IMU low-pass, its filter advanced over every step), add
     Gaussian noise (numpy RNG: same law as MJX, not the same realisation);
  2. run ONE jitted, vmapped `controller_step` over the whole batch (compiled once per batch
     shape), quantise the leg targets to the servo resolution exactly as the MJX loop
     (`tkujax.sim.tick.control_tick`, shared);
  3. set ctrl = the stand ctrl with the leg actuators replaced, and advance every robot
     `substeps` physics steps with `mujoco.rollout` (a persistent `Rollout(nthread=...)` thread
     pool: the physics runs across all cores, the GIL released).

With `RolloutConfig.fixed` the fixed-point controller runs (`tick.control_tick_fx`, one compiled
tick per FixedPointConfig); for a fractional latency each robot's per-substep ctrl holds the
previous command until the switch substep, exactly as in the MJX loop.

The push (`push.force_at`, a half-sine force at a point of the chest axis, with its moment
about the chest CoM, as `rollout_mjx._push_wrench`) goes in through `xfrc_applied`, given to
`mujoco.rollout` per step as part of the control (control_spec = mjSTATE_CTRL |
mjSTATE_XFRC_APPLIED). The moment depends on the chest orientation, which rollout cannot feed
back inside a chunk of steps, so two modes:

  push_wrench="exact" (default): periods in which some push acts are stepped one physics step
    per rollout call, the wrench of each step computed from the chest pose MJX uses for it
    (MJX applies `_push_wrench` to d.xpos / d.xmat / d.xipos, which after `mjx.step` hold the
    kinematics of the qpos *before* the previous step; this backend reproduces that lag).
    Periods without any push run as one rollout chunk of `substeps` steps.
  push_wrench="period_start": every period is one chunk; the force keeps its exact per-step
    time profile, but the lever arm (chest orientation) is frozen at the pose used for the
    period's first step. The 20 ms pulse spans 1-2 periods of 30 ms. Measured on the test
    batch (onset 0.75 s, so the pulse lies in one period; 0.3-2.2 N s from behind / in front):
    the chest turns by up to 1.2 deg while the force acts; for sagittal pushes the moment
    error is second order in that angle (the lever arm turns in the plane of the force):
    <= 1.2 mN m, 0.1 % of the peak moment, changing the pitch trace by <= 0.19 deg and the
    step length by <= 0.2 mm, no fall outcome. Sideways / oblique pushes make it first order
    (a few % of the moment). tests/test_backend_mujoco.py prints the effect.

Warm start: MuJoCo's solver (here Newton with a single iteration, so the warm start matters)
starts from the previous step's qacc. `mujoco.rollout` takes it as `initial_warmstart` but
does not return it; with the Euler integrator and eulerdamp disabled, qvel_next = qvel +
dt * qacc exactly, so it is recovered as (qvel[-1] - qvel[-2]) / dt and chained between
chunks: the chunked run is the same trajectory as one uninterrupted mj_step loop (to
round-off; tests check it).

Series kinematics follow MJX's convention too: positions (ankles, CoM, sole sensor sites,
collision geoms) are those MJX leaves in d.site_xpos etc. after the last step of the period
(the kinematics of the state before that step), while pitch, roll and pelvis_z come from the
final qpos.

Differences that remain against MJX: float64 physics (MJX runs float32), MuJoCo C's own
collision routines and solver implementation, and the noise realisation.
"""

from __future__ import annotations

import dataclasses
import functools
import os

import jax
import jax.numpy as jnp
import mujoco
import mujoco.rollout
import numpy as np

from tkujax.control.controller import StepOverride, controller_init
from tkujax.control.fixed import (FixedPointConfig, check_supported, controller_init_fx,
                                  servo_switch_substep)
from tkujax.control.gait import WalkCommand, batch_walk
from tkujax.control.controller_params import ControllerParams
from tkujax.control.walking import walking_init
from tkujax.model import ModelParams
from tkujax.sim.leg_chain import chain_targets_host
from tkujax.sim import physics, recording
from tkujax.sim.closed_loop import check_walk
from tkujax.sim.metrics import outcomes as _outcomes
from tkujax.sim.push import PULSE_FIELDS, Push, first_onset
from tkujax.sim.records import SERIES_FIELDS, Outcomes, Series
from tkujax.sim.rollout_mjx import RolloutConfig
from tkujax.sim.robot import Robot, as_robot
from tkujax.sim.setup import ModelIndex
from tkujax.sim.kicks_host import kick_ticks
from tkujax.sim.slope import Floor, tilt_host_model
from tkujax.sim.tick import control_tick, control_tick_fx

PUSH_WRENCH_MODES = ("exact", "period_start")

_FULL = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
_CTRL = int(mujoco.mjtState.mjSTATE_CTRL)
_CTRL_XFRC = _CTRL | int(mujoco.mjtState.mjSTATE_XFRC_APPLIED)


@dataclasses.dataclass(frozen=True)
class _Setup:
    model: mujoco.MjModel
    index: ModelIndex
    state0: np.ndarray        # (nstate,) settled stand, FULLPHYSICS layout
    warmstart0: np.ndarray    # (nv,)
    sensordata0: np.ndarray   # (nsensordata,)
    qpos_slice: slice
    qvel_slice: slice


@functools.lru_cache(maxsize=8)
def _setup(robot: Robot) -> _Setup:
    model, data = robot.host_model, robot.settled
    # FULLPHYSICS layout: time, qpos, qvel, act, history, plugin (state bits in ascending order).
    nt = mujoco.mj_stateSize(model, int(mujoco.mjtState.mjSTATE_TIME))
    nq = mujoco.mj_stateSize(model, int(mujoco.mjtState.mjSTATE_QPOS))
    nv = mujoco.mj_stateSize(model, int(mujoco.mjtState.mjSTATE_QVEL))
    if model.opt.integrator != mujoco.mjtIntegrator.mjINT_EULER:
        raise ValueError("tkujax.sim.rollout_mujoco recovers the warm start assuming the Euler "
                         "integrator")
    if not model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_EULERDAMP:
        raise ValueError("tkujax.sim.rollout_mujoco recovers the warm start assuming eulerdamp "
                         "is disabled")
    state0 = np.empty(mujoco.mj_stateSize(model, _FULL))
    mujoco.mj_getState(model, data, state0, _FULL)
    state0.setflags(write=False)
    return _Setup(model=model, index=robot.index, state0=state0,
                  warmstart0=np.array(data.qacc_warmstart), sensordata0=np.array(data.sensordata),
                  qpos_slice=slice(nt, nt + nq), qvel_slice=slice(nt + nq, nt + nq + nv))


@functools.lru_cache(maxsize=8)
def _slope_setup(robot: Robot, floor: Floor) -> _Setup:
    """_setup's, on that floor (tkujax.sim.slope: its gravity)."""
    setup = _setup(robot)
    return dataclasses.replace(setup, model=tilt_host_model(setup.model, floor))


@functools.lru_cache(maxsize=4)
def _rollout_pool(nthread: int) -> mujoco.rollout.Rollout:
    """Persistent thread pool (nthread 0: run on the calling thread)."""
    return mujoco.rollout.Rollout(nthread=nthread)


@functools.partial(jax.jit, static_argnames=("quantise",))
def _control_tick(states, gyro, accel, params, enabled, quantise: bool, overrides=None,
                  schedule=None, walk=None):
    """controller_step over the batch (states, gyro, accel, enabled, overrides, walk batched;
    params and schedule shared)."""
    step = jax.vmap(control_tick, in_axes=(0, 0, 0, None, 0, None, 0, None, 0))
    return step(states, gyro, accel, params, enabled, quantise, overrides, schedule, walk)


def _init_states(params: ControllerParams, config: RolloutConfig, n: int,
                 walk: WalkCommand | None, overrides, schedule):
    """(the batch's initial controller states, walk broadcast to the batch): standing (float or
    fixed point), or walking (one state per robot's command; refused with a fixed-point
    controller, overrides or a schedule)."""
    if walk is not None:
        check_walk(config, overrides, schedule)
        walk = batch_walk(walk, n)
        return jax.vmap(lambda c: walking_init(params, c, jnp.float32))(walk), walk
    init = (controller_init(params, jnp.float32) if config.fixed is None else
            controller_init_fx(params, config.fixed, jnp.float32))
    return jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (n,) + x.shape), init), None


@functools.partial(jax.jit, static_argnames=("quantise", "fixed"))
def _control_tick_fx(states, gyro, accel, params, enabled, quantise: bool,
                     fixed: FixedPointConfig):
    """controller_step_fx over the batch: one compiled tick per FixedPointConfig."""
    step = jax.vmap(control_tick_fx, in_axes=(0, 0, 0, None, 0, None, None))
    return step(states, gyro, accel, params, enabled, quantise, fixed)


@jax.jit
def _batched_outcomes(series: Series, onset_s: jax.Array) -> Outcomes:
    return jax.vmap(_outcomes)(series, onset_s)


def _force(pushes: dict, t: np.ndarray) -> np.ndarray:
    """Numpy twin of push.force_at: (n, k, 3) world force at times t (n, k). Push sequences
    (impulse_ns, azimuth_rad, onset_s of shape (n, pulses)) sum their pulses' forces."""
    if np.ndim(pushes["impulse_ns"]) == 2:
        return sum(_force(dict(pushes, **{k: pushes[k][:, i] for k in PULSE_FIELDS}), t)
                   for i in range(pushes["impulse_ns"].shape[1]))
    onset, dur = pushes["onset_s"][:, None], pushes["duration_s"][:, None]
    phase = (t - onset) / dur
    active = (phase >= 0.0) & (phase < 1.0)
    mag = pushes["impulse_ns"][:, None] * (np.pi / (2.0 * dur)) * np.sin(np.pi * phase)
    mag = np.where(active, mag, 0.0)
    az = pushes["azimuth_rad"][:, None]
    return mag[..., None] * np.stack([np.cos(az), np.sin(az), np.zeros_like(az)], -1)


class _Kinematics:
    """Forward kinematics of a batch of FULLPHYSICS states on one scratch MjData."""

    def __init__(self, setup: _Setup):
        self.m, self.idx = setup.model, setup.index
        self.d = mujoco.MjData(self.m)

    def chest(self, states: np.ndarray):
        """(xpos (n,3), xmat (n,3,3), xipos (n,3)) of the chest body."""
        m, d, b = self.m, self.d, self.idx.chest_body
        n = states.shape[0]
        xpos, xmat, xipos = np.empty((n, 3)), np.empty((n, 3, 3)), np.empty((n, 3))
        for i in range(n):
            mujoco.mj_setState(m, d, states[i], _FULL)
            mujoco.mj_kinematics(m, d)
            xpos[i], xmat[i], xipos[i] = d.xpos[b], d.xmat[b].reshape(3, 3), d.xipos[b]
        return xpos, xmat, xipos

    def series(self, states: np.ndarray) -> dict:
        """Kinematic quantities recorded per period (see module doc for which state)."""
        m, d, idx = self.m, self.d, self.idx
        n = states.shape[0]
        right, left = idx.ankle_sites
        out = dict(com=np.empty((n, 3)), r_ankle=np.empty((n, 3)), l_ankle=np.empty((n, 3)),
                   fsr_xy=np.empty((n, len(idx.fsr_sites), 2)),
                   sphere_z=np.empty((n, len(idx.sphere_geoms))),
                   box_z=np.empty((n, len(idx.box_geoms))),
                   box_zrow=np.empty((n, len(idx.box_geoms), 3)),
                   mesh_z=np.empty((n, len(idx.mesh_geoms))),
                   capsule_zz=np.empty((n, 2, len(idx.capsule_geoms))),
                   cylinder_zz=np.empty((n, 2, len(idx.cylinder_geoms))))
        for i in range(n):
            mujoco.mj_setState(m, d, states[i], _FULL)
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            out["com"][i] = d.subtree_com[1]
            out["r_ankle"][i], out["l_ankle"][i] = d.site_xpos[right], d.site_xpos[left]
            out["fsr_xy"][i] = d.site_xpos[idx.fsr_sites, :2]
            out["sphere_z"][i] = d.geom_xpos[idx.sphere_geoms, 2]
            if idx.mesh_geoms:
                out["mesh_z"][i] = [np.min(d.geom_xpos[g, 2] + pts @ d.geom_xmat[g][6:9])
                                    for g, pts in zip(idx.mesh_geoms, idx.mesh_points)]
            # Capsules' and cylinders' centre heights and axes' world z (xmat[2, 2]).
            out["capsule_zz"][i] = d.geom_xpos[idx.capsule_geoms, 2], \
                d.geom_xmat[idx.capsule_geoms, 8]
            out["cylinder_zz"][i] = d.geom_xpos[idx.cylinder_geoms, 2], \
                d.geom_xmat[idx.cylinder_geoms, 8]
            if idx.box_geoms.size:
                out["box_z"][i] = d.geom_xpos[idx.box_geoms, 2]
                out["box_zrow"][i] = d.geom_xmat[idx.box_geoms].reshape(-1, 3, 3)[:, 2, :]
        return out


def _wrench(idx: ModelIndex, pose, height: np.ndarray, force: np.ndarray) -> np.ndarray:
    """Numpy twin of rollout_mjx._push_wrench: (n, k, 6) [force, moment about the chest CoM].

    pose: chest (xpos, xmat, xipos) per robot; force (n, k, 3) for k steps sharing that pose.
    """
    xpos, xmat, xipos = pose
    local = np.zeros((height.shape[0], 3))
    local[:, 2] = (height - idx.chest_stand_z) / idx.chest_stand_cos
    point = xpos + np.einsum("nij,nj->ni", xmat, local)
    arm = (point - xipos)[:, None, :]
    return np.concatenate([force, np.cross(np.broadcast_to(arm, force.shape), force)], -1)


class _ImuFilter:
    """The IMU reading the controller gets: the last physics step's gyro and accelerometer,
    or, with the model's low-pass (ModelIndex.accel_alpha / gyro_alpha > 0), the first-order
    filter y += alpha (x - y) advanced over every physics step, as in the MJX loop."""

    def __init__(self, idx: ModelIndex, sensordata0: np.ndarray):
        self.g, self.a = (slice(idx.gyro_adr, idx.gyro_adr + 3),
                          slice(idx.accel_adr, idx.accel_adr + 3))
        self.filtered, self.alpha = idx.imu_filtered, idx.imu_gains
        self.gyro, self.accel = sensordata0[:, self.g].copy(), sensordata0[:, self.a].copy()

    def advance(self, sens_steps: np.ndarray) -> None:
        """sens_steps (n, substeps, nsensordata): the sensordata after each physics step."""
        (ag, aa), g, a = self.alpha, self.gyro, self.accel
        if not self.filtered:
            self.gyro, self.accel = sens_steps[:, -1, self.g], sens_steps[:, -1, self.a]
            return
        for j in range(sens_steps.shape[1]):
            g = g + ag * (sens_steps[:, j, self.g] - g)
            a = a + aa * (sens_steps[:, j, self.a] - a)
        self.gyro, self.accel = g, a


class _Physics:
    """Advances a batch of robots one control period with `mujoco.rollout`, chaining the warm
    start (module doc); holds the static pieces (model, thread pool, scratch data)."""

    def __init__(self, setup: _Setup, n: int, n_threads: int | None):
        if n_threads is None:
            n_threads = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
                os.cpu_count() or 1)
        nthread = int(n_threads) if (n_threads > 1 and n > 1) else 0
        self.setup, self.m, self.idx = setup, setup.model, setup.index
        self.pool = _rollout_pool(nthread)
        self.datas = [mujoco.MjData(self.m) for _ in range(max(nthread, 1))]
        self.kin = _Kinematics(setup)
        self.dt = float(self.m.opt.timestep)
        self.ctrl_spec_size = mujoco.mj_stateSize(self.m, _CTRL_XFRC)
        nu, chest = self.m.nu, self.idx.chest_body
        self.xfrc_cols = slice(nu + 6 * chest, nu + 6 * chest + 6)

    def _run(self, s0, w0, control, spec, nstep):
        states, sens = self.pool.rollout(self.m, self.datas, s0, control, control_spec=spec,
                                         initial_warmstart=w0, nstep=nstep)
        qv = self.setup.qvel_slice
        prev_qvel = s0[:, qv] if nstep == 1 else states[:, -2, qv]
        return states, sens, (states[:, -1, qv] - prev_qvel) / self.dt

    def period(self, state, pose_state, warm, ctrl_steps, held, force, height, push_wrench):
        """One period of `substeps` physics steps. ctrl_steps (n, substeps, nu) per-step
        controls; held: they are all equal (one row serves); force (n, substeps, 3) the push;
        height (n,). Returns (state, pose_state, sensordata per step (n, substeps,
        nsensordata), warm) after the period, pose_state the state whose kinematics MJX's
        d.xpos holds (before the last step)."""
        substeps, nu = ctrl_steps.shape[1], self.m.nu
        if not np.any(force != 0.0):
            control = np.ascontiguousarray(ctrl_steps[:, :1]) if held else ctrl_steps
            states, sens, warm = self._run(state, warm, control, _CTRL, substeps)
            pose_state = states[:, -2] if substeps > 1 else state
            return states[:, -1], pose_state, sens, warm
        if push_wrench == "period_start":
            control = np.zeros((state.shape[0], substeps, self.ctrl_spec_size))
            control[:, :, :nu] = ctrl_steps
            control[:, :, self.xfrc_cols] = _wrench(self.idx, self.kin.chest(pose_state), height,
                                                    force)
            states, sens, warm = self._run(state, warm, control, _CTRL_XFRC, substeps)
            pose_state = states[:, -2] if substeps > 1 else state
            return states[:, -1], pose_state, sens, warm
        # exact: one step per call, the wrench from the pose MJX would use
        control = np.zeros((state.shape[0], 1, self.ctrl_spec_size))
        per_step = []
        for j in range(substeps):
            control[:, 0, :nu] = ctrl_steps[:, j]
            control[:, :, self.xfrc_cols] = _wrench(self.idx, self.kin.chest(pose_state), height,
                                                    force[:, j:j + 1])
            states, sens, warm = self._run(state, warm, control, _CTRL_XFRC, 1)
            pose_state = state
            state = states[:, -1]
            per_step.append(sens[:, -1])
        return state, pose_state, np.stack(per_step, axis=1), warm

    def record(self, state, pose_state, sensordata, out, ctrl_state, record_qpos: bool) -> Series:
        """The Series row of the period just run (numpy; the controller's fields as given)."""
        idx = self.idx
        k = self.kin.series(pose_state)
        qpos = state[:, self.setup.qpos_slice]
        pitch, roll = physics.pitch_roll_from_quat(qpos[:, 3:7])
        zmp_xy, total = recording.zmp(np, sensordata[:, idx.fsr_adr], k["fsr_xy"])
        boxes = (dict(box_z=k["box_z"], box_zrow=k["box_zrow"],
                      box_half_sizes=idx.box_half_sizes) if idx.box_geoms.size else {})
        point_z = np.concatenate([k["mesh_z"], recording.axial_lows(
            np, *k["capsule_zz"].transpose(1, 0, 2), idx.capsule_sizes, True),
            recording.axial_lows(np, *k["cylinder_zz"].transpose(1, 0, 2), idx.cylinder_sizes,
                                 False)], -1)
        lowest = recording.lowest_point(np, k["sphere_z"], idx.sphere_radii, **boxes,
                                        point_z=point_z if point_z.shape[-1] else None)
        return recording.tick_series(
            t=state[:, 0], pitch=pitch, roll=roll, zmp_xy=zmp_xy, fsr_total=total, com=k["com"],
            r_ankle=k["r_ankle"], l_ankle=k["l_ankle"], pelvis_z=qpos[:, 2],
            lowest_body_z=lowest, out=out, ctrl_state=ctrl_state,
            qpos=qpos if record_qpos else None)


def _mapped(idx: ModelIndex, legs) -> np.ndarray:
    """(n, n_act) actuator targets of the controller's leg targets (closed_loop.map_legs)."""
    legs = np.asarray(legs, np.float64)
    if idx.leg_chain is not None:
        return chain_targets_host(idx.leg_chain, legs)
    if idx.leg_matrix is not None:
        return legs @ idx.leg_matrix.T + idx.leg_offsets
    if idx.leg_signs is None:
        return legs
    return legs * idx.leg_signs + idx.leg_offsets


def _stack_ticks(rows: list[Series]) -> Series:
    """(n_ticks of (n, ...)) -> Series of (n, n_ticks, ...); physical fields in MJX's float32,
    the controller's fields in the dtype the controller gives them."""
    series = {}
    for key in SERIES_FIELDS:
        if getattr(rows[0], key) is None:
            continue
        arr = np.stack([np.asarray(getattr(r, key)) for r in rows], 1)
        if arr.dtype == np.float64:
            arr = arr.astype(np.float32)
        series[key] = arr
    return Series(**series)


def _period_push(p: dict, kicks, tick: int, state: np.ndarray, qvel: slice, dt: float,
                 substeps: int) -> np.ndarray:
    """The push's (n, substeps, 3) force over control period `tick`; with velocity kicks
    (`tkujax.sim.kicks_host.kick_ticks`) no force, and the period's kicks added to the
    states' base velocity."""
    force = _force(p, state[:, :1] + dt * np.arange(substeps)[None, :])
    if kicks is None:
        return force
    state[:, qvel.start:qvel.start + 2] += kicks[tick]
    return np.zeros_like(force)


def _check_overrides(overrides, pushes: Push, n: int, fixed):
    """The overrides broadcast to the batch, their onset_s taken from the pushes (float32)."""
    if overrides is None:
        return None
    if fixed is not None:
        raise ValueError("commanded steps (overrides) have no fixed-point controller twin; "
                         "use RolloutConfig(fixed=None)")
    return jax.tree_util.tree_map(lambda v: jnp.broadcast_to(jnp.asarray(v, jnp.float32), (n,)),
                                  dataclasses.replace(overrides, onset_s=pushes.onset_s))


def simulate_mujoco(pushes: Push, enabled, params: ControllerParams, seed: int = 0,
                    gyro_noise_std: float = 0.0, accel_noise_std: float = 0.0,
                    model_params: ModelParams | None = None,
                    config: RolloutConfig = RolloutConfig(), n_threads: int | None = None,
                    push_wrench: str = "exact", overrides: StepOverride | None = None,
                    schedule=None, robot: Robot | None = None,
                    walk: WalkCommand | None = None) -> tuple[Series, Outcomes]:
    """Run a batch of pushes with MuJoCo C physics; returns numpy (series, outcomes).

    Same arguments, keys and shapes as `tkujax.sim.rollout_mjx.simulate`, plus n_threads (physics
    threads; default: the CPUs this process may use) and push_wrench ("exact" or
    "period_start", see the module doc) and overrides (stacked StepOverride, leading axis n;
    their onset_s is taken from the pushes) and schedule (a scheduled policy's
    `tkujax.control.policy.Schedule`, shared by the batch; not with a fixed-point controller)
    and walk (a `tkujax.control.gait.WalkCommand`, one or stacked; None: standing).
    """
    if push_wrench not in PUSH_WRENCH_MODES:
        raise ValueError(f"push_wrench must be one of {PUSH_WRENCH_MODES}, got {push_wrench!r}")
    setup = _slope_setup(as_robot(robot, model_params), config.floor)
    idx = setup.index
    n = int(np.shape(pushes.impulse_ns)[0])
    phys = _Physics(setup, n, n_threads)
    substeps = int(round(config.control_period_s / idx.timestep_s))
    n_ticks = int(round(config.duration_s / config.control_period_s))
    params = dataclasses.replace(params, control_period=config.control_period_s)
    enabled_j = jnp.broadcast_to(jnp.asarray(enabled, jnp.float32), (n,))
    p = {k: np.asarray(getattr(pushes, k), np.float64)
         for k in ("impulse_ns", "azimuth_rad", "height_m", "duration_s", "onset_s")}
    kicks = kick_ticks(pushes, n, n_ticks, config.control_period_s, idx.timestep_s)
    rng = np.random.default_rng(seed)
    fixed = config.fixed
    if fixed is not None:   # options the fixed-point twin lacks: refused, not ignored
        check_supported(params)
    overrides = _check_overrides(overrides, pushes, n, fixed)
    if fixed is not None and schedule is not None:
        raise ValueError("scheduled parameters have no fixed-point controller twin; "
                         "use RolloutConfig(fixed=None)")
    switch = 0 if fixed is None else servo_switch_substep(fixed, substeps)
    ctrl_state, walk = _init_states(params, config, n, walk, overrides, schedule)
    state = np.tile(setup.state0, (n, 1))                 # current state
    pose_state = state.copy()     # whose kinematics MJX's d.xpos holds (before the last step)
    warm = np.tile(setup.warmstart0, (n, 1))
    sensordata = np.tile(setup.sensordata0, (n, 1))
    imu = _ImuFilter(idx, sensordata)
    stand_ctrl = np.asarray(idx.stand_ctrl, np.float64)
    rows = []
    for _ in range(n_ticks):
        gyro, accel = imu.gyro, imu.accel
        gyro = gyro + gyro_noise_std * rng.standard_normal((n, 3))
        accel = accel + accel_noise_std * rng.standard_normal((n, 3))
        gyro_j, accel_j = jnp.asarray(gyro, jnp.float32), jnp.asarray(accel, jnp.float32)
        if fixed is None:
            ctrl_state, legs, out = _control_tick(ctrl_state, gyro_j, accel_j, params,
                                                  enabled_j, config.quantise_targets, overrides,
                                                  schedule, walk)
        else:
            ctrl_state, legs, prev, out = _control_tick_fx(ctrl_state, gyro_j, accel_j, params,
                                                           enabled_j, config.quantise_targets,
                                                           fixed)
        ctrl = np.tile(stand_ctrl, (n, 1))
        ctrl[:, idx.leg_actuators] = _mapped(idx, legs)
        # Per physics substep (n, substeps, nu): the previous command until the switch substep
        # (fractional latency of the fixed-point controller), then the new one.
        ctrl_steps = np.repeat(ctrl[:, None, :], substeps, 1)
        if switch > 0:
            ctrl_steps[:, :switch, idx.leg_actuators] = _mapped(idx, prev)[:, None, :]
        force = _period_push(p, kicks, len(rows), state, setup.qvel_slice, phys.dt, substeps)
        state, pose_state, sens_steps, warm = phys.period(
            state, pose_state, warm, ctrl_steps, switch == 0, force, p["height_m"], push_wrench)
        sensordata = sens_steps[:, -1]
        imu.advance(sens_steps)
        rows.append(phys.record(state, pose_state, sensordata, out, ctrl_state,
                                config.record_qpos))

    series = _stack_ticks(rows)
    out = _batched_outcomes(jax.tree_util.tree_map(jnp.asarray, series),
                            jnp.asarray(first_onset(pushes), jnp.float32))
    return series, jax.tree_util.tree_map(np.asarray, out)
