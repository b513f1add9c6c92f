"""Slopes: the floor pitched uphill or downhill as a tilted gravity (tkujax.sim.slope,
RolloutConfig.floor_pitch_deg, [sweep] floor_pitch_deg).

The gravity against its closed form; the independent reference: TKU-X on a level floor under
the slope's gravity moves exactly as TKU-X on a floor plane actually pitched in the MuJoCo model
under the usual gravity, its state rotated onto it (MuJoCo C, 0.6 s with its stand held);
standing uphill leans back and downhill forward; the spec's key refused out of range with its
name, in the records and the hash; a slope sweep's records equal the direct simulation; MJX
against MuJoCo C (slow).
"""

import math

import mujoco
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams, model_xml
from tkujax.sim import physics
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import make_push, stack_pushes
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.sim.slope import slope_gravity, tilt_host_model
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.sweep import load, run_sweep
from tkujax.sweeps.sweep_hash import spec_hash

PARAMS = ControllerParams.paper()


def test_slope_gravity_closed_form():
    g = slope_gravity(10.0, 9.81)
    np.testing.assert_allclose(g, [-9.81 * math.sin(math.radians(10)), 0.0,
                                   -9.81 * math.cos(math.radians(10))])
    assert np.linalg.norm(g) == pytest.approx(9.81)
    np.testing.assert_array_equal(slope_gravity(0.0, 9.81), [-0.0, 0.0, -9.81])


def test_rollout_config_refuses_steep_floors():
    with pytest.raises(ValueError, match=r"floor_pitch_deg must be a number in \[-15, 15\] deg"):
        RolloutConfig(floor_pitch_deg=20.0)


def _ry(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def test_tilted_gravity_is_a_pitched_floor():
    """World B = world A rotated by R = Ry(-theta): A is the level floor under the slope's
    gravity (what tkujax simulates), B the floor plane pitched by theta under (0, 0, -g). Every
    body's position in B is R times its position in A, to 0.1 mm after 0.6 s."""
    theta = math.radians(8.0)
    base = physics.host_model(ModelParams())
    model_a = tilt_host_model(base, 8.0)
    rot = _ry(-theta)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, rot.ravel())
    floor = '<geom name="floor" type="plane"'
    xml = model_xml(ModelParams())
    assert xml.count(floor) == 1
    model_b = mujoco.MjModel.from_xml_string(xml.replace(
        floor, floor + ' quat="' + " ".join(f"{v:.17g}" for v in quat) + '"'))
    data_a = physics.settled_stand_data(base)
    data_b = mujoco.MjData(model_b)
    data_b.qpos[:] = data_a.qpos
    data_b.qvel[:] = data_a.qvel
    data_b.qpos[:3] = rot @ data_a.qpos[:3]
    q = np.zeros(4)
    mujoco.mju_mulQuat(q, quat, data_a.qpos[3:7])
    data_b.qpos[3:7] = q
    data_b.qvel[:3] = rot @ data_a.qvel[:3]
    data_b.ctrl[:] = data_a.ctrl
    data_b.act[:] = data_a.act
    for _ in range(300):
        mujoco.mj_step(model_a, data_a)
        mujoco.mj_step(model_b, data_b)
    np.testing.assert_allclose(data_b.xpos, data_a.xpos @ rot.T, atol=1e-4)
    # and the robot did move on the slope (the comparison is not of two robots at rest)
    assert np.abs(data_a.qpos[:3] - physics.settled_stand_data(base).qpos[:3]).max() > 1e-3


def test_standing_uphill_leans_back_and_downhill_forward():
    """TKU-X's stand leans forward about 7 deg on a level floor; on a 3 deg uphill it leans
    less, on a 3 deg downhill more (the pitch is the floor's frame's)."""
    pitch = {}
    for deg in (-3.0, 0.0, 3.0):
        s, o = simulate_mujoco(stack_pushes([make_push(0.0)]), 0.0, PARAMS,
                               config=RolloutConfig(duration_s=1.5, floor_pitch_deg=deg))
        assert not o.fell[0]
        pitch[deg] = float(np.degrees(np.asarray(s.pitch)[0, -1]))
    assert pitch[3.0] < pitch[0.0] - 1.0 and pitch[-3.0] > pitch[0.0] + 1.0


def test_spec_floor_pitch_is_checked_recorded_and_hashed():
    with pytest.raises(SpecError, match=r"sweep\.floor_pitch_deg: 20 is out of range "
                                        r"\[-15\.0, 15\.0\] deg"):
        parse_spec({"sweep": {"floor_pitch_deg": 20}, "push": {"grid": {"impulse_ns": [1]}}})
    level = parse_spec({"push": {"grid": {"impulse_ns": [1]}}})
    slope = parse_spec({"sweep": {"floor_pitch_deg": 4}, "push": {"grid": {"impulse_ns": [1]}}})
    assert "floor_pitch_deg" not in level.records()
    np.testing.assert_array_equal(slope.records()["floor_pitch_deg"], 4.0)
    assert spec_hash(level, PARAMS, ModelParams()) != spec_hash(slope, PARAMS, ModelParams())


def test_slope_sweep_records_equal_the_direct_simulation(tmp_path):
    data = {"sweep": {"duration_s": 1.5, "floor_pitch_deg": -4.0, "control": ["on"]},
            "push": {"grid": {"impulse_ns": [0.3, 1.2], "azimuth_deg": [0, 180],
                              "onset_s": [0.6]}}}
    run_sweep(parse_spec(data), tmp_path / "out", backend="mujoco", quiet=True)
    rec = load(tmp_path / "out")
    pushes = stack_pushes([make_push(float(j), float(a), onset_s=0.6)
                           for j, a in zip(rec["impulse_ns"], rec["azimuth_deg"])])
    _, out = simulate_mujoco(pushes, 1.0, PARAMS,
                             config=RolloutConfig(duration_s=1.5, floor_pitch_deg=-4.0))
    np.testing.assert_array_equal(rec["fell"], out.fell)
    np.testing.assert_allclose(rec["peak_incl_deg"], out.peak_incl_deg, rtol=1e-6)
    _, level = simulate_mujoco(pushes, 1.0, PARAMS, config=RolloutConfig(duration_s=1.5))
    assert not np.allclose(out.peak_incl_deg, level.peak_incl_deg, rtol=1e-3)


@pytest.mark.slow
def test_mjx_slope_matches_mujoco():
    from tkujax.sim.rollout_mjx import simulate

    pushes = stack_pushes([make_push(j, a, onset_s=0.6) for j, a in ((0.3, 0), (0.8, 180))])
    cfg = RolloutConfig(duration_s=1.5, floor_pitch_deg=5.0)
    s_c, o_c = simulate_mujoco(pushes, 1.0, PARAMS, config=cfg)
    s_j, o_j = simulate(pushes, 1.0, PARAMS, config=cfg)
    np.testing.assert_array_equal(o_j.fell, o_c.fell)
    np.testing.assert_allclose(np.degrees(s_j.pitch), np.degrees(s_c.pitch), atol=1.0)
