"""Which geoms a robot file's fall test reads (tkujax.robot.fall_geoms), on generated robots.

- A shin mesh that the "primitives" collision mode boxes is read by its own vertices: at the
  stand and in bent poses, the fall test's lowest point is the mesh's lowest vertex by MuJoCo's
  kinematics of the mesh geom (kept in the model for its mass and looks), where the box reaches
  lower; and the closed loop's reading on MJX agrees.
- A geom within STAND_CLEARANCE_MIN_M of the floor at the stand is left out and named; one
  higher up is read.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.robot.fall_geoms import STAND_CLEARANCE_MIN_M, fall_geoms
from tkujax.robot.loader import load_robot
from tkujax.robot.simsetup import robot_index
from tkujax.robot.stand import stand_pose
from tkujax.sim.closed_loop import lowest_body_point
from tkujax.sim.mjx_import import mjx

# A lumpy mesh (an off-centre, tilted point cloud) so that its box and its hull differ.
_RNG = np.random.default_rng(3)
_MESH_VERTS = (_RNG.normal(size=(60, 3)) * [0.012, 0.018, 0.045]
               @ np.array([[1.0, 0.0, 0.0], [0.0, 0.9, -0.44], [0.0, 0.44, 0.9]]))


def _edit(toml, edit) -> None:
    """Apply `edit` to the generated robot's MJCF, with the floor colliding by contype (the
    generated floor collides through <pair>s only)."""
    xml = toml.with_suffix(".xml")
    spec = mujoco.MjSpec.from_file(str(xml))
    edit(spec)
    floor = spec.geom("floor")
    floor.contype, floor.conaffinity = 1, 1
    xml.write_text(spec.to_xml())


def _robot_with_shin_mesh(folder):
    toml = write_generated_robot(folder, GENERATED_SECOND, name="mesh", keyframe=False)

    def add(spec):
        spec.add_mesh(name="lump", uservert=_MESH_VERTS.reshape(-1).tolist())
        spec.body("r_shin").add_geom(name="shin_lump", type=mujoco.mjtGeom.mjGEOM_MESH,
                                     meshname="lump", pos=[0.01, 0.0, -0.04], mass=0.0, density=0.0,
                                     contype=1, conaffinity=1)
    _edit(toml, add)
    return toml


def _mesh_low(model, qpos, g) -> float:
    """The lowest vertex of mesh geom g by MuJoCo's kinematics."""
    d = mujoco.MjData(model)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(model, d)
    m = model.geom_dataid[g]
    verts = model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]]
    return float((d.geom_xpos[g] + verts @ d.geom_xmat[g].reshape(3, 3).T)[:, 2].min())


def test_a_boxed_mesh_is_read_by_its_own_vertices(tmp_path):
    robot = load_robot(_robot_with_shin_mesh(tmp_path))
    model = robot.model
    mesh, box = model.geom("shin_lump").id, model.geom("shin_lump_tkujax_box").id
    assert model.geom_contype[mesh] == 0 and model.geom_type[box] == mujoco.mjtGeom.mjGEOM_BOX
    pose = stand_pose(robot)
    fall = fall_geoms(robot, pose.qpos)
    assert box in fall.point_geoms and mesh not in fall.point_geoms + fall.primitives
    points = fall.points[fall.point_geoms.index(box)]
    knee = model.jnt_qposadr[robot.leg_joints[0][robot.column("knee")]]
    for bend in (0.0, 0.6, -0.4):
        qpos = pose.qpos.copy()
        qpos[knee] += bend
        d = mujoco.MjData(model)
        d.qpos[:] = qpos
        mujoco.mj_kinematics(model, d)
        read = float((d.geom_xpos[box][2] + points @ d.geom_xmat[box].reshape(3, 3)[2]).min())
        np.testing.assert_allclose(read, _mesh_low(model, qpos, mesh), atol=1e-9)
        box_low = d.geom_xpos[box][2] - np.abs(d.geom_xmat[box].reshape(3, 3)[2]) @ \
            model.geom_size[box]
        assert box_low < read - 1e-3          # the box reaches lower than the mesh
    idx = robot_index(robot, pose)
    d = mujoco.MjData(model)
    d.qpos[:] = pose.qpos
    mujoco.mj_forward(model, d)
    lows = [_mesh_low(model, pose.qpos, mesh)] + [
        float(((d.xpos[b] + _corners(model, g) @ d.xmat[b].reshape(3, 3).T)[:, 2]).min())
        for g in idx.box_geoms for b in [model.geom_bodyid[g]]]
    np.testing.assert_allclose(float(lowest_body_point(idx, mjx.put_data(model, d))),
                               min(lows), atol=1e-6)


def _corners(model, g) -> np.ndarray:
    """Box geom g's corners in its body's frame."""
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[g])
    return (signs * model.geom_size[g]) @ rot.reshape(3, 3).T + model.geom_pos[g]


@pytest.mark.parametrize("height_m, left_out", [(0.003, True), (0.05, False)])
def test_a_geom_at_the_floor_at_the_stand_is_left_out(tmp_path, height_m, left_out):
    """A sphere on the shin, its lowest point `height_m` above the floor at the stand."""
    toml = write_generated_robot(tmp_path, GENERATED_SECOND, name="low", keyframe=False)
    _edit(toml, lambda spec: None)
    probe = load_robot(toml)
    d = mujoco.MjData(probe.model)
    d.qpos[:] = stand_pose(probe).qpos
    mujoco.mj_kinematics(probe.model, d)
    shin = probe.model.body("r_shin").id
    radius = 0.01
    world = d.xpos[shin].copy()
    world[2] = height_m + radius
    local = d.xmat[shin].reshape(3, 3).T @ (world - d.xpos[shin])
    _edit(toml, lambda spec: spec.body("r_shin").add_geom(
        name="shin_guard", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0],
        pos=local.tolist(), mass=0.0, density=0.0, contype=1, conaffinity=1))
    robot = load_robot(toml)
    fall = fall_geoms(robot, stand_pose(robot).qpos)
    guard = robot.model.geom("shin_guard").id
    names = [name for name, _ in fall.left_out]
    assert ("shin_guard" in names) == left_out
    assert (guard in fall.primitives) == (not left_out)
    if left_out:
        clearance = dict(fall.left_out)["shin_guard"]
        np.testing.assert_allclose(clearance, height_m, atol=1e-4)
        assert clearance < STAND_CLEARANCE_MIN_M


def test_a_robot_files_sweep_records_the_fall_tests_rule(tmp_path):
    """A robot file's sweep hash holds the fall test's rule (a sweep run with the box reading
    is another sweep, never resumed into one with the mesh reading); TKU-X's does not."""
    from tkujax.control.controller_params import ControllerParams
    from tkujax.dialects.sweep_spec import parse_spec
    from tkujax.robot.fall_geoms import FALL_TEST_RULE
    from tkujax.robot.robot_setup import robot_setup
    from tkujax.sweeps.sweep_hash import INPUT_NAMES, hash_parts

    spec = parse_spec({"sweep": {"name": "t"}, "push": {"grid": {"impulse_ns": [0.3]}}})
    robot = robot_setup(write_generated_robot(tmp_path, GENERATED_SECOND, name="r"))
    parts = hash_parts(spec, robot.params, robot)
    assert parts["fall_test"] == FALL_TEST_RULE and "fall_test" in INPUT_NAMES
    assert "fall_test" not in hash_parts(spec, ControllerParams.paper(), None)
