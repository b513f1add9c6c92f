"""Robots from a user's own MuJoCo model: the robot file, its checks, the controller's geometry
read from the model, numeric leg IK and a standing pose (see docs/robots.md)."""
