"""The one init (tkujax.sim.setup), the one model randomisation (tkujax.sim.randomize) and the
per-tick recording both rollouts share (tkujax.sim.recording). No closed loop is compiled."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.sim import physics, recording
from tkujax.sim.randomize import randomize_model
from tkujax.sim.setup import SETTLE_S, SimSetup, init, model_index


@pytest.fixture(scope="module")
def setup() -> SimSetup:
    return init()


def test_init_is_cached_however_spelled(setup):
    assert init(None) is setup and init(None, SETTLE_S) is setup and init(settle_s=1) is setup
    assert init(settle_s=0.0) is not setup


def test_init_builds_the_settled_stand(setup):
    host, device, index, state = setup
    # Built from the default robot: the same sizes and indices as a fresh build (identity
    # would depend on what other tests left in the lru caches).
    assert (host.nq, host.nu) == (physics.host_model(None).nq, physics.host_model(None).nu)
    assert device.nq == host.nq and device.nu == host.nu
    fresh = model_index(None)
    for field in dataclasses.fields(fresh):
        np.testing.assert_array_equal(np.asarray(getattr(index, field.name), dtype=object),
                                      np.asarray(getattr(fresh, field.name), dtype=object),
                                      err_msg=field.name)
    settled = physics.settled_stand_data(host, SETTLE_S)
    np.testing.assert_allclose(np.asarray(state.qpos), settled.qpos, atol=1e-6)
    assert float(state.time) == 0.0
    keyframe = init(settle_s=0.0).stand_state
    np.testing.assert_allclose(np.asarray(keyframe.qpos), host.key("stand").qpos, atol=1e-7)


def test_randomize_scales_what_is_given_and_nothing_else(setup):
    model, chest = setup.device_model, setup.index.chest_body
    same = randomize_model(model, chest)                      # nothing given: unchanged
    assert all(getattr(same, f) is getattr(model, f) for f in
               ("body_mass", "body_ipos", "actuator_gainprm", "dof_damping", "pair_friction"))
    m = randomize_model(model, chest, mass_scale=1.1, torso_com_dx_m=0.01, friction=0.5,
                        kp_scale=0.9)
    np.testing.assert_allclose(m.body_mass, 1.1 * np.asarray(model.body_mass), rtol=1e-6)
    np.testing.assert_allclose(m.body_ipos[chest, 0], model.body_ipos[chest, 0] + 0.01)
    np.testing.assert_array_equal(np.delete(np.asarray(m.body_ipos), chest, 0),
                                  np.delete(np.asarray(model.body_ipos), chest, 0))
    np.testing.assert_allclose(m.pair_friction[:, :2], 0.5)
    np.testing.assert_allclose(m.actuator_gainprm[:, 0],
                               0.9 * np.asarray(model.actuator_gainprm[:, 0]), rtol=1e-6)
    assert m.dof_damping is model.dof_damping                 # not given: the same array
    kept = randomize_model(model, chest, friction=-1.0)       # <= 0: the model's friction
    np.testing.assert_array_equal(kept.pair_friction, model.pair_friction)


def test_randomize_masks_and_gradient(setup):
    model, index = setup.device_model, setup.index
    legs = np.isin(np.arange(setup.host_model.nu), index.leg_actuators)

    def total_gain(kp):
        m = randomize_model(model, index.chest_body, kp_scale=kp, actuator_mask=legs)
        return jnp.sum(m.actuator_gainprm[:, 0])

    m = randomize_model(model, index.chest_body, kp_scale=2.0, actuator_mask=legs)
    gain = np.asarray(model.actuator_gainprm[:, 0])
    np.testing.assert_allclose(m.actuator_gainprm[:, 0], np.where(legs, 2.0 * gain, gain))
    assert float(jax.grad(total_gain)(1.0)) == pytest.approx(gain[legs].sum(), rel=1e-5)


@pytest.mark.parametrize("xp", [np, jnp])
def test_zmp_is_the_centre_of_pressure_or_the_feet_centre(xp):
    sites = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 2.0], [0.0, 2.0]])
    zmp, total = recording.zmp(xp, xp.asarray([3.0, 1.0, 0.0, 0.0]), xp.asarray(sites))
    np.testing.assert_allclose(zmp, [0.25, 0.0])
    assert float(total) == 4.0
    zmp, total = recording.zmp(xp, xp.zeros(4), xp.asarray(sites))     # in the air
    np.testing.assert_allclose(zmp, [0.5, 1.0])
    batch, _ = recording.zmp(xp, xp.asarray([[0.0, 0.0, 2.0, 2.0], [0.0] * 4]),
                             xp.asarray(np.stack([sites, sites])))
    np.testing.assert_allclose(batch, [[0.5, 2.0], [0.5, 1.0]])


@pytest.mark.parametrize("xp", [np, jnp])
def test_lowest_point_of_spheres_and_tilted_boxes(xp):
    spheres = recording.lowest_point(xp, xp.asarray([0.30, 0.05]), xp.asarray([0.02, 0.04]))
    assert float(spheres) == pytest.approx(0.01)
    # A box of half height 0.1 turned on its side (its x axis vertical: half extent 0.2).
    low = recording.lowest_point(xp, xp.asarray([0.30]), xp.asarray([0.02]),
                                 box_z=xp.asarray([0.25]), box_zrow=xp.asarray([[1.0, 0, 0]]),
                                 box_half_sizes=xp.asarray([[0.2, 0.1, 0.1]]))
    assert float(low) == pytest.approx(0.05)
