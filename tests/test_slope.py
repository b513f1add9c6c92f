"""Slopes: the floor pitched uphill or downhill and rolled sideways as a tilted gravity
(tkujax.sim.slope, RolloutConfig.floor_pitch_deg/floor_roll_deg, [sweep] floor_pitch_deg and
floor_roll_deg).

The gravity against its closed form; the independent reference: TKU-X on a level floor under
the slope's gravity moves exactly as TKU-X on a floor plane actually pitched (rolled, both) in
the MuJoCo model under the usual gravity, its state rotated onto it (MuJoCo C, 0.6 s with its
stand held); standing uphill leans back and downhill forward; the spec's keys refused out of
range with their names, in the records and the hash (a spec without them keeps its hash); a
slope sweep's records equal the direct simulation; MJX against MuJoCo C (slow).
"""

import json
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams, model_xml
from tkujax.sim import physics
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import make_push, stack_pushes
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.sim.slope import LEVEL_FLOOR, Floor, slope_gravity, tilt_host_model
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.record_schema import (manifest_controller_params, manifest_model_params,
                                         manifest_spec)
from tkujax.sweeps.sweep import load, run_sweep
from tkujax.sweeps.sweep_hash import spec_hash

PARAMS = ControllerParams.paper()
RESULTS = Path(__file__).resolve().parents[1] / "results"


def test_slope_gravity_closed_form():
    g = slope_gravity(10.0, 9.81)
    np.testing.assert_allclose(g, [-9.81 * math.sin(math.radians(10)), 0.0,
                                   -9.81 * math.cos(math.radians(10))])
    assert np.linalg.norm(g) == pytest.approx(9.81)
    np.testing.assert_array_equal(slope_gravity(0.0, 9.81), [-0.0, 0.0, -9.81])


def test_rolled_gravity_closed_form():
    """Roll only: (0, -g sin phi, -g cos phi) (+ = the floor rises toward +y, so gravity pulls
    toward -y along it); pitch then roll: R^T (0, 0, -g) with R = Rx(phi) Ry(-theta), of
    magnitude g; roll 0: the pitched floor's vector bit for bit."""
    phi = math.radians(7.0)
    np.testing.assert_allclose(slope_gravity(0.0, 9.81, 7.0),
                               [0.0, -9.81 * math.sin(phi), -9.81 * math.cos(phi)], atol=1e-15)
    for pitch, roll in ((10.0, 7.0), (-12.0, 15.0), (15.0, -15.0)):
        g = slope_gravity(pitch, 9.81, roll)
        rot = _rx(math.radians(roll)) @ _ry(-math.radians(pitch))
        np.testing.assert_allclose(g, rot.T @ [0.0, 0.0, -9.81], atol=1e-12)
        assert np.linalg.norm(g) == pytest.approx(9.81, rel=1e-14)
        assert g[1] * roll < 0 and g[0] * pitch < 0
    for pitch in (-15.0, -3.0, 0.0, 8.0, 15.0):
        th = math.radians(pitch)
        before = np.array([-9.81 * math.sin(th), 0.0, -9.81 * math.cos(th)])
        assert slope_gravity(pitch, 9.81).tobytes() == before.tobytes()
        assert slope_gravity(pitch, 9.81, 0.0).tobytes() == before.tobytes()


def test_rollout_config_refuses_steep_floors():
    with pytest.raises(ValueError, match=r"floor_pitch_deg must be a number in \[-15, 15\] deg"):
        RolloutConfig(floor_pitch_deg=20.0)
    with pytest.raises(ValueError, match=r"floor_roll_deg must be a number in \[-15, 15\] deg "
                                         r"\(\+ = the floor rises toward \+y\)"):
        RolloutConfig(floor_roll_deg=-15.5)
    assert RolloutConfig(floor_pitch_deg=15, floor_roll_deg=-15).floor_roll_deg == -15


def test_floor_is_one_checked_hashable_value():
    """RolloutConfig.floor: the two angles as one Floor (floats, a cache key), its gravity
    slope_gravity's, the level floor LEVEL_FLOOR; a Floor checks as RolloutConfig does."""
    floor = RolloutConfig(floor_pitch_deg=4, floor_roll_deg=-3).floor
    assert floor == Floor(4.0, -3.0) and hash(floor) == hash(Floor(4.0, -3.0))
    assert type(floor.pitch_deg) is float and not floor.is_level
    assert floor.gravity(9.81).tobytes() == slope_gravity(4.0, 9.81, -3.0).tobytes()
    assert RolloutConfig().floor == LEVEL_FLOOR and LEVEL_FLOOR.is_level
    with pytest.raises(ValueError, match=r"floor_roll_deg must be a number in \[-15, 15\]"):
        Floor(0.0, 16.0)


def _ry(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rx(phi: float) -> np.ndarray:
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_tilted_gravity_is_a_pitched_floor():
    """World B = world A rotated by R = Ry(-theta): A is the level floor under the slope's
    gravity (what tkujax simulates), B the floor plane pitched by theta under (0, 0, -g). Every
    body's position in B is R times its position in A, to 0.1 mm after 0.6 s."""
    _check_against_tilted_plane(8.0, 0.0)


@pytest.mark.parametrize("pitch_deg, roll_deg", [(0.0, 8.0), (5.0, -6.0)])
def test_tilted_gravity_is_a_rolled_floor(pitch_deg, roll_deg):
    """As above with the floor plane rolled (after its pitch): R = Rx(phi) Ry(-theta)."""
    _check_against_tilted_plane(pitch_deg, roll_deg)


def _check_against_tilted_plane(pitch_deg: float, roll_deg: float) -> None:
    base = physics.host_model(ModelParams())
    model_a = tilt_host_model(base, Floor(pitch_deg, roll_deg))
    rot = _rx(math.radians(roll_deg)) @ _ry(-math.radians(pitch_deg))
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



def test_spec_floor_roll_is_checked_recorded_and_hashed():
    grid = {"push": {"grid": {"impulse_ns": [1]}}}
    with pytest.raises(SpecError, match=r"sweep\.floor_roll_deg: 20 is out of range "
                                        r"\[-15\.0, 15\.0\] deg \(\+ = the floor rises"):
        parse_spec({"sweep": {"floor_roll_deg": 20}} | grid)
    with pytest.raises(SpecError, match=r"sweep\.floor_roll_deg: expected a number"):
        parse_spec({"sweep": {"floor_roll_deg": "left"}} | grid)
    with pytest.raises(SpecError, match=r"sweep\.floor_roll_deg: a slope runs with decisions"):
        parse_spec({"sweep": {"floor_roll_deg": 3, "decisions": "early"}} | grid)
    level = parse_spec(grid)
    roll = parse_spec({"sweep": {"floor_roll_deg": -3}} | grid)
    both = parse_spec({"sweep": {"floor_pitch_deg": 4, "floor_roll_deg": -3}} | grid)
    assert (level.floor_roll_deg, roll.floor_roll_deg, roll.floor_pitch_deg) == (0.0, -3.0, 0.0)
    assert "floor_roll_deg" not in level.records()
    assert "floor_pitch_deg" not in roll.records()
    np.testing.assert_array_equal(roll.records()["floor_roll_deg"], -3.0)
    np.testing.assert_array_equal(both.records()["floor_pitch_deg"], 4.0)
    np.testing.assert_array_equal(both.records()["floor_roll_deg"], -3.0)
    hashes = {spec_hash(s, PARAMS, ModelParams()) for s in (level, roll, both)}
    assert len(hashes) == 3


@pytest.mark.parametrize("folder", ["walk_push_map_cpu", "walk_uphill_cpu"])
def test_specs_without_the_roll_keep_their_hash(folder):
    """The committed level and uphill sweeps' manifests: their specs hash as when they ran."""
    path = RESULTS / "walking" / folder / "manifest.json"
    m = json.loads(path.read_text())
    assert "floor_roll_deg" not in m["spec"].get("sweep", {})
    spec = manifest_spec(m)
    model = manifest_model_params(m) or ModelParams()
    assert spec_hash(spec, manifest_controller_params(m, str(path)), model) == m["spec_hash"]


def test_rolled_sweep_records_equal_the_direct_simulation(tmp_path):
    data = {"sweep": {"duration_s": 1.5, "floor_pitch_deg": 2.0, "floor_roll_deg": 5.0,
                      "control": ["on"]},
            "push": {"grid": {"impulse_ns": [0.3, 1.2], "azimuth_deg": [90, 270],
                              "onset_s": [0.6]}}}
    run_sweep(parse_spec(data), tmp_path / "out", backend="mujoco", quiet=True)
    rec = load(tmp_path / "out")
    np.testing.assert_array_equal(rec["floor_roll_deg"], 5.0)
    pushes = stack_pushes([make_push(float(j), float(a), onset_s=0.6)
                           for j, a in zip(rec["impulse_ns"], rec["azimuth_deg"])])
    cfg = RolloutConfig(duration_s=1.5, floor_pitch_deg=2.0, floor_roll_deg=5.0)
    _, out = simulate_mujoco(pushes, 1.0, PARAMS, config=cfg)
    np.testing.assert_array_equal(rec["fell"], out.fell)
    np.testing.assert_allclose(rec["peak_incl_deg"], out.peak_incl_deg, rtol=1e-6)
    _, pitched = simulate_mujoco(pushes, 1.0, PARAMS,
                                 config=RolloutConfig(duration_s=1.5, floor_pitch_deg=2.0))
    assert not np.allclose(out.peak_incl_deg, pitched.peak_incl_deg, rtol=1e-3)

@pytest.mark.slow
def test_mjx_slope_matches_mujoco():
    from tkujax.sim.rollout_mjx import simulate

    pushes = stack_pushes([make_push(j, a, onset_s=0.6) for j, a in ((0.3, 0), (0.8, 180))])
    cfg = RolloutConfig(duration_s=1.5, floor_pitch_deg=5.0)
    s_c, o_c = simulate_mujoco(pushes, 1.0, PARAMS, config=cfg)
    s_j, o_j = simulate(pushes, 1.0, PARAMS, config=cfg)
    np.testing.assert_array_equal(o_j.fell, o_c.fell)
    np.testing.assert_allclose(np.degrees(s_j.pitch), np.degrees(s_c.pitch), atol=1.0)



@pytest.mark.slow
def test_mjx_rolled_slope_matches_mujoco():
    from tkujax.sim.rollout_mjx import simulate

    pushes = stack_pushes([make_push(j, a, onset_s=0.6) for j, a in ((0.3, 90), (0.8, 270))])
    cfg = RolloutConfig(duration_s=1.5, floor_pitch_deg=3.0, floor_roll_deg=4.0)
    s_c, o_c = simulate_mujoco(pushes, 1.0, PARAMS, config=cfg)
    s_j, o_j = simulate(pushes, 1.0, PARAMS, config=cfg)
    np.testing.assert_array_equal(o_j.fell, o_c.fell)
    np.testing.assert_allclose(np.degrees(s_j.roll), np.degrees(s_c.roll), atol=1.0)
