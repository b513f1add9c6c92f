"""MJX plumbing shared by every simulation: the device model, initial states, stepping.

All functions are pure: models and states go in and out; nothing is stored on objects.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from tkujax.sim.mjx_import import mjx

from tkujax.model import ModelParams, load_model


@functools.lru_cache(maxsize=8)
def host_model(params: ModelParams | None = None) -> mujoco.MjModel:
    """The compiled MuJoCo model (cached per parameter set)."""
    return load_model(params)


@functools.lru_cache(maxsize=8)
def device_model(params: ModelParams | None = None) -> mjx.Model:
    """The MJX model on this process's first local device (cached per parameter set).

    Local, not jax.devices()[0]: in a multi-process run that is another process's device."""
    return mjx.put_model(host_model(params), device=jax.local_devices()[0])


def stand_data(model: mujoco.MjModel) -> mujoco.MjData:
    """MuJoCo C state at the `stand` keyframe, forward-computed."""
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("stand").id)
    mujoco.mj_forward(model, data)
    return data


def settled_stand_data(model: mujoco.MjModel, settle_s: float = 1.0) -> mujoco.MjData:
    """The `stand` keyframe after `settle_s` of holding its targets (MuJoCo C), clock reset to 0.

    The keyframe is placed kinematically; the first steps compress the sole contacts and the
    IMU reads that transient. Starting rollouts settled keeps it out of the controller.
    """
    data = stand_data(model)
    data.ctrl[:] = model.key("stand").ctrl
    for _ in range(int(round(settle_s / model.opt.timestep))):
        mujoco.mj_step(model, data)
    data.time = 0.0
    mujoco.mj_forward(model, data)
    return data


def stand_state(model: mujoco.MjModel, settle_s: float = 0.0) -> mjx.Data:
    """MJX state at the `stand` keyframe (unbatched), optionally settled first."""
    data = settled_stand_data(model, settle_s) if settle_s > 0 else stand_data(model)
    return mjx.put_data(model, data, device=jax.local_devices()[0])


def batch_state(state: mjx.Data, batch: int) -> mjx.Data:
    """Repeat an unbatched state `batch` times along a new leading axis."""
    return jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), state)


def pitch_roll_from_quat(quat: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Inclination of a body from its quaternion (w, x, y, z), radians.

    pitch > 0: the body's z axis leans toward +x (forward); roll > 0: it leans toward -y
    (a rotation about +x). Computed from the body z axis in world coordinates.
    """
    xp = np if isinstance(quat, np.ndarray) else jnp   # numpy in, numpy out (the C path)
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    zx = 2 * (x * z + w * y)        # world x of the body's z axis
    zy = 2 * (y * z - w * x)        # world y
    zz = 1 - 2 * (x * x + y * y)    # world z
    return xp.arctan2(zx, zz), xp.arctan2(-zy, zz)


def without_sensors(model: mjx.Model) -> mjx.Model:
    """The model with MuJoCo's sensor stage off (mjDSBL_SENSOR): `mjx.forward` then computes
    no sensor, and `d.sensordata` keeps its old values."""
    off = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
    return model.replace(opt=model.opt.replace(disableflags=model.opt.disableflags | off))


def imu_reading(model: mjx.Model, d: mjx.Data, index) -> tuple[jax.Array, jax.Array]:
    """The gyro (rad/s) and accelerometer (m/s^2) readings of `index`'s IMU sites (a
    `tkujax.sim.setup.ModelIndex`), from a state after `mjx.forward` and before the integrator.

    The formulas are MJX's own (mujoco/mjx/_src/sensor.py: sensor_vel's GYRO, sensor_acc's
    ACCELEROMETER, with its body accelerations from `mjx.rne_postconstraint`), so the values are
    the sensordata that `mjx.step` writes, up to float rounding (a sum over fewer terms).
    Computed alone, they skip what the full sensor stage also computes every step: the eight
    sole touch sensors (contact forces, ray distances), which the closed loop needs once per
    control tick (`touch_sensordata`)."""
    rot = d.site_xmat[index.gyro_site]
    gyro = rot.T @ d.cvel[index.gyro_body, :3]
    b = index.accel_body
    cacc = _body_acceleration(model, d, index)
    rot, cvel = d.site_xmat[index.accel_site], d.cvel[b]
    dif = d.site_xpos[index.accel_site] - d.subtree_com[index.accel_root]
    ang = rot.T @ cvel[:3]
    lin = rot.T @ (cvel[3:] - jnp.cross(dif, cvel[:3]))
    acc = rot.T @ (cacc[3:] - jnp.cross(dif, cacc[:3]))
    return gyro, acc + jnp.cross(ang, lin)


def _body_acceleration(model: mjx.Model, d: mjx.Data, index) -> jax.Array:
    """cacc (6,) of the accelerometer's body: for a body whose parent is the world (TKU-X's
    IMU is on its floating base) MJX's forward pass of `rne_postconstraint` for that body alone
    (mujoco/mjx/_src/smooth.py, `_forward`, the same operations); the whole pass otherwise."""
    if index.accel_parent != 0:
        return mjx.rne_postconstraint(model, d)._impl.cacc[index.accel_body]
    if model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_GRAVITY:
        cacc0 = jnp.zeros(6, d.qvel.dtype)
    else:
        cacc0 = jnp.concatenate((jnp.zeros(3, d.qvel.dtype), -model.opt.gravity))
    # Only the body's own dofs: the other terms of MJX's masked sum over every dof are exact
    # zeros (products of zero; x + 0 = x).
    dofs = slice(index.accel_dofs[0], index.accel_dofs[0] + index.accel_dofs[1])
    return cacc0 + d.cdof_dot[dofs].T @ d.qvel[dofs] + d.cdof[dofs].T @ d.qacc[dofs]


def touch_sensordata(model: mjx.Model, d: mjx.Data) -> jax.Array:
    """The sensordata of a state after a step with its touch sensors computed again (MJX's
    acceleration-stage sensor code, run once on a view of the model whose other sensors are
    left out of that stage). Touch sensors read the step's contact forces and site poses, which
    the integrator leaves as they were, so their entries equal those the step itself writes
    (an accelerometer's would not: it reads qvel, which the integrator changed; read the IMU
    from `imu_reading`). The other entries are not updated."""
    touch = model.sensor_type == mujoco.mjtSensor.mjSENS_TOUCH
    view = model.replace(sensor_needstage=np.where(touch, model.sensor_needstage, 0))
    return mjx.sensor_acc(view, d).sensordata


def step_holding(model: mjx.Model, state: mjx.Data, ctrl: jax.Array, n_steps: int):
    """Step one robot `n_steps` physics steps holding actuator targets `ctrl` (nu,).

    Returns (final state, trace) with trace = dict of per-step arrays:
      base_pos (n, 3) m, pitch (n,) rad, roll (n,) rad, sensordata (n, nsensordata).
    vmap over `state` (and `ctrl`) for a batch of robots.
    """
    state = state.replace(ctrl=ctrl)

    def body(d, _):
        d = mjx.step(model, d)
        pitch, roll = pitch_roll_from_quat(d.qpos[3:7])
        return d, dict(base_pos=d.qpos[:3], pitch=pitch, roll=roll, sensordata=d.sensordata)

    return jax.lax.scan(body, state, None, length=n_steps)


def step_holding_c(model: mujoco.MjModel, data: mujoco.MjData, ctrl: np.ndarray, n_steps: int):
    """MuJoCo C twin of `step_holding` (one robot, float64), for cross-checks and the CPU path."""
    data.ctrl[:] = ctrl
    base_pos, pitch, roll, sensordata = [], [], [], []
    for _ in range(n_steps):
        mujoco.mj_step(model, data)
        p, r = pitch_roll_from_quat(np.asarray(data.qpos[3:7]))
        base_pos.append(data.qpos[:3].copy())
        pitch.append(float(p))
        roll.append(float(r))
        sensordata.append(data.sensordata.copy())
    return data, dict(base_pos=np.array(base_pos), pitch=np.array(pitch), roll=np.array(roll),
                      sensordata=np.array(sensordata))
