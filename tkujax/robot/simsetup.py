"""A robot file as the simulation's starting point: `init_robot(path)` -> SimSetup, the same
(host model, MJX model, ModelIndex, settled stand state) tuple as `tkujax.sim.setup.init()`.

It lives here, not in tkujax/sim/, because robot files are a layer above the simulator.
The index is the robot's: its leg actuators (right then left, in role order), its floating
base as the pushed body, tkujax's IMU and touch sensors, the ankle sites, the stand's targets,
and the fall test's geoms (tkujax.robot.fall_geoms). The IMU has no low-pass (TKU-X's is a
model of TKU-X's sensor).

For the closed loop use `tkujax.robot.robot_setup.robot_from_file`: it adds the leg map (the
controller's joint conventions to the robot's) and the controller's parameters. See docs/robots.md.
"""

from __future__ import annotations

from pathlib import Path

import jax
import mujoco
import numpy as np

from tkujax.robot.description import RobotDescription
from tkujax.robot.fall_geoms import fall_geoms
from tkujax.robot.loader import ACCEL, GYRO, RobotModel, load_robot
from tkujax.robot.stand import StandPose, stand_pose
from tkujax.sim.mjx_import import mjx
from tkujax.sim.setup import ModelIndex, SimSetup, fall_geom_fields, imu_indices


def robot_index(robot: RobotModel, pose: StandPose) -> ModelIndex:
    """The ModelIndex of a robot standing at `pose`."""
    model = robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = pose.qpos
    mujoco.mj_forward(model, data)
    fall = fall_geoms(robot, pose.qpos)
    adr = lambda n: int(model.sensor_adr[model.sensor(n).id])  # noqa: E731
    base = robot.root_body
    return ModelIndex(
        leg_actuators=robot.leg_actuators.reshape(-1), chest_body=base,
        chest_stand_z=float(data.xpos[base][2]), chest_stand_cos=float(data.xmat[base][8]),
        gyro_adr=adr(GYRO), accel_adr=adr(ACCEL),
        fsr_adr=np.array([adr(n) for n in robot.fsr_sensors]), fsr_sites=robot.fsr_sites,
        **fall_geom_fields(model, list(fall.primitives)),
        mesh_geoms=fall.point_geoms, mesh_points=fall.points,
        ankle_sites=tuple(int(s) for s in robot.ankle_sites), stand_ctrl=pose.ctrl.copy(),
        timestep_s=float(model.opt.timestep), **imu_indices(model, GYRO, ACCEL))


def settled_data(robot: RobotModel, pose: StandPose, settle_s: float) -> mujoco.MjData:
    """MuJoCo C state at `pose` after `settle_s` holding its targets, clock reset to 0."""
    model = robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = pose.qpos
    data.ctrl[:] = pose.ctrl
    mujoco.mj_forward(model, data)
    for _ in range(int(round(settle_s / model.opt.timestep))):
        mujoco.mj_step(model, data)
    data.time = 0.0
    mujoco.mj_forward(model, data)
    return data


def init_robot(robot: RobotDescription | RobotModel | str | Path,
               settle_s: float = 1.0) -> SimSetup:
    """SimSetup of a robot file (or a parsed description or a loaded robot), as `init()`."""
    if not isinstance(robot, RobotModel):
        robot = load_robot(robot)
    pose = stand_pose(robot)
    device = jax.local_devices()[0]
    data = settled_data(robot, pose, settle_s)
    return SimSetup(robot.model, mjx.put_model(robot.model, device=device),
                    robot_index(robot, pose), mjx.put_data(robot.model, data, device=device))
