"""Leg chains as real robots have them (tkujax.robot): hips in any order and a waist above them
(Booster T1), five-joint legs, left and right checked, servos from the robot file for
`<motor>` legs and learning-pipeline gains, the stand's per-joint explanation, and the linear
leg map for chains that are not TKU-X's, against MuJoCo's kinematics and the sign map.

T1 and OP3 come from a Menagerie checkout (TKUJAX_MENAGERIE or ../shared/models beside the
repository) and are skipped without one; the five-joint leg is generated from TKU-X's MJCF.
"""

import os
from pathlib import Path

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import tkujax
from tkujax.control.controller import stand_leg_targets
from tkujax.control.controller_params import ControllerParams
from tkujax.control.solve import solve_legs
from tkujax.model import ModelParams, build_mjcf
from tkujax.robot.builtin import robot_toml, write_generated_robot
from tkujax.robot.robot_setup import robot_setup
from tkujax.robot.description import RobotFileError
from tkujax.robot.geometry import RobotGeometry, scaled_defaults
from tkujax.robot.ik_numeric import base_data, foot_pose, solve_leg_ik
from tkujax.robot.leg_map import jacobian_map
from tkujax.robot.loader import LEG_ORDER, load_robot
from tkujax.robot.stand import check_stand, stand_pose
from tkujax.sim.leg_chain import chain_targets_host
from tkujax.sim.rollout_mujoco import simulate_mujoco

REPO = Path(__file__).resolve().parents[1]


def _menagerie() -> Path:
    env = os.environ.get("TKUJAX_MENAGERIE")
    return Path(env) if env else REPO.parent / "shared" / "models"


HAVE_T1 = (_menagerie() / "booster_t1" / "t1.xml").is_file()
HAVE_OP3 = (_menagerie() / "robotis_op3" / "op3.xml").is_file()
needs_t1 = pytest.mark.skipif(not HAVE_T1, reason="no Menagerie booster_t1 (TKUJAX_MENAGERIE)")
needs_op3 = pytest.mark.skipif(not HAVE_OP3, reason="no Menagerie robotis_op3")
T1_FILE = REPO / "specs" / "robots" / "t1.toml"


def _gentle_pushes(height_m: float, impulse_ns: float):
    return tkujax.stack_pushes([tkujax.make_push(impulse_ns, azimuth_deg=a, height_m=height_m,
                                                 onset_s=0.3) for a in (0.0, 90.0, 180.0)])


def _no_fall_on_c(setup, impulse_ns: float) -> None:
    """A gentle push from three sides, control off and on, 1.5 s on MuJoCo C: nothing falls."""
    pushes = _gentle_pushes(float(setup.defaults.com_height), impulse_ns)
    config = tkujax.RolloutConfig(duration_s=1.5)
    for enabled in (0.0, 1.0):
        _, out = simulate_mujoco(pushes, np.full(3, enabled), setup.params, robot=setup,
                                 config=config)
        assert not out.fell.any(), (enabled, out.fell)


# --- Booster T1: hips pitch-roll-yaw below a waist --------------------------------------------


@needs_t1
def test_t1_chain_order_and_waist_are_read_from_the_model():
    t1 = load_robot(T1_FILE)
    assert t1.chain_order[0] == ("hip_pitch", "hip_roll", "hip_yaw", "knee", "ankle_pitch",
                                 "ankle_roll")
    assert not t1.tkux_chain
    assert [t1.model.joint(j).name for j in t1.waist_joints] == ["Waist"]
    # [servo] made each leg joint a 200 N m/rad servo with the joint's force range.
    for a in t1.leg_actuators.reshape(-1):
        assert t1.model.actuator_gainprm[a, 0] == 200.0
        assert t1.model.actuator_biasprm[a, 2] == -5.0
    knee = t1.leg_actuators[0, t1.column("knee")]
    assert t1.model.actuator_forcerange[knee, 1] == pytest.approx(60.0)


@needs_t1
def test_t1_with_its_own_servos_falls_and_is_told_why(tmp_path):
    text = _without_controller(T1_FILE.read_text()).split("[servo]")[0]
    text = text.replace("${TKUJAX_MENAGERIE:-../../../shared/models}", str(_menagerie()))
    path = tmp_path / "t1_model_servos.toml"
    path.write_text(text)
    robot = load_robot(path)
    result = check_stand(robot, stand_pose(robot), seconds=3.0)
    assert not result.stood
    assert "toppling stiffness m g h" in result.why
    assert "raise [servo] kp of ankle_pitch" in result.why


@needs_t1
def test_t1_stands_with_the_servo_table():
    t1 = load_robot(T1_FILE)
    result = check_stand(t1, stand_pose(t1), seconds=3.0)
    assert result.stood, result.why
    assert result.sole_force_fraction == pytest.approx(1.0, abs=0.02)


def _ankles_base(robot, qpos) -> np.ndarray:
    data = base_data(robot, qpos)
    return np.array([foot_pose(robot, data, side)[0] for side in LEG_ORDER])


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _without_controller(text: str) -> str:
    """A robot file's text without its controller lines (a copy elsewhere has no such files)."""
    return "\n".join(line for line in text.splitlines()
                     if not line.startswith(("controller", "walk_controller")))


def _t1_moved(moves, exact: bool):
    """Each controller step (the right foot moved by `move` from the stand, m) through T1's
    leg map (the IK, or its linear start) and MuJoCo's kinematics: (moved, asked) ankle
    displacements in the base frame."""
    t1 = robot_setup(T1_FILE)
    robot, idx, params = load_robot(T1_FILE), t1.setup.index, t1.defaults
    pose = stand_pose(robot)
    stand = np.array([[0.0, -params.hip_offset_y, -params.hip_to_ankle_z],
                      [0.0, params.hip_offset_y, -params.hip_to_ankle_z]])
    ankles0 = _ankles_base(robot, pose.qpos)
    out = []
    for move in moves:
        p = stand + np.array([move, [0.0, 0.0, 0.0]])
        q, ok = solve_legs(jnp.asarray(p[0], jnp.float32), jnp.asarray(p[1], jnp.float32),
                           params)
        assert bool(ok)
        q = np.asarray(q, np.float64)
        targets = (chain_targets_host(idx.leg_chain, q[None])[0] if exact
                   else idx.leg_matrix @ q + idx.leg_offsets)
        qpos = pose.qpos.copy()
        qpos[robot.leg_qpos.reshape(-1)] = targets
        asked = _rot_y(float(params.standing_lean)).T @ np.array(move)
        out.append((_ankles_base(robot, qpos) - ankles0, asked))
    return out


T1_STEPS = ((0.03, 0.0, 0.0), (0.0, 0.02, 0.0), (-0.03, 0.0, 0.02), (-0.175, 0.0, 0.07),
            (0.15, 0.05, 0.05), (0.0, -0.06, 0.04))


@needs_t1
def test_t1_leg_ik_puts_the_feet_where_the_controller_asks():
    """Controller foot targets -> TKU-X joint targets -> T1's IK (the rollouts' map) ->
    MuJoCo's kinematics: the swing ankle moves by the asked displacement (pelvis frame),
    large steps included; the stance foot stays."""
    assert robot_setup(T1_FILE).setup.index.leg_chain is not None
    for (moved, asked), move in zip(_t1_moved(T1_STEPS, exact=True), T1_STEPS):
        assert np.linalg.norm(moved[0] - asked) < 0.5e-3, (move, moved[0], asked)
        assert np.linalg.norm(moved[1]) < 1e-4


@needs_t1
def test_t1_linear_map_alone_is_first_order():
    """The IK's start, the linear map about the stand, is good for small steps only (a 17.5 cm
    backward step with a 7 cm lift lands 7.8 mm off: why the rollouts solve the IK)."""
    small, large = _t1_moved([(0.03, 0.0, 0.0), (-0.175, 0.0, 0.07)], exact=False)
    assert np.linalg.norm(small[0][0] - small[1]) < 0.5e-3
    assert np.linalg.norm(large[0][0] - large[1]) > 5e-3


@needs_t1
def test_t1_runs_gentle_pushes_without_falling_on_mujoco_c():
    _no_fall_on_c(robot_setup(T1_FILE), impulse_ns=3.0)


def test_jacobian_map_equals_the_sign_map_on_tkux(tmp_path):
    """On TKU-X's own chain with the controller's stand equal to the robot's, the linear map is
    the identity (the sign map): the two Jacobians are independent computations."""
    robot = load_robot(write_generated_robot(tmp_path, name="tkux"))
    pose = stand_pose(robot)
    params = ControllerParams.paper()
    q = np.asarray(stand_leg_targets(params), np.float64)
    matrix, offsets = jacobian_map(robot, pose.qpos, pose.ctrl, q, params.thigh_length,
                                   params.calf_length)
    np.testing.assert_allclose(matrix, np.eye(12), atol=1e-6)
    np.testing.assert_allclose(offsets, 0.0, atol=1e-6)


# --- five-joint legs ----------------------------------------------------------------------------


def _five_joint_robot(folder: Path) -> Path:
    """TKU-X's MJCF without the ankle roll joints (and their servos), no keyframe."""
    spec = mujoco.MjSpec.from_string(build_mjcf(ModelParams()))
    for side in "rl":
        for a in list(spec.actuators):
            if a.target == f"{side}_ankle_roll":
                spec.delete(a)
        spec.delete(spec.joint(f"{side}_ankle_roll"))
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "five.xml").write_text(spec.to_xml())
    text = robot_toml("five.xml", "five", stand=None)
    text = "\n".join(line for line in text.splitlines() if not line.startswith("ankle_roll"))
    (folder / "five.toml").write_text(text + "\n")
    return folder / "five.toml"


def test_five_joint_leg_loads_stands_and_solves_its_ik(tmp_path):
    robot = load_robot(_five_joint_robot(tmp_path))
    assert robot.roles == ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch")
    assert robot.leg_joints.shape == (2, 5) and not robot.tkux_chain
    pose = stand_pose(robot)
    assert check_stand(robot, pose, seconds=2.0).stood
    rng = np.random.default_rng(0)
    for i, side in enumerate(LEG_ORDER):
        for _ in range(10):
            q_true = pose.qpos[robot.leg_qpos[i]] + rng.uniform(-0.2, 0.2, 5)
            data = base_data(robot, pose.qpos)
            data.qpos[robot.leg_qpos[i]] = q_true
            mujoco.mj_kinematics(robot.model, data)
            pos, rot = foot_pose(robot, data, side)
            sol = solve_leg_ik(robot, side, pos, rot, q_init=pose.qpos[robot.leg_qpos[i]])
            assert sol.position_error_m < 1e-7 and sol.rotation_error_rad < 1e-6


def test_five_joint_leg_runs_gentle_pushes(tmp_path):
    setup = robot_setup(_five_joint_robot(tmp_path))
    assert setup.setup.index.leg_matrix.shape == (10, 12)
    _no_fall_on_c(setup, impulse_ns=0.3)


# --- refused descriptions -------------------------------------------------------------------


def test_swapped_legs_are_refused(tmp_path):
    path = write_generated_robot(tmp_path, name="swap")
    text = path.read_text()
    text = text.replace("[legs.left]", "[legs.TMP]").replace("[legs.right]", "[legs.left]")
    path.write_text(text.replace("[legs.TMP]", "[legs.right]"))
    with pytest.raises(RobotFileError, match=r"left and right swapped"):
        load_robot(path)


def test_a_knee_given_as_a_hip_is_refused(tmp_path):
    path = write_generated_robot(tmp_path, name="mixed")
    text = path.read_text()
    text = text.replace('hip_pitch = "l_hip_pitch"', 'hip_pitch = "TMP"')
    text = text.replace('knee = "l_knee"', 'knee = "l_hip_pitch"').replace('"TMP"', '"l_knee"')
    path.write_text(text)
    with pytest.raises(RobotFileError, match=r"legs\.left: the joints are not the chain"):
        load_robot(path)


def test_clamped_defaults_stay_in_range_and_say_why():
    geo = RobotGeometry(thigh_length_m=0.42, calf_length_m=0.45, hip_offset_y_m=0.1,
                        hip_to_ankle_z_m=0.8, leg_length_m=0.95, com_height_m=1.0,
                        stand_lean_rad=-1.6, hip_centre_base_m=(0.0, 0.1, 0.0), mass_kg=40.0)
    params, notes = scaled_defaults(geo)
    params.validate()
    said = " ".join(notes)
    for field in ("lift_height", "standing_lean", "eps_backward"):
        assert field in said
    assert params.lift_height == 0.1


# --- servos from the robot file (OP3 rewritten) ----------------------------------------------


def _op3_variant(folder: Path, edit, servo: str = "") -> Path:
    """OP3 with its op3.xml text edited by `edit`, beside a link to its assets."""
    src = _menagerie() / "robotis_op3"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "assets").symlink_to(src / "assets")
    (folder / "op3.xml").write_text(edit((src / "op3.xml").read_text()))
    (folder / "scene.xml").write_text((src / "scene.xml").read_text())
    text = (REPO / "specs" / "robots" / "op3.toml").read_text()
    text = text.replace("${TKUJAX_MENAGERIE:-../../../shared/models}/robotis_op3/", "")
    (folder / "op3.toml").write_text(_without_controller(text) + "\n" + servo)
    return folder / "op3.toml"


LEG_JOINTS = [f"{s}_{j}" for s in "lr" for j in ("hip_yaw", "hip_roll", "hip_pitch", "knee",
                                                   "ank_pitch", "ank_roll")]


def _motors(text: str) -> str:
    for j in LEG_JOINTS:
        text = text.replace(f'<position name="{j}_act" joint="{j}"/>',
                            f'<motor name="{j}_act" joint="{j}" ctrlrange="-5 5"/>')
    return text


@needs_op3
def test_motor_legs_need_a_servo_table(tmp_path):
    with pytest.raises(RobotFileError, match=r"legs\.right\.hip_yaw: .*give a \[servo\] table"):
        load_robot(_op3_variant(tmp_path, _motors))


@needs_op3
def test_motor_legs_with_a_servo_table_stand_and_sweep(tmp_path):
    path = _op3_variant(tmp_path, _motors, "[servo]\nkp = 21.1\nkv = 0.3\n")
    robot = load_robot(path)
    a = robot.leg_actuators[0, robot.column("knee")]
    # The motor's ctrlrange x gear (5 N m) is the servo's force limit; its target the joint's.
    assert robot.model.actuator_forcerange[a, 1] == pytest.approx(5.0)
    assert robot.model.actuator_gainprm[a, 0] == pytest.approx(21.1)
    assert check_stand(robot, stand_pose(robot), seconds=2.0).stood
    _no_fall_on_c(robot_setup(path), impulse_ns=0.3)


@needs_op3
def test_learning_pipeline_gains_are_explained_per_joint(tmp_path):
    def soft(text: str) -> str:
        for j in LEG_JOINTS:
            if "knee" in j or "ank" in j:
                text = text.replace(f'<position name="{j}_act" joint="{j}"/>',
                                    f'<position name="{j}_act" joint="{j}" kp="1"/>')
        return text

    robot = load_robot(_op3_variant(tmp_path, soft))
    result = check_stand(robot, stand_pose(robot), seconds=2.0)
    assert not result.stood
    assert "knee: the stand needs" in result.why
    assert "kp 1 gives 0.05 N m at 0.05 rad of error" in result.why
    assert "raise [servo] kp to at least" in result.why


@needs_t1
def test_a_waist_without_a_servo_is_refused(tmp_path):
    src = _menagerie() / "booster_t1"
    (tmp_path / "assets").symlink_to(src / "assets")
    text = (src / "t1.xml").read_text()
    text = text.replace('<position class="t1" name="Waist" joint="Waist"/>', "")
    (tmp_path / "t1.xml").write_text(text.replace("\n    0\n    -0.2", "\n    -0.2"))
    (tmp_path / "scene.xml").write_text((src / "scene.xml").read_text())
    robot_file = _without_controller(T1_FILE.read_text()).replace(
        "${TKUJAX_MENAGERIE:-../../../shared/models}/booster_t1/", "")
    (tmp_path / "t1.toml").write_text(robot_file.replace('keyframe = "home"', ""))
    with pytest.raises(RobotFileError, match=r"'Waist' sits between .* give \[servo\.other\]"):
        load_robot(tmp_path / "t1.toml")
    (tmp_path / "t1.toml").write_text(robot_file.replace('keyframe = "home"', "")
                                      + "\n[servo.other]\nkp = 200.0\nkv = 5.0\n")
    assert load_robot(tmp_path / "t1.toml").waist_joints


@pytest.mark.slow
def test_five_joint_leg_mjx_agrees_with_mujoco_c(tmp_path):
    """The robot's IK in the MJX loop (tkujax.sim.leg_chain, traced) against the same IK
    called from MuJoCo C's loop: the same falls, and pitch and ankles alike before any."""
    from tkujax.sim.rollout_mjx import simulate

    setup = robot_setup(_five_joint_robot(tmp_path))
    pushes = tkujax.stack_pushes([
        tkujax.make_push(j, azimuth_deg=a, height_m=float(setup.defaults.com_height),
                         onset_s=0.3) for j, a in ((0.3, 0.0), (0.6, 90.0), (6.0, 180.0))])
    enabled, config = np.array([1.0, 1.0, 0.0]), tkujax.RolloutConfig(duration_s=1.2)
    series, out = simulate_mujoco(pushes, enabled, setup.params, robot=setup, config=config)
    mjx_series, mjx_out = simulate(pushes, enabled, setup.params, robot=setup, config=config)
    assert out.fell.tolist() == mjx_out.fell.tolist() == [False, False, True]
    np.testing.assert_allclose(mjx_series.pitch[:2], series.pitch[:2], atol=2e-3)
    np.testing.assert_allclose(mjx_series.l_ankle[:2], series.l_ankle[:2], atol=2e-3)


@needs_op3
def test_a_tilted_axis_in_tkux_order_gets_the_robots_own_ik(tmp_path):
    """TKU-X's joint order is not enough for the joint-for-joint sign map: with OP3's hip-yaw
    axes tilted 30 degrees (as the Berkeley Humanoid's are 45), the loop solves the robot's
    own IK (whose round trip the tests above measure) instead of mapping joint for joint."""
    def tilt(text: str) -> str:
        for side in "lr":
            text = text.replace(f'<joint name="{side}_hip_yaw" axis="0 0 -1"/>',
                                f'<joint name="{side}_hip_yaw" axis="0.5 0 -0.866"/>')
        return text

    plain, tilted = load_robot(_op3_variant(tmp_path / "plain", lambda t: t)), \
        load_robot(_op3_variant(tmp_path / "tilted", tilt))
    assert plain.tkux_chain and plain.joint_for_joint
    assert tilted.tkux_chain and not tilted.joint_for_joint
    assert robot_setup(tmp_path / "plain" / "op3.toml").leg_chain is None
    assert robot_setup(tmp_path / "tilted" / "op3.toml").leg_chain is not None


@needs_op3
def test_the_stands_needs_do_not_depend_on_armature(tmp_path):
    """Statics do not see armature: OP3 with its joints' armature removed needs the torques it
    needs with it (the stiff servos' stand integrated implicitly; with Euler it diverged and
    read kilonewton-metres)."""
    import re

    from tkujax.robot.stand_torques import stand_torques

    def needs(edit, folder):
        robot = load_robot(_op3_variant(tmp_path / folder, edit))
        pose = stand_pose(robot)
        return stand_torques(robot, pose.qpos, pose.ctrl)

    with_armature = needs(lambda text: text, "own")
    without = needs(lambda text: re.sub(r'armature="[^"]*"', 'armature="0"', text), "none")
    assert with_armature.max() > 0.3                  # the knees hold the stand
    np.testing.assert_allclose(without, with_armature, rtol=0.15, atol=0.05)
