"""Robots from a user's own MuJoCo model: the robot file, its checks, the controller's geometry
read from the model, numeric leg IK and a standing pose (see docs/robots.md).

The Robot value every simulation takes (tkujax.sim.robot.Robot), from either constructor:

  builtin_robot(model_params)   TKU-X, its MJCF generated from ModelParams (None: the default)
  robot_from_file(path)   a robot file
  as_robot(x)             a Robot, ModelParams or None resolved to a Robot (the public edges)
"""

from tkujax.robot.robot_setup import robot_from_file
from tkujax.sim.robot import Robot, as_robot, builtin_robot

__all__ = ["Robot", "as_robot", "builtin_robot", "robot_from_file"]
