"""MuJoCo Menagerie's Berkeley Humanoid from its robot file: a hip axis tilted 45° from the
vertical and a learning pipeline's servos (knee and ankles kp 1). Without the file's [servo]
it falls off its keyframe and `tkujax stand` names each leg joint's shortfall; with it, it
stands, and its file names the controller `tkujax tune --robot` wrote.

The model comes from a Menagerie checkout (TKUJAX_MENAGERIE, or the shared models folder
beside the repository); the tests skip without it.
"""

import json
import os
import re
from pathlib import Path

import pytest

from tkujax.cli import main
from tkujax.robot.robot_setup import robot_setup

REPO = Path(__file__).resolve().parents[1]
ROBOT_FILE = REPO / "specs" / "robots" / "berkeley_humanoid.toml"


def _model() -> Path:
    env = os.environ.get("TKUJAX_MENAGERIE")
    root = Path(env) if env else REPO.parent / "shared" / "models"
    model = root / "berkeley_humanoid" / "scene.xml"
    if not model.is_file():
        pytest.skip("no Menagerie berkeley_humanoid (TKUJAX_MENAGERIE)")
    return model


def test_it_stands_on_the_files_servos(capsys):
    _model()
    code = main(["stand", "--robot", str(ROBOT_FILE), "--seconds", "2"])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["stand"]["stood"] and out["ik"] == "numeric"
    robot = robot_setup(ROBOT_FILE)
    assert robot.controller == "file berkeley_humanoid_controller.json"
    assert robot.leg_chain is not None        # its tilted hip axes: its own IK, not signs


def test_its_own_servos_are_explained_per_leg_joint(tmp_path, capsys):
    model = _model()
    text = ROBOT_FILE.read_text()
    text = re.sub(r"\n\[servo\][^\[]*", "\n", text)           # the model's own kp 1 servos
    text = text.replace('mjcf = "${TKUJAX_MENAGERIE:-../../../shared/models}/berkeley_humanoid/'
                        'scene.xml"', f'mjcf = "{model}"')
    text = re.sub(r'\ncontroller = .*', "", text)
    bare = tmp_path / "bare.toml"
    bare.write_text(text)
    main(["stand", "--robot", str(bare), "--seconds", "2"])
    why = json.loads(capsys.readouterr().out)["stand"]["why"]
    assert "legs.left.knee: the stand needs" in why and "legs.right.knee: the stand needs" in why
    asked = [(float(kp), int(least)) for kp, least in re.findall(
        r"kp ([\d.]+) gives [^;]*; raise \[servo\] kp to at least (\d+)", why)]
    assert len(asked) >= 4
    assert all(least > kp for kp, least in asked)     # never asks for what it already has
