"""A robot file's [walk] table: the robot's gait (lift, sway, step period, double support and
the walking recovery's gains) for `tkujax walk` and for [walk] sweeps, checked at the edge and
overridden by the command line and the sweep spec."""

import json

import pytest

from tkujax.cli import main
from tkujax.control.controller_params import ControllerParams
from tkujax.dialects.walk_table import parse_walk, resolve_walk
from tkujax.robot.builtin import write_generated_robot
from tkujax.robot.description import load_description
from tkujax.robot.file_checks import RobotFileError
from tkujax.walking.walk import walker

GAIT = {"lift_m": 0.02, "sway_m": 0.02, "step_period_s": 0.36, "double_support_ratio": 0.3,
        "recovery_forward_gain": 0.0}


def _with_walk(folder, table: str):
    toml = write_generated_robot(folder, name="gen")
    toml.write_text(toml.read_text() + "\n[walk]\n" + table + "\n")
    return toml


@pytest.fixture(scope="module")
def robot_file(tmp_path_factory):
    return _with_walk(tmp_path_factory.mktemp("walkrobot"),
                      "\n".join(f"{k} = {v}" for k, v in GAIT.items()))


@pytest.mark.parametrize("table, message", [
    ("lift_m = 0.3", r"walk\.lift_m: expected a number in \[0, 0\.1\] m, got 0\.3"),
    ("sway_m = -0.3", r"walk\.sway_m: expected a number in \[-0\.25, 0\.25\] m"),
    ("step_period_s = \"fast\"", r"walk\.step_period_s: expected a number"),
    ("stride_m = 0.1", r"stride_m"),
])
def test_a_bad_walk_table_is_refused_naming_the_key(tmp_path, table, message):
    with pytest.raises(RobotFileError, match=message):
        load_description(_with_walk(tmp_path, table))


def test_the_robot_gait_reaches_the_walk_and_the_spec_wins_over_it(robot_file):
    who = walker(str(robot_file))
    # The file's table over the defaults from the stand (tkujax.robot.walk_defaults).
    assert set(who.gait) == set(GAIT) | {"com_shift_m"}
    assert {k: who.gait[k] for k in GAIT} == pytest.approx(GAIT)
    unset = parse_walk({"walk": {"speed_mps": 0.1}})
    command = resolve_walk(unset, who.gait_params, who.gait).command()
    for key, value in GAIT.items():
        assert float(getattr(command, key)) == pytest.approx(value, abs=1e-7), key
    given = parse_walk({"walk": {"step_period_s": 0.4, "recovery_forward_gain": 1.0}})
    command = resolve_walk(given, who.gait_params, who.gait).command()
    assert float(command.step_period_s) == pytest.approx(0.4)
    assert float(command.recovery_forward_gain) == 1.0
    assert float(command.lift_m) == pytest.approx(GAIT["lift_m"])
    # Without a table (TKU-X), the scaled defaults and gains of 1.
    paper = resolve_walk(unset, ControllerParams.paper()).command()
    assert float(paper.recovery_forward_gain) == 1.0
    assert float(paper.lift_m) == pytest.approx(ControllerParams.paper().lift_height)


def test_tkujax_walk_takes_the_robot_gait_and_the_command_line_over_it(robot_file, capsys):
    main(["walk", "--robot", str(robot_file), "--seconds", "0.6", "--speed-mps", "0",
          "--sway-m", "0.01"])
    command = json.loads(capsys.readouterr().out)["command"]
    assert command["lift_m"] == pytest.approx(GAIT["lift_m"])
    assert command["step_period_s"] == pytest.approx(GAIT["step_period_s"])
    assert command["sway_m"] == pytest.approx(0.01)


def test_tkujax_stand_prints_the_robot_gait(robot_file, capsys):
    main(["stand", "--robot", str(robot_file), "--seconds", "0.2"])
    out = json.loads(capsys.readouterr().out)
    gait = out["walk_gait"]
    shift = walker(str(robot_file)).gait["com_shift_m"]
    assert gait == pytest.approx(GAIT | {"com_shift_m": shift})
    # The margins printed beside it are those the shift was computed from (walk_defaults).
    margins = out["walk_gait_com_margin_m"]
    assert shift == pytest.approx(round(0.5 * (margins["front_m"] - margins["back_m"]), 4),
                                  abs=1e-4)
