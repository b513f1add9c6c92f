"""The settled CoM's margins in the support polygon (tkujax.robot.support), against the feet's
contact pads read from the model: TKU-X's generated robot stands on four sphere pads a foot."""

import mujoco
import numpy as np
import pytest

from tkujax.robot.builtin import write_generated_robot
from tkujax.robot.loader import load_robot
from tkujax.robot.stand import check_stand, stand_pose
from tkujax.robot.support import com_margins


@pytest.fixture(scope="module")
def standing(tmp_path_factory):
    robot = load_robot(write_generated_robot(tmp_path_factory.mktemp("robot"), name="gen"))
    result = check_stand(robot, stand_pose(robot), seconds=1.0)
    return robot, result


def test_margins_span_the_pads(standing):
    robot, result = standing
    assert result.stood
    m = result.com_margin_m
    model = robot.model
    pads = [np.array(model.geom_pos[g]) for g in sorted(robot.foot_geoms[0])]
    span_x = max(p[0] for p in pads) - min(p[0] for p in pads)
    assert m["front_m"] + m["back_m"] == pytest.approx(span_x, abs=2e-3)
    # Across both feet: the outer pads' distance, from where the feet stand.
    data = mujoco.MjData(model)
    data.qpos[:] = stand_pose(robot).qpos
    mujoco.mj_forward(model, data)
    outer = [float((data.geom_xpos[g])[1]) for side in robot.foot_geoms for g in side]
    assert m["left_m"] + m["right_m"] == pytest.approx(max(outer) - min(outer), abs=3e-3)
    assert 0 < m["least_m"] == pytest.approx(min(m["front_m"], m["back_m"], m["left_m"],
                                                 m["right_m"]), abs=1e-6)


def test_no_polygon_without_three_contacts(standing):
    robot, _ = standing
    data = mujoco.MjData(robot.model)          # nothing touches the floor before a step
    data.qpos[:] = stand_pose(robot).qpos
    data.qpos[2] += 0.5
    mujoco.mj_forward(robot.model, data)
    assert com_margins(robot, data) is None
