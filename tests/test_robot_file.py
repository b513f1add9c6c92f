"""Robot files (tkujax/robot/): parsing and its errors, geometry from the model, numeric leg IK
round trips, the stand; on TKU-X, on a second robot tkujax generates itself and, when a
Menagerie checkout is found (TKUJAX_MENAGERIE or ../shared/models beside the repository), on
ROBOTIS OP3."""

import json
import math
import os
from pathlib import Path

import mujoco
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.robot.description import RobotFileError, load_description
from tkujax.robot.geometry import controller_params_for, measure_geometry
from tkujax.robot.ik_numeric import analytic_ik_applies, base_data, foot_pose, solve_leg_ik
from tkujax.robot.loader import LEG_ORDER, load_robot
from tkujax.robot.stand import RobotStandError, check_stand, require_stand, stand_pose

REPO = Path(__file__).resolve().parents[1]


def _menagerie() -> Path | None:
    env = os.environ.get("TKUJAX_MENAGERIE")
    root = Path(env) if env else REPO.parent / "shared" / "models"
    return root if (root / "robotis_op3" / "op3.xml").is_file() else None


needs_op3 = pytest.mark.skipif(_menagerie() is None, reason="no Menagerie checkout with "
                               "robotis_op3 (set TKUJAX_MENAGERIE)")


@pytest.fixture(scope="module")
def tkux(tmp_path_factory):
    return load_robot(write_generated_robot(tmp_path_factory.mktemp("tkux"), name="tkux"))


@pytest.fixture(scope="module")
def second_file(tmp_path_factory):
    return write_generated_robot(tmp_path_factory.mktemp("second"), GENERATED_SECOND,
                                 name="second", keyframe=False)


@pytest.fixture(scope="module")
def second(second_file):
    return load_robot(second_file)


@pytest.fixture(scope="module")
def op3():
    return load_robot(REPO / "specs" / "robots" / "op3.toml")


def test_tkux_geometry_reproduces_controller_params(tkux):
    geo = measure_geometry(tkux, stand_pose(tkux).qpos)
    ref = ControllerParams.paper()
    for mine, theirs in [(geo.thigh_length_m, ref.thigh_length), (geo.calf_length_m,
                         ref.calf_length), (geo.hip_offset_y_m, ref.hip_offset_y),
                         (geo.hip_to_ankle_z_m, ref.hip_to_ankle_z),
                         (geo.leg_length_m, ref.leg_length), (geo.com_height_m, ref.com_height)]:
        assert abs(mine - theirs) < 1e-3
    assert math.isclose(geo.stand_lean_rad, ref.standing_lean, abs_tol=1e-9)
    scaled = controller_params_for(geo)
    for name in ("step_period", "lift_height", "eps_forward", "eps_backward",
                 "cp_trigger_forward_m", "standing_lean"):
        assert math.isclose(getattr(scaled, name), getattr(ref, name), rel_tol=1e-2), name
    assert analytic_ik_applies(tkux)[0]


def test_second_robot_geometry_and_scaled_defaults(second):
    assert second.model.sensor("tkujax_gyro") is not None
    pose = stand_pose(second)
    assert pose.source.startswith("computed")
    geo = measure_geometry(second, pose.qpos)
    p = GENERATED_SECOND
    assert geo.thigh_length_m == pytest.approx(p.thigh_length_m, abs=1e-9)
    assert geo.calf_length_m == pytest.approx(p.calf_length_m, abs=1e-9)
    assert geo.hip_offset_y_m == pytest.approx(p.hip_offset_y_m, abs=1e-9)
    assert geo.hip_to_ankle_z_m == pytest.approx(0.93 * geo.reach_m, abs=1e-6)
    assert 0.2 < geo.com_height_m < 0.32
    ref, scaled = ControllerParams.paper(), controller_params_for(geo)
    assert scaled.step_period == pytest.approx(
        ref.step_period * math.sqrt(geo.com_height_m / ref.com_height))
    assert scaled.lift_height == pytest.approx(ref.lift_height * geo.reach_m / 0.22)
    assert analytic_ik_applies(second)[0]     # the generator's chain: the closed form holds


def _round_trip(robot, n: int, seed: int) -> tuple[float, float]:
    """Worst (position m, rotation rad) error of IK on foot poses made by random leg angles
    around the stand, checked by MuJoCo's own forward kinematics."""
    rng = np.random.default_rng(seed)
    stand = stand_pose(robot).qpos
    worst_p = worst_r = 0.0
    for _ in range(n):
        for i, side in enumerate(LEG_ORDER):
            q_true = stand[robot.leg_qpos[i]] + rng.uniform(-0.25, 0.25, 6)
            data = base_data(robot, stand)
            data.qpos[robot.leg_qpos[i]] = q_true
            mujoco.mj_kinematics(robot.model, data)
            pos, rot = foot_pose(robot, data, side)
            sol = solve_leg_ik(robot, side, pos, rot, q_init=stand[robot.leg_qpos[i]])
            check = base_data(robot, stand)
            check.qpos[robot.leg_qpos[i]] = sol.q_rad
            mujoco.mj_kinematics(robot.model, check)
            got_p, got_r = foot_pose(robot, check, side)
            worst_p = max(worst_p, float(np.linalg.norm(got_p - pos)))
            cos = (np.trace(got_r.T @ rot) - 1) / 2
            worst_r = max(worst_r, float(np.arccos(np.clip(cos, -1, 1))))
    return worst_p, worst_r


def test_numeric_ik_round_trip_second_robot(second):
    err_p, err_r = _round_trip(second, 10, 0)
    assert err_p < 1e-4 and err_r < math.radians(0.1)


def test_second_robot_stands_5s(second):
    result = require_stand(second, seconds=5.0)
    assert result.stood and result.floor_contact_body is None
    assert 0.9 < result.sole_force_fraction < 1.1


def test_a_robot_that_cannot_stand_is_refused(tmp_path):
    import dataclasses

    weak = dataclasses.replace(GENERATED_SECOND, leg_servo=dataclasses.replace(
        GENERATED_SECOND.leg_servo, kp_nm_per_rad=0.5))
    robot = load_robot(write_generated_robot(tmp_path, weak, name="weak", keyframe=False))
    with pytest.raises(RobotStandError, match=r"cannot stand 5 s .*touched the floor at t ="):
        require_stand(robot, seconds=5.0)


def _edit(folder: Path, second_file: Path, toml=None, xml=None) -> Path:
    """A copy of the second robot's files with the TOML and/or the MJCF text edited."""
    folder.mkdir(exist_ok=True)
    text = second_file.read_text()
    model = (second_file.parent / "second.xml").read_text()
    (folder / "second.xml").write_text(xml(model) if xml else model)
    out = folder / "robot.toml"
    out.write_text(toml(text) if toml else text)
    return out


BAD = {
    "missing_file": (None, None, r"robot file not found"),
    "unknown_joint": (lambda t: t.replace('knee = "l_knee"', 'knee = "l_kne"'), None,
                      r"legs.left.knee: no joint named 'l_kne'.*close matches: \['l_knee'"),
    "role_twice": (lambda t: t.replace('hip_roll = "l_hip_roll"', 'hip_roll = "l_hip_yaw"'),
                   None, r"legs.left.hip_roll: joint 'l_hip_yaw' is already given as "
                         r"legs.left.hip_yaw"),
    "not_a_chain": (lambda t: t.replace('knee = "l_knee"', 'knee = "TMP"')
                    .replace('hip_pitch = "l_hip_pitch"', 'hip_pitch = "l_knee"')
                    .replace('knee = "TMP"', 'knee = "l_hip_pitch"'), None,
                    r"legs.left: the joints are not the chain from the floating base"),
    "no_free_joint": (None, lambda x: x.replace('<freejoint name="root"/>', ""),
                      r"no floating base"),
    "missing_key": (lambda t: t.replace('imu = "imu"\n', ""), None,
                    r"missing required key\(s\) \['imu'\]"),
    "unknown_key": (lambda t: t.replace('imu = "imu"', 'imu = "imu"\ncolour = "red"'), None,
                    r"unknown key\(s\) \['colour'\]"),
    "no_servo": (None, lambda x: "\n".join(line for line in x.splitlines()
                                           if 'name="l_knee" joint="l_knee"' not in line),
                 r"legs.left.knee: joint 'l_knee' has no position actuator"),
    "unknown_foot": (lambda t: t.replace('foot = "r_foot"', 'foot = "r_fot"'), None,
                     r"legs.right.foot: no body named 'r_fot'.*close matches"),
    "unknown_imu": (lambda t: t.replace('imu = "imu"', 'imu = "imux"'), None,
                    r"imu: no body or site named 'imux'"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_descriptions_are_refused_naming_the_key(case, second_file, tmp_path):
    toml, xml, message = BAD[case]
    path = tmp_path / "nowhere.toml" if case == "missing_file" else _edit(
        tmp_path / case, second_file, toml, xml)
    with pytest.raises(RobotFileError, match=message):
        load_robot(path)


def test_stand_cli_prints_measurements(second_file, capsys):
    from tkujax.cli import main

    assert main(["stand", "--robot", str(second_file), "--seconds", "1"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["stand"]["stood"] and out["ik"] == "analytic"
    assert out["geometry"]["thigh_length_m"] == pytest.approx(GENERATED_SECOND.thigh_length_m)


def test_example_file_parses_structure(monkeypatch):
    found = _menagerie()
    monkeypatch.setenv("TKUJAX_MENAGERIE", str(found or REPO))
    if found is None:
        with pytest.raises(RobotFileError, match="mjcf: model file not found"):
            load_description(REPO / "specs" / "robots" / "op3.toml")
    else:
        desc = load_description(REPO / "specs" / "robots" / "op3.toml")
        assert desc.left.joint("knee") == "l_knee" and desc.right.foot == "r_ank_roll_link"


@needs_op3
def test_op3_parses_and_geometry_is_plausible(op3):
    assert op3.model.nsensor == 10          # tkujax's gyro, accelerometer and 8 touch sensors
    geo = measure_geometry(op3, stand_pose(op3).qpos)
    assert 0.09 <= geo.thigh_length_m <= 0.11 + 1e-3 and 0.09 <= geo.calf_length_m <= 0.11 + 1e-3
    assert 0.2 <= geo.com_height_m <= 0.3
    assert geo.hip_offset_y_m == pytest.approx(0.035, abs=1e-6)
    ok, why = analytic_ik_applies(op3)
    assert not ok and "reversed" in why


@needs_op3
def test_op3_ik_round_trip(op3):
    err_p, err_r = _round_trip(op3, 10, 1)
    assert err_p < 1e-4 and err_r < math.radians(0.1)


@needs_op3
def test_op3_stands_5s(op3):
    result = check_stand(op3, stand_pose(op3), 5.0)
    assert result.stood, result.why
    assert result.com_drift_m < 0.02 and abs(result.pitch_end_deg) < 5


def test_init_robot_index_matches_tkux(tkux):
    from tkujax.robot.simsetup import init_robot
    from tkujax.sim.setup import model_index

    host, device, index, state = init_robot(tkux, settle_s=0.2)
    ref = model_index()
    ref_host = load_robot(tkux.description).model
    assert np.array_equal(index.leg_actuators, ref.leg_actuators)
    assert np.array_equal(index.stand_ctrl, ref.stand_ctrl)
    names = lambda m, ids: sorted(m.geom(int(g)).name for g in ids)  # noqa: E731
    assert names(host, index.sphere_geoms) == names(ref_host, ref.sphere_geoms)
    assert names(host, index.box_geoms) == names(ref_host, ref.box_geoms)
    for mine, theirs in zip(index.ankle_sites, ("r_ankle", "l_ankle")):
        assert np.allclose(host.site_pos[mine], host.site(theirs).pos)
    assert state.qpos.shape == (host.nq,) and float(state.time) == 0.0
    assert device.nu == host.nu
