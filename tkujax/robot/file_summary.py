"""`tkujax stand --robot FILE`: what tkujax reads and measures on a robot file's model."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from tkujax.robot.fall_geoms import STAND_CLEARANCE_MIN_M, fall_geoms
from tkujax.robot.geometry import scaled_defaults
from tkujax.robot.ik_numeric import analytic_ik_applies
from tkujax.robot.loader import LEG_ORDER, RobotModel, load_robot
from tkujax.robot.own_controller import CONSERVATIVE_SOURCE
from tkujax.robot.robot_setup import robot_gait, settled_geometry
from tkujax.robot.simsetup import settled_data
from tkujax.robot.stand import check_stand, stand_pose
from tkujax.robot.support import com_margins
from tkujax.sim.setup import SETTLE_S

SCALED_FIELDS = ("step_period", "lift_height", "standing_lean", "eps_forward", "eps_backward",
                 "cp_trigger_forward_m", "cp_trigger_backward_m", "cp_trigger_lateral_m")


def robot_stand_summary(path: str | Path, seconds: float = 5.0) -> dict:
    """Load and check a robot file, make its stand, hold it `seconds` in MuJoCo C; the
    geometry, the controller's scaled defaults, which IK applies, and the stand's measurements."""
    if not (0 < seconds <= 60):
        raise ValueError(f"seconds must be in (0, 60], got {seconds!r}")
    robot = load_robot(path)
    pose = stand_pose(robot)
    # The lean the sweeps' controller takes: the settled stand's, not the pose's.
    settled = settled_data(robot, pose, SETTLE_S)
    geo = settled_geometry(robot, pose, settled)
    params, clamped = scaled_defaults(geo)
    gait = dict(robot_gait(robot, settled, params))
    analytic, why = analytic_ik_applies(robot)
    result = check_stand(robot, pose, seconds)
    def rounded(v):
        if isinstance(v, dict):          # the stand's CoM margins
            return {k: rounded(x) for k, x in v.items()}
        return round(v, 6) if isinstance(v, float) else v
    return dict(
        robot=robot.name, mjcf=str(robot.description.mjcf_path), engine="mujoco",
        stand_source=pose.source,
        geometry={k: (tuple(map(rounded, v)) if isinstance(v, tuple) else rounded(v))
                  for k, v in dataclasses.asdict(geo).items()},
        stand_lean_deg=round(math.degrees(geo.stand_lean_rad), 3),
        controller_defaults={k: round(float(getattr(params, k)), 6) for k in SCALED_FIELDS},
        clamped_defaults=list(clamped),
        controller=(f"file {robot.description.controller_path.name}"
                    if robot.description.controller_path else CONSERVATIVE_SOURCE),
        walk_controller=(f"file {robot.description.walk_controller_path.name}"
                         if robot.description.walk_controller_path else "the controller"),
        walk_gait=gait or "the scaled defaults",
        # The margins the gait's defaults read: the stand after SETTLE_S, as the simulations
        # start from it (`stand.com_margin_m` below is after the longer hold of `seconds`).
        walk_gait_com_margin_m=rounded(com_margins(robot, settled)),
        servos=servo_summary(robot),
        fall_test=fall_test_summary(robot, pose.qpos),
        ik="analytic" if analytic else "numeric", ik_reason=why,
        stand={k: rounded(v) for k, v in result.as_dict().items()},
        fell=not result.stood)


def fall_test_summary(robot: RobotModel, stand_qpos) -> dict:
    """The geoms the fall test reads, and those it leaves out as too near the floor at the
    stand (tkujax.robot.fall_geoms)."""
    fall = fall_geoms(robot, stand_qpos)
    return dict(geoms_read=len(fall.primitives) + len(fall.point_geoms),
                meshes_read_by_vertices=len(fall.point_geoms),
                left_out={name: f"{1e3 * z:.1f} mm above the floor at the stand (under "
                          f"{1e3 * STAND_CLEARANCE_MIN_M:g} mm)" for name, z in fall.left_out})


def servo_summary(robot: RobotModel) -> dict:
    """Each leg joint's servo: kp (N m/rad), kv (N m s/rad), force limit (N m, None: none)."""
    model, out = robot.model, {}
    for i, side in enumerate(LEG_ORDER):
        for k, role in enumerate(robot.roles):
            a = int(robot.leg_actuators[i, k])
            limit = (round(float(abs(model.actuator_forcerange[a]).max()), 3)
                     if model.actuator_forcelimited[a] else None)
            out[f"legs.{side}.{role}"] = dict(kp=round(float(model.actuator_gainprm[a, 0]), 3),
                                              kv=round(float(-model.actuator_biasprm[a, 2]), 3),
                                              force_limit=limit)
    return out
