"""`[collision] floor = "feet"` (tkujax.robot.collision.feet_only): the floor touches the feet
only, the fall test still reads every body.

On a generated robot with a colliding shin: the shin's floor contact is gone and the feet's kept,
while the fall test's geoms are the same; bad values are refused naming the key. On OP3
(skipped without the shared models): MJX's contacts per step drop, and a MuJoCo C push set
falls exactly as with every body colliding (the fall test decides a fall before a body other
than a foot reaches the floor).
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
import pytest

from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.robot.description import RobotFileError, load_description
from tkujax.robot.loader import load_robot
from tkujax.robot.fall_geoms import floor_geoms

from test_robot_file import REPO, needs_op3


def _robot_with_shin(folder):
    """A generated robot whose right shin carries a box colliding with a dynamic floor."""
    toml = write_generated_robot(folder, GENERATED_SECOND, name="shin", keyframe=False)
    xml = toml.with_suffix(".xml")
    spec = mujoco.MjSpec.from_file(str(xml))
    spec.body("r_shin").add_geom(name="r_shin_box", type=mujoco.mjtGeom.mjGEOM_BOX,
                                 size=[0.02, 0.02, 0.04], contype=1, conaffinity=1, mass=0.0)
    floor = spec.geom("floor")
    floor.contype, floor.conaffinity = 1, 1
    xml.write_text(spec.to_xml())
    return toml


def _load(path, floor: str):
    return load_robot(dataclasses.replace(load_description(path), floor_contacts=floor))


def _floor_contacts(model, lowered_m: float) -> set[str]:
    """Bodies touching the world with the base lowered by lowered_m from the model's qpos0."""
    data = mujoco.MjData(model)
    data.qpos[2] -= lowered_m
    mujoco.mj_forward(model, data)
    out = set()
    for c in data.contact[:data.ncon]:
        bodies = {int(model.geom_bodyid[c.geom1]), int(model.geom_bodyid[c.geom2])}
        if 0 in bodies:
            out |= {model.body(b).name for b in bodies - {0}}
    return out


def test_the_floor_touches_the_feet_only_and_the_fall_test_reads_every_body(tmp_path):
    toml = _robot_with_shin(tmp_path)
    every, feet = _load(toml, "all"), _load(toml, "feet")
    assert load_description(toml).floor_contacts == "all"
    shin = every.model.body("r_shin").id
    lowered = float(every.model.body_pos[1][2])       # deep enough for the shin to touch
    assert "r_shin" in _floor_contacts(every.model, lowered)
    touching = _floor_contacts(feet.model, lowered)
    assert "r_shin" not in touching and touching <= {"r_foot", "l_foot"} and touching
    shin_geoms = lambda r: [g for g in floor_geoms(r) if r.model.geom_bodyid[g] == shin]  # noqa: E731
    assert shin_geoms(feet) == shin_geoms(every) and shin_geoms(every)
    np.testing.assert_array_equal(floor_geoms(feet), floor_geoms(every))


def test_a_bad_floor_value_is_refused_naming_the_key(tmp_path):
    toml = write_generated_robot(tmp_path, GENERATED_SECOND, name="bad", keyframe=False)
    toml.write_text(toml.read_text() + '\n[collision]\nfloor = "hands"\n')
    with pytest.raises(RobotFileError, match=r"collision\.floor: expected one of \['all', "
                                             r"'feet'\], got 'hands'"):
        load_description(toml)


@needs_op3
def test_op3_feet_only_contacts_fall_as_every_body(tmp_path):
    """OP3 (MuJoCo C, control off and on): 10 pushes from behind and the side across the
    fall boundary give the same falls with the floor touching only the feet."""
    from tkujax.sim.push import make_push, stack_pushes
    from tkujax.sim.options import RolloutConfig
    from tkujax.sim.rollout_mujoco import simulate_mujoco
    from tkujax import robot_from_file

    source = REPO / "specs" / "robots" / "op3.toml"
    feet_file = source.parent / "_test_op3_feet.toml"
    feet_file.write_text(source.read_text() + '\n[collision]\nfloor = "feet"\n')
    try:
        robots = {"all": robot_from_file(source), "feet": robot_from_file(feet_file)}
    finally:
        feet_file.unlink()
    assert robots["feet"].setup.host_model.nexclude > robots["all"].setup.host_model.nexclude
    pushes = stack_pushes([make_push(j, az, height_m=0.262, onset_s=0.5)
                           for j in (0.8, 1.2, 1.6, 2.0, 2.4) for az in (0.0, 90.0)])
    fell = {}
    for name, robot in robots.items():
        out = []
        for enabled in (0.0, 1.0):
            _, outcomes = simulate_mujoco(pushes, np.full(10, enabled), robot.params,
                                          config=RolloutConfig(duration_s=2.0), robot=robot)
            out.append(np.asarray(outcomes.fell, bool))
        fell[name] = np.concatenate(out)
    assert fell["all"].any() and not fell["all"].all()
    np.testing.assert_array_equal(fell["feet"], fell["all"])
