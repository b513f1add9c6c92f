"""Humanoids from unitreerobotics/unitree_mujoco, read as a new user would, from the robot files in
specs/robots/: G1 (hips pitch-roll-yaw, a waist), H1 (five-joint legs), H1-2 (hips yaw-pitch-roll)
and R1 (a tilted hip-pitch axis), all with <motor> legs replaced by [servo]. Each stands on
MuJoCo C, and each file names the controller `tkujax tune --robot` wrote for it.

The models come from a checkout of unitree_mujoco (TKUJAX_UNITREE, or ../unitree_mujoco beside
the repository); the tests skip without one.
"""

import json
import os
from pathlib import Path

import pytest

from tkujax.cli import main
from tkujax.robot.robot_setup import robot_setup

REPO = Path(__file__).resolve().parents[1]
MODELS = {"g1": "g1/scene_23dof.xml", "h1": "h1/scene.xml", "h1_2": "h1_2/scene.xml",
          "r1": "r1/scene.xml"}


def _checkout() -> Path:
    env = os.environ.get("TKUJAX_UNITREE")
    return Path(env) if env else REPO.parent / "unitree_mujoco"


def _robot_file(name: str) -> Path:
    if not (_checkout() / "unitree_robots" / MODELS[name]).is_file():
        pytest.skip("no unitree_mujoco checkout (TKUJAX_UNITREE)")
    return REPO / "specs" / "robots" / f"{name}.toml"


@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_robot_stands_on_its_servos(name, capsys):
    robot_file = _robot_file(name)
    code = main(["stand", "--robot", str(robot_file), "--seconds", "2"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and not out["fell"] and out["stand"]["stood"]
    assert out["stand"]["sole_force_fraction"] > 0.95      # on its soles, nothing else
    assert out["ik"] == "numeric"                          # none of them is TKU-X's chain


@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_tuned_controller_is_the_robots(name):
    robot = robot_setup(_robot_file(name))
    assert robot.controller == f"file {name}_controller.json"
