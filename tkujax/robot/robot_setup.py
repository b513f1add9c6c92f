"""A robot file ready for the closed loop: `robot_from_file(path)` -> tkujax.sim.robot.Robot
(`robot_setup`, its older name, is the same function).

What it adds to `init_robot`'s SimSetup:

- the leg map: the controller writes TKU-X's joint conventions (axes z, x, y, y, y, x with the
  right-hand rule, zero = the straight leg, right leg first); each robot actuator gets
  sign x q + offset, the sign the joint's axis against TKU-X's (`RobotModel.axis_signs`), the
  offset making the controller's stand (feet at (0, -+d_y, -d_z) from the waist P_W) the
  robot's stand exactly. The actuators are addressed by id, in the controller's slot order, so
  any actuator order works (OP3 lists its left leg first). The offsets absorb what differs
  from TKU-X at the stand (the hip centre 28.5 mm below OP3's base origin does not enter: the
  IK works from the hip centre; the computed stand's fore-aft foot shift and lean do): exact
  at the stand, to first order around it (`tests/test_robot_loop.py` measures the round trip);
- the fall test's mesh geoms (collision mode "model"; "primitives" makes them boxes): every
  non-foot collision mesh that can touch the floor, with its
  vertices (the lowest vertex is the geom's lowest point);
- MuJoCo's eulerdamp off (the C rollout chains the solver's warm start through
  qvel' = qvel + dt qacc, which holds only without it; MJX and C then step the same Euler);
- the controller: the one the robot file names, else a conservative default
  (tkujax.robot.own_controller) on `controller_params_for` the geometry at the stand, with the
  standing lean read from the stand settled `SETTLE_S` in MuJoCo C (OP3: -2.3 deg); the leg
  map is built on those scaled defaults.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import re
from pathlib import Path

import jax
import mujoco
import numpy as np

from tkujax.control.controller import stand_leg_targets
from tkujax.control.controller_params import ControllerParams
from tkujax.robot.description import RobotFileError, load_description
from tkujax.robot.geometry import (RobotGeometry, base_pitch_roll, controller_params_for,
                                   measure_geometry)
from tkujax.robot.leg_map import leg_chain, sign_map
from tkujax.robot.loader import RobotModel, load_robot
from tkujax.robot.model_files import model_files, model_files_digest
from tkujax.robot.own_controller import robot_controller, walking_controller
from tkujax.robot.simsetup import robot_index, settled_data
from tkujax.robot.stand import stand_pose
from tkujax.robot.support import com_margins
from tkujax.robot.walk_defaults import walk_defaults
from tkujax.sim.mjx_import import mjx
from tkujax.sim.robot import Robot
from tkujax.sim.setup import SETTLE_S, ModelIndex, SimSetup


def _without_controller(text: bytes) -> bytes:
    """The robot file without its `controller = ...` and `walk_controller = ...` lines: naming a
    controller is not another robot (the controller's values enter a sweep's hash as its
    parameters)."""
    return re.sub(rb"(?m)^[ \t]*(?:walk_)?controller[ \t]*=.*\n?", b"", text)


def file_digest(path: str | Path) -> str:
    """sha256 of a robot file (without its controller line) and of the model file it names
    (hex), of the collision mode when it is not "model" (the default changes the model the
    file gives), and of every file the model includes and every asset it references, by
    content (`tkujax.robot.model_files`)."""
    desc = load_description(path)
    h = hashlib.sha256(_without_controller(Path(path).read_bytes()))
    h.update(desc.mjcf_path.read_bytes())
    if desc.collision_mode != "model":
        h.update(f"collision mode {desc.collision_mode}".encode())
    if model_files(desc.mjcf_path):   # included files and assets, by content
        h.update(model_files_digest(desc.mjcf_path).encode())
    return h.hexdigest()


def leg_map(robot: RobotModel, pose, params: ControllerParams) -> dict:
    """ModelIndex's leg map fields taking the controller's targets (slot order: right then
    left, roles in order) to the robot's leg actuators, the controller's stand to the pose's
    (tkujax.robot.leg_map: signs for TKU-X's chain, the robot's IK for any other)."""
    q_stand = np.asarray(stand_leg_targets(params), np.float64)
    if robot.joint_for_joint:
        signs, offsets = sign_map(robot, pose.ctrl, q_stand)
        return dict(leg_signs=signs, leg_offsets=offsets)
    chain = leg_chain(robot, pose.qpos, pose.ctrl, q_stand, float(params.thigh_length),
                      float(params.calf_length))
    return dict(leg_matrix=chain.matrix, leg_offsets=chain.offsets, leg_chain=chain)


def _check_layout(robot: RobotModel) -> None:
    """The loop reads the base's pose from qpos[0:7] and the CoM from body 1's subtree."""
    model = robot.model
    if robot.root_body != 1 or model.jnt_qposadr[model.body_jntadr[1]] != 0:
        raise RobotFileError("mjcf: the closed loop needs the floating base as the model's "
                             "first body, its free joint first in qpos")


def closed_loop_index(robot: RobotModel, pose, params: ControllerParams) -> ModelIndex:
    """robot_index with the leg map."""
    return dataclasses.replace(robot_index(robot, pose), **leg_map(robot, pose, params))


def settled_geometry(robot: RobotModel, pose, data: mujoco.MjData) -> RobotGeometry:
    """The stand's geometry, its lean read from the settled stand `data` (what the robot's
    controller defaults are scaled from)."""
    geo = measure_geometry(robot, pose.qpos)
    adr = int(robot.model.jnt_qposadr[robot.model.body_jntadr[robot.root_body]])
    lean = base_pitch_roll(np.asarray(data.qpos[adr + 3:adr + 7]))[0]
    return dataclasses.replace(geo, stand_lean_rad=lean)


def robot_gait(robot: RobotModel, data: mujoco.MjData,
               scaled: ControllerParams) -> tuple[tuple[str, float], ...]:
    """The robot's gait (`Robot.gait`): its defaults from the settled stand `data` and its
    scaled controller defaults (`walk_defaults`), then its file's [walk] table (later wins)."""
    return walk_defaults(com_margins(robot, data), scaled) + robot.description.walk


def _params(robot: RobotModel, pose, data: mujoco.MjData) -> ControllerParams:
    """controller_params_for the settled stand's geometry."""
    return controller_params_for(settled_geometry(robot, pose, data))


@functools.lru_cache(maxsize=8)
def _robot_from_file(path: str, digest: str, controller: str) -> Robot:
    robot = load_robot(path)
    _check_layout(robot)
    pose = stand_pose(robot)
    data = settled_data(robot, pose, SETTLE_S)
    scaled = _params(robot, pose, data)
    params, schedule, controller = robot_controller(robot.description, scaled)
    walk_params, walk_source = walking_controller(robot.description, params, controller)
    device = jax.local_devices()[0]
    setup = SimSetup(robot.model, mjx.put_model(robot.model, device=device),
                     closed_loop_index(robot, pose, scaled),
                     mjx.put_data(robot.model, data, device=device))
    return Robot(setup=setup, settled=data, params=params, name=robot.name, digest=digest,
                      source=path, controller=controller, defaults=scaled,
                      walk_params=walk_params, walk_controller=walk_source,
                      gait=robot_gait(robot, data, scaled), schedule=schedule)


def robot_from_file(path: str | Path) -> Robot:
    """The Robot of a robot file (cached per file path and content)."""
    path = str(Path(path).resolve())
    return _robot_from_file(path, file_digest(path), controller_digest(path))


robot_setup = robot_from_file   # the older name


def controller_digest(path: str | Path) -> str:
    """sha256 of the robot file's controller lines and of the files they name ("" without
    any): with file_digest, what a loaded Robot depends on."""
    desc = load_description(path)
    paths = (desc.controller_path, desc.walk_controller_path)
    if paths == (None, None):
        return ""
    h = hashlib.sha256()
    for p in paths:
        h.update(b"-" if p is None else str(p).encode() + p.read_bytes())
    return h.hexdigest()
