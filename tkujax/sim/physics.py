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
