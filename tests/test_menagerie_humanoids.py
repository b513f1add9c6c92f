"""Two more of MuJoCo Menagerie's humanoids, read as a new user would, from the robot files in
specs/robots/: Fourier N1 (39.7 kg, the ankle's roll joint above its pitch joint) and PNDbotics
Adam Lite (58.2 kg, a three-joint waist), both hips pitch-roll-yaw with <motor> legs replaced
by [servo]. Each stands on MuJoCo C and survives gentle pushes with its conservative default
controller. The models come from TKUJAX_MENAGERIE; the tests skip without them.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from tkujax.cli import main

REPO = Path(__file__).resolve().parents[1]
MODELS = {"fourier_n1": "fourier_n1/scene.xml",
          "pndbotics_adam_lite": "pndbotics_adam_lite/scene.xml"}


def _robot_file(name: str) -> Path:
    env = os.environ.get("TKUJAX_MENAGERIE")
    models = Path(env) if env else REPO.parent / "shared" / "models"
    if not (models / MODELS[name]).is_file():
        pytest.skip(f"no Menagerie {name} (TKUJAX_MENAGERIE)")
    return REPO / "specs" / "robots" / f"{name}.toml"


@pytest.mark.parametrize("name", sorted(MODELS))
def test_the_robot_stands_and_survives_gentle_pushes(name, capsys, tmp_path):
    robot_file = _robot_file(name)
    assert main(["stand", "--robot", str(robot_file), "--seconds", "2"]) == 0
    stand = json.loads(capsys.readouterr().out)
    assert not stand["fell"] and stand["stand"]["stood"]
    assert stand["controller"].startswith("conservative default")
    out = tmp_path / "sweep"
    assert main(["sweep", str(REPO / "specs" / "sweep" / "tiny.toml"), "--robot",
                 str(robot_file), "--out", str(out), "--backend", "mujoco"]) == 0
    fell = [np.load(chunk)["fell"] for chunk in sorted(out.glob("chunk_*.npz"))]
    assert len(fell) == 2 and not np.concatenate(fell).any()
