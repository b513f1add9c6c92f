"""The closed loop's physics step without MuJoCo's sensor stage (tkujax.sim.physics:
without_sensors, imu_reading, touch_sensordata).

References: MuJoCo C's own sensors (mj_forward, mj_step) for TKU-X moving in every dof, and
for a small robot whose IMU sits on a child body (imu_reading's other branch); MJX's full step
for the sole touch sensors.
"""

import types

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.sim import physics
from tkujax.sim import rollout_mjx as sim
from tkujax.sim.mjx_import import mjx
from tkujax.sim.push import Push
from tkujax.sim.setup import imu_indices, init


def _moving(host, qpos0, seed=0):
    """A MuJoCo C state near `qpos0`, moving in every dof (slowly enough that the soles stay
    on the floor), with targets off the stand."""
    rng = np.random.default_rng(seed)
    data = mujoco.MjData(host)
    data.qpos[:] = qpos0
    data.qvel[:] = rng.normal(0.0, 0.2, host.nv)
    data.ctrl[:] = host.key("stand").ctrl + rng.normal(0.0, 0.1, host.nu)
    return data


def _sensor(host, data, name):
    s = host.sensor(name)
    return np.array(data.sensordata[s.adr[0]:s.adr[0] + s.dim[0]])


@pytest.fixture(scope="module")
def tkux():
    host, model, index, stand = init()
    data = _moving(host, np.asarray(stand.qpos))
    state = mjx.put_data(host, data)
    lean = physics.without_sensors(model)

    @jax.jit
    def lean_step(d):
        d = mjx.forward(lean, d)
        gyro, accel = physics.imu_reading(lean, d, index)
        return gyro, accel, mjx.euler(lean, d)

    gyro, accel, after = lean_step(state)
    return types.SimpleNamespace(host=host, model=model, index=index, data=data,
                                 state=state, gyro=gyro, accel=accel, after=after)


def test_imu_reading_is_mujocos_gyro_and_accelerometer(tkux):
    mujoco.mj_forward(tkux.host, tkux.data)          # float64 C, the reference
    gyro, accel = _sensor(tkux.host, tkux.data, "gyro"), _sensor(tkux.host, tkux.data, "accel")
    assert np.abs(gyro).max() > 0.05 and np.abs(accel - [0, 0, 9.81]).max() > 1.0  # it moves
    np.testing.assert_allclose(tkux.gyro, gyro, rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(tkux.accel, accel, rtol=1e-3, atol=2e-3)


def test_the_lean_step_is_mjx_step(tkux):
    """Same next state as mjx.step; its touch sensors, computed once after it, equal the
    step's own (they read contact forces and site poses, which the integrator leaves)."""
    full = jax.jit(mjx.step)(tkux.model, tkux.state)
    np.testing.assert_allclose(tkux.after.qpos, full.qpos, rtol=0, atol=1e-6)
    np.testing.assert_allclose(tkux.after.qvel, full.qvel, rtol=1e-5, atol=1e-5)
    touch = np.asarray(tkux.host.sensor_type == mujoco.mjtSensor.mjSENS_TOUCH)
    assert touch.sum() == 8
    adr = np.concatenate([np.arange(a, a + n) for a, n, t in zip(
        tkux.host.sensor_adr, tkux.host.sensor_dim, touch) if t])
    ours = jax.jit(physics.touch_sensordata)(tkux.model, tkux.after)
    assert int(jnp.sum(full.sensordata[adr] > 1.0)) >= 2     # the soles carry the robot
    np.testing.assert_allclose(ours[adr], full.sensordata[adr], rtol=1e-5, atol=1e-4)
    # The lean step computed no sensor: the state's old sensordata rides along.
    np.testing.assert_array_equal(tkux.after.sensordata, tkux.state.sensordata)


_ARM = """
<mujoco>
  <option timestep="0.002"/>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <body name="base" pos="0 0 0.5">
      <freejoint/>
      <geom type="box" size="0.1 0.1 0.1" mass="2"/>
      <body name="arm" pos="0.1 0 0">
        <joint name="hinge" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.03" mass="0.5"/>
        <site name="imu" pos="0.25 0.02 0.01" euler="10 20 30"/>
      </body>
    </body>
  </worldbody>
  <sensor>
    <gyro name="gyro" site="imu"/>
    <accelerometer name="accel" site="imu"/>
  </sensor>
</mujoco>
"""


def test_imu_on_a_child_body_uses_the_whole_acceleration_pass():
    host = mujoco.MjModel.from_xml_string(_ARM)
    data = mujoco.MjData(host)
    data.qvel[:] = np.random.default_rng(1).normal(0.0, 1.0, host.nv)
    index = types.SimpleNamespace(**imu_indices(host))
    assert index.accel_body == host.body("arm").id and index.accel_parent != 0
    model = physics.without_sensors(mjx.put_model(host))
    d = mjx.forward(model, mjx.put_data(host, data))
    gyro, accel = physics.imu_reading(model, d, index)
    mujoco.mj_forward(host, data)
    np.testing.assert_allclose(gyro, _sensor(host, data, "gyro"), rtol=1e-4, atol=1e-4)
    np.testing.assert_allclose(accel, _sensor(host, data, "accel"), rtol=1e-3, atol=2e-3)


def test_rollout_refuses_a_non_euler_integrator():
    _, model, index, stand = init()
    rk4 = model.replace(opt=model.opt.replace(integrator=mujoco.mjtIntegrator.mjINT_RK4))
    push = Push(jnp.float32(1.0), jnp.float32(0.0), jnp.float32(0.36), jnp.float32(0.02),
                jnp.float32(0.3))
    with pytest.raises(ValueError, match="Euler integrator"):
        sim.rollout(rk4, stand, sim.Episode(push, 1.0, jax.random.PRNGKey(0)),
                    ControllerParams.paper(), sim.RolloutConfig(duration_s=0.06), index)
