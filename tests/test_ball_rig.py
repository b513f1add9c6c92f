"""The paper's ball rig (a MuJoCo pendulum) against the impulse model `tkujax.sim.push`.

Tolerance on delivered momentum vs the impulse model's J = m v (`ball_momentum_ns`), from the
physics: a perfectly inelastic hit on a free body of the robot's 4.5 kg would deliver
M/(M+m) = 0.93-0.97 J; a perfectly elastic one up to 2 J. MuJoCo's default soft contact
(solref (0.02, 1)) lands at delivered/J = 1.12 / 1.09 (baseball back / front) and 1.07 / 1.02
(volleyball back / front): the floor-anchored robot stops the ball and returns it at 4-12 % of
its speed (restitution 0.11-0.18). The test pins each case to its measured ratio +-10 % (and
inside the physical [inelastic free body, elastic] bracket), so it documents the relation and
fails if the rig changes: the ball misses (raises), grazes an edge or hits twice, a different
contact model, a different pendulum.
"""

import math

import mujoco
import numpy as np
import pytest

from tkujax.sim import physics
from tkujax.sim.ball_rig import (RIG_GAP_M, ball_rig_impulse, ball_rig_model, ball_rig_xml,
                             rig_geometry)
from tkujax.sim.push import (BALLS, DEFAULT_HEIGHT_M, ball_momentum_ns, ball_speed_m_s,
                             pendulum_length_m)

CASES = [(b, d) for b in ("baseball", "volleyball") for d in ("back", "front")]
# delivered / J with the default model and contact (see tkujax/ball_rig.py's docstring).
MEASURED_RATIO = {("baseball", "back"): 1.12, ("baseball", "front"): 1.09,
                  ("volleyball", "back"): 1.07, ("volleyball", "front"): 1.02}
RATIO_TOL = 0.10      # relative, around the measured ratio
SPEED_TOL = 0.03      # relative, arrival speed vs ball_speed_m_s()
TIME_TOL_S = 0.020    # first contact vs the paper's 0.75 s
ROBOT_MASS_KG = 4.5


@pytest.fixture(scope="module")
def results():
    out = {case: ball_rig_impulse(*case) for case in CASES}
    print("\ncase               v_in   t_hit   v_out   delivered  /J     e     contact  robot_dp"
          "  floor")
    for (b, d), r in out.items():
        print(f"{b:10s} {d:5s}   {r['arrival_speed_m_s']:.3f}  {r['contact_time_s']:.3f}  "
              f"{r['v_after_m_s']:+.3f}  {r['delivered_x_ns']:+.4f}    {r['ratio']:.3f}  "
              f"{r['restitution']:.2f}  {1e3 * r['contact_duration_s']:4.0f} ms  "
              f"{r['robot_dp_ns']:.4f}    {r['floor_impulse_ns']:+.4f}")
    return out


@pytest.mark.parametrize("ball,direction", CASES)
def test_rig_geometry(ball, direction):
    """Ball of the right size on a pendulum of the right length, 1.5 mm off the leaning chest."""
    model = ball_rig_model(ball, direction)
    b = BALLS[ball]
    assert model.body("ball").mass[0] == pytest.approx(b.mass_kg)
    assert model.geom("ball").size[0] == pytest.approx(b.radius_m)
    # One contact pair more than the robot's, ball-chest; the ball can touch nothing else.
    ball_geom, chest_geom = model.geom("ball").id, model.geom("chest").id
    assert model.npair == physics.host_model().npair + 1
    pairs = [{int(g1), int(g2)} for g1, g2 in zip(model.pair_geom1, model.pair_geom2)
             if ball_geom in (g1, g2)]
    assert pairs == [{ball_geom, chest_geom}]
    assert model.geom_contype[ball_geom] == 0 and model.geom_conaffinity[ball_geom] == 0
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("rig").id)
    mujoco.mj_forward(model, data)
    pivot, centre = data.xpos[model.body("ball_pendulum").id], data.xpos[model.body("ball").id]
    assert np.linalg.norm(pivot - centre) == pytest.approx(pendulum_length_m(), abs=1e-9)
    sign = 1.0 if direction == "back" else -1.0
    # Released from 45 deg, on the side the ball comes from.
    assert math.atan2(-(centre - pivot)[0], -(centre - pivot)[2]) == pytest.approx(
        sign * math.pi / 4, abs=1e-9)
    # Keyframe = stand pose + ball: the robot's qpos and ctrl are the stand key's.
    n = model.nq - 1
    np.testing.assert_array_equal(model.key("rig").qpos[:n], model.key("stand").qpos[:n])
    np.testing.assert_array_equal(model.key("rig").ctrl, model.key("stand").ctrl)
    # At the bottom of the swing: centre at 0.36 m, 1.5 mm from the chest box, on the right side.
    data.qpos[model.joint("ball_swing").qposadr[0]] = 0.0
    mujoco.mj_kinematics(model, data)
    centre = data.xpos[model.body("ball").id]
    assert centre[2] == pytest.approx(DEFAULT_HEIGHT_M, abs=1e-9)
    gap = mujoco.mj_geomDistance(model, data, model.geom("ball").id, model.geom("chest").id,
                                 0.1, None)
    assert gap == pytest.approx(RIG_GAP_M, abs=1e-6)
    chest = data.geom_xpos[model.geom("chest").id]
    assert sign * (chest[0] - centre[0]) > 0      # back: the ball is behind (-x) the chest
    assert rig_geometry(ball, direction).release_angle_rad == pytest.approx(sign * math.pi / 4)


def test_rig_xml_compiles_standalone():
    xml = ball_rig_xml("volleyball", "back")
    model = mujoco.MjModel.from_xml_string(xml)
    assert model.nkey == 2 and model.key("rig").qpos[-1] == pytest.approx(math.pi / 4)
    with pytest.raises(ValueError, match="ball"):
        ball_rig_xml("football", "back")
    with pytest.raises(ValueError, match="direction"):
        ball_rig_impulse("baseball", "left")


@pytest.mark.parametrize("ball,direction", CASES)
def test_arrival(results, ball, direction):
    """(a) The ball arrives at the pendulum's speed, at the paper's 0.75 s."""
    r = results[ball, direction]
    assert r["arrival_speed_m_s"] == pytest.approx(ball_speed_m_s(), rel=SPEED_TOL)
    assert abs(r["contact_time_s"] - 0.75) <= TIME_TOL_S
    assert 0.0 < r["gap_m"] < 0.003                 # touching distance after settling


@pytest.mark.parametrize("ball,direction", CASES)
def test_delivered_momentum_vs_impulse_model(results, ball, direction):
    """(b) delivered / J at its measured value +-10 %, inside the physical bracket; one hit."""
    r = results[ball, direction]
    m = BALLS[ball].mass_kg
    j = ball_momentum_ns(ball)
    assert r["impulse_model_ns"] == pytest.approx(j)
    ratio = r["delivered_ns"] / j
    print(f"{ball} {direction}: delivered {r['delivered_ns']:.4f} N s, J = m v = {j:.4f} N s, "
          f"ratio {ratio:.3f} (measured {MEASURED_RATIO[ball, direction]})")
    assert ratio == pytest.approx(MEASURED_RATIO[ball, direction], rel=RATIO_TOL)
    inelastic = ROBOT_MASS_KG / (ROBOT_MASS_KG + m) * r["arrival_speed_m_s"] * m / j
    elastic = 2.0 * r["arrival_speed_m_s"] * m / j
    assert inelastic < ratio < elastic
    assert r["n_contacts"] == 1, "the ball hit the chest more than once"
    assert 0.0 <= r["restitution"] < 0.5
    assert 0.005 < r["contact_duration_s"] < 0.15
    # The robot gains momentum in the push direction, less than the ball gave (floor friction).
    assert 0.0 < r["robot_dp_ns"] < r["delivered_ns"]
    assert r["floor_impulse_ns"] < 0.0


@pytest.mark.parametrize("ball,direction", CASES)
def test_direction_sign(results, ball, direction):
    """(c) The delivered momentum points along the push: +x from the back, -x from the front."""
    r = results[ball, direction]
    sign = 1.0 if direction == "back" else -1.0
    assert np.sign(r["delivered_x_ns"]) == sign
    assert r["delivered_x_ns"] == pytest.approx(sign * r["delivered_ns"])
