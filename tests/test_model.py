"""The TKU-X model: spec, geometry, validation, standing in MuJoCo C and MJX, rendering."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from tkujax.sim import physics
from tkujax.model import (FSR_SENSORS, JOINT_NAMES, LEG_ACTUATORS, MX28, MX64, ModelParams,
                          leg_geometry, load_model, model_xml, stand_joint_angles)


@pytest.fixture(scope="module")
def model():
    return load_model()


def _straight_pose_extent(model):
    """Lowest and highest points of all geoms with every joint at zero, base upright."""
    data = mujoco.MjData(model)
    data.qpos[:] = 0
    data.qpos[3] = 1.0
    mujoco.mj_forward(model, data)
    lo, hi = np.inf, -np.inf
    for g in range(model.ngeom):
        if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_PLANE:
            continue
        # Conservative vertical half-extent from the geom's bounding radius along world z.
        t, size, xmat = model.geom_type[g], model.geom_size[g], data.geom_xmat[g].reshape(3, 3)
        if t == mujoco.mjtGeom.mjGEOM_SPHERE:
            half = size[0]
        elif t == mujoco.mjtGeom.mjGEOM_BOX:
            half = np.abs(xmat[2]) @ size
        else:  # capsule: half-length along local z plus radius
            half = abs(xmat[2, 2]) * size[1] + size[0]
        lo, hi = min(lo, data.geom_xpos[g][2] - half), max(hi, data.geom_xpos[g][2] + half)
    return lo, hi


def test_mass_height_dof(model):
    assert model.body_subtreemass[model.body("pelvis").id] == pytest.approx(4.5, rel=0.01)
    lo, hi = _straight_pose_extent(model)
    assert hi - lo == pytest.approx(0.5645, rel=0.01)
    assert model.njnt == 24 and model.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    hinges = [model.joint(i).name for i in range(1, model.njnt)]
    assert all(model.jnt_type[i] == mujoco.mjtJoint.mjJNT_HINGE for i in range(1, model.njnt))
    assert sorted(hinges) == sorted(JOINT_NAMES) and len(hinges) == 23
    assert [model.actuator(i).name for i in range(model.nu)] == list(JOINT_NAMES)
    assert len(LEG_ACTUATORS) == 12
    assert LEG_ACTUATORS[0] == "r_hip_yaw" and LEG_ACTUATORS[-1] == "l_ankle_roll"


def test_actuators_model_the_servos(model):
    mp = ModelParams()
    for name in JOINT_NAMES:
        servo = mp.leg_servo if name in LEG_ACTUATORS else mp.arm_servo
        a, j = model.actuator(name), model.joint(name)
        np.testing.assert_allclose(a.forcerange, [-servo.stall_torque_nm, servo.stall_torque_nm],
                                   err_msg=name)
        assert a.gainprm[0] == pytest.approx(servo.kp_nm_per_rad), name
        assert j.damping[0] == pytest.approx(servo.damping_nms_per_rad), name
        if servo.damping_override_nms_per_rad is None:
            # Torque-speed line: the stall torque is used up by back-EMF damping at no-load speed.
            assert a.forcerange[1] / j.damping[0] == pytest.approx(servo.no_load_speed_rad_s), name
        assert j.armature[0] == pytest.approx(servo.armature_kgm2), name
        assert j.frictionloss[0] == pytest.approx(servo.friction_loss_nm), name
        assert j.limited and j.range[0] < 0 <= j.range[1] or name.endswith("knee"), name
    assert MX64.no_load_speed_rad_s == pytest.approx(63 * 2 * math.pi / 60)
    assert MX64.stall_torque_nm == 6.0 and MX28.stall_torque_nm == 2.5


def test_sensors_sites_and_contacts(model):
    names = [model.sensor(i).name for i in range(model.nsensor)]
    assert names == ["gyro", "accel", *FSR_SENSORS]
    for site in ["imu", "waist", "r_ankle", "l_ankle", *FSR_SENSORS]:
        model.site(site)  # raises KeyError when missing
    assert model.site("imu").bodyid == model.site("waist").bodyid == model.body("pelvis").id
    # Explicit pairs only: nothing collides through contype/conaffinity.
    assert not model.geom_contype.any() and not model.geom_conaffinity.any()
    paired = {model.geom(int(g)).name for g in model.pair_geom2}
    assert {"r_fsr_1", "l_fsr_4", "r_knee", "head", "chest", "l_hand"} <= paired
    assert model.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON and model.opt.iterations == 1
    assert model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_EULERDAMP


def test_leg_geometry_matches_compiled_model(model):
    g = leg_geometry()
    assert model.body("r_shin").pos[2] == pytest.approx(-g.thigh)
    assert model.body("r_ankle_link").pos[2] == pytest.approx(-g.calf)
    data = physics.stand_data(model)
    waist = data.site("waist").xpos
    for side, sign in (("r", -1), ("l", 1)):
        hip = data.xpos[model.body(f"{side}_thigh").id]
        ankle = data.site(f"{side}_ankle").xpos
        # Hip joint centre d_y to the side of the waist (in the pelvis frame), ankle d_z below.
        hip_local = data.site("waist").xmat.reshape(3, 3).T @ (hip - waist)
        np.testing.assert_allclose(hip_local, [0, sign * g.d_y, 0], atol=1e-9)
        np.testing.assert_allclose(ankle - hip, [0, 0, -g.d_z], atol=1e-9)
        # Soles flat in the stand keyframe, upper body leaning 7 deg forward.
        np.testing.assert_allclose(data.site(f"{side}_ankle").xmat.reshape(3, 3), np.eye(3),
                                   atol=1e-9)
    pitch, _ = physics.pitch_roll_from_quat(data.qpos[3:7])
    assert math.degrees(pitch) == pytest.approx(7.0)
    assert stand_joint_angles()["r_knee"] > math.radians(30)  # knees bent: IK has margin


@pytest.mark.parametrize("field, value, match", [
    ("thigh_length_m", -0.1, "thigh_length_m"),
    ("leg_mass_kg", 0.0, "leg_mass_kg"),
    ("chest_mass_kg", 1.2, "mass split does not add up"),
    ("stand_hip_to_ankle_m", 0.3, "stand_hip_to_ankle_m"),
    ("leg_mass_fractions", (0.5, 0.5, 0.1, 0.1, 0.1, 0.1), "leg_mass_fractions"),
    ("timestep_s", 0.1, "timestep_s"),
    ("foot_width_m", float("nan"), "foot_width_m"),
])
def test_bad_parameters_rejected(field, value, match):
    with pytest.raises(ValueError, match=match):
        load_model(dataclasses.replace(ModelParams(), **{field: value}))


def test_valid_variant_compiles():
    p = dataclasses.replace(ModelParams(), chest_mass_kg=ModelParams().chest_mass_kg + 0.1,
                            total_mass_kg=4.6)
    assert load_model(p).body_subtreemass[1] == pytest.approx(4.6)
    assert "stand" in model_xml(p)


def test_stands_5s_in_mujoco_c(model):
    data = physics.stand_data(model)
    _, trace = physics.step_holding_c(model, data, model.key("stand").ctrl, 2500)
    pitch = np.degrees(trace["pitch"])
    assert np.abs(pitch - 7.0).max() < 1.0
    assert trace["base_pos"][:, 2].min() > 0.2


@pytest.fixture(scope="module")
def mjx_stand_1s(model):
    """MJX rollout of 1 s (500 steps) holding the stand targets, compiled once."""
    mx = physics.device_model()
    run = jax.jit(lambda d: physics.step_holding(mx, d, jnp.asarray(model.key("stand").ctrl), 500))
    return run


@pytest.mark.slow
def test_stands_5s_in_mjx_and_agrees_with_c(model, mjx_stand_1s):
    state = physics.stand_state(model)
    pitches, heights, traces = [], [], []
    for _ in range(5):
        state, trace = mjx_stand_1s(state)
        traces.append(trace)
        pitches.append(np.degrees(np.asarray(trace["pitch"])))
        heights.append(np.asarray(trace["base_pos"][:, 2]))
    assert np.abs(np.concatenate(pitches) - 7.0).max() < 1.0
    assert np.concatenate(heights).min() > 0.2
    # MJX (float32) against MuJoCo C (float64) over the first second from the same state.
    # Same algorithm, different precision: a stable stance keeps the paths within 1 mm and 0.25 deg.
    _, c = physics.step_holding_c(model, physics.stand_data(model), model.key("stand").ctrl, 500)
    np.testing.assert_allclose(np.asarray(traces[0]["base_pos"]), c["base_pos"], atol=1e-3,
                               err_msg="base position, MJX vs C")
    np.testing.assert_allclose(pitches[0], np.degrees(c["pitch"]), atol=0.25,
                               err_msg="pitch (deg), MJX vs C")
    # The eight sole sensors carry the robot's weight in both engines.
    fsr = np.asarray(traces[0]["sensordata"])[-1, 6:]
    assert fsr.sum() == pytest.approx(4.5 * 9.81, rel=0.02)
    np.testing.assert_allclose(fsr, c["sensordata"][-1, 6:], rtol=0.05, atol=0.1)


@pytest.mark.slow
def test_vmap_batch_of_standing_robots(model, mjx_stand_1s):
    states = physics.batch_state(physics.stand_state(model), 3)
    states = states.replace(qpos=states.qpos.at[:, 7:].add(
        jnp.linspace(-0.01, 0.01, 3)[:, None].astype(states.qpos.dtype)))
    _, trace = jax.vmap(mjx_stand_1s)(states)
    assert trace["pitch"].shape == (3, 500)
    assert np.isfinite(np.asarray(trace["pitch"])).all()


def test_render_stand_png(tmp_path, model):
    from tkujax import render

    ok, why = render.rendering_available()
    if not ok:
        pytest.skip(f"offscreen rendering unavailable: {why}")
    frame = render.render_frames(model, physics.stand_data(model).qpos[None], 64, 48)[0]
    assert frame.shape == (48, 64, 3) and frame.std() > 5  # not a blank image
    assert render.save_image(frame, tmp_path / "stand.png").stat().st_size > 0
