"""The robot file's collision modes (tkujax.robot.collision): colliding meshes as fitted boxes,
self-collisions off, the floor kept; checked against MuJoCo's own kinematics and collision
detection on the "model" mode, and MuJoCo C against MJX.

The generated second robot gets colliding meshes here (a shin mesh on each leg, reaching
across to the other one, and one inside a foot); OP3 runs when a Menagerie checkout is found."""

from __future__ import annotations

import dataclasses

import jax
import mujoco
import numpy as np
import pytest

from tkujax.robot.builtin import GENERATED_SECOND, write_generated_robot
from tkujax.robot.robot_setup import file_digest
from tkujax.robot.collision import BOX_SUFFIX, fit_box, mesh_vertices_in_body
from tkujax.robot.description import RobotFileError, load_description
from tkujax.robot.loader import geom_points, load_robot
from tkujax.sim.mjx_import import mjx

from test_robot_file import REPO, needs_op3

# A skewed convex hexahedron (m): no face is axis-aligned in its body's frame.
HEX = np.array([[-0.02, -0.015, -0.05], [0.025, -0.02, -0.045], [0.02, 0.02, -0.055],
                [-0.025, 0.015, -0.05], [-0.015, -0.02, 0.05], [0.02, -0.015, 0.055],
                [0.025, 0.02, 0.045], [-0.02, 0.02, 0.05]])


def _with_meshes(toml):
    """Give the robot at `toml` colliding meshes (shins reaching across, one in the right
    foot) and a floor that collides dynamically."""
    xml = toml.with_suffix(".xml")
    spec = mujoco.MjSpec.from_file(str(xml))
    spec.add_mesh(name="hex", uservert=HEX.reshape(-1).tolist())
    for side, y in (("r", 0.05), ("l", -0.05)):
        spec.body(f"{side}_shin").add_geom(
            name=f"{side}_shin_mesh", type=mujoco.mjtGeom.mjGEOM_MESH, meshname="hex",
            pos=[0, y, -0.05], quat=[0.96, 0.1, 0.2, 0.15], contype=1, conaffinity=1)
    spec.body("r_foot").add_geom(name="r_foot_mesh", type=mujoco.mjtGeom.mjGEOM_MESH,
                                 meshname="hex", pos=[0, 0, 0.0], contype=1, conaffinity=1,
                                 quat=[0.98, 0.0, 0.0, 0.2], mass=0.0)
    floor = spec.geom("floor")
    floor.contype, floor.conaffinity = 1, 1
    xml.write_text(spec.to_xml())
    return toml


@pytest.fixture(scope="module")
def meshed(tmp_path_factory):
    return _with_meshes(write_generated_robot(tmp_path_factory.mktemp("meshed"),
                                              GENERATED_SECOND, name="meshed", keyframe=False))


def _load(path, mode: str):
    return load_robot(dataclasses.replace(load_description(path), collision_mode=mode))


@pytest.fixture(scope="module")
def modes(meshed):
    return {mode: _load(meshed, mode) for mode in ("model", "primitives")}


def _geom(model, name: str) -> int:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, name)


def _contacts(model, qpos) -> set[tuple[str, str]]:
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    name = lambda g: model.body(model.geom_bodyid[g]).name  # noqa: E731
    return {tuple(sorted((name(c.geom1), name(c.geom2)))) for c in data.contact[:data.ncon]}


def test_default_mode_is_primitives_and_bad_modes_are_refused(meshed, tmp_path):
    assert load_description(meshed).collision_mode == "primitives"
    bad = tmp_path / "bad.toml"
    mjcf = f'mjcf = "{meshed.with_suffix(".xml")}"'
    bad.write_text(meshed.read_text().replace('mjcf = "meshed.xml"', mjcf)
                   + '\n[collision]\nmode = "convex"\n')
    with pytest.raises(RobotFileError, match=r"collision\.mode: expected one of"):
        load_description(bad)
    bad.write_text(bad.read_text().replace('mode = "convex"', 'shape = "box"'))
    with pytest.raises(RobotFileError, match=r"collision: unknown key"):
        load_description(bad)


def test_boxes_bound_the_meshes_in_world_coordinates(modes):
    """Every mesh vertex, placed by MuJoCo's kinematics of the "model" robot at a bent pose,
    lies in its box placed by the kinematics of the "primitives" robot; the feet's box is
    level in the foot's frame; the masses are unchanged."""
    model, prim = modes["model"].model, modes["primitives"].model
    qpos = modes["model"].model.qpos0.copy()
    qpos[7:] = np.random.default_rng(0).uniform(-0.3, 0.3, qpos.size - 7)
    datas = []
    for m in (model, prim):
        d = mujoco.MjData(m)
        d.qpos[:] = qpos
        mujoco.mj_kinematics(m, d)
        datas.append(d)
    for name in ("r_shin_mesh", "l_shin_mesh", "r_foot_mesh"):
        g, b = _geom(model, name), _geom(prim, name + BOX_SUFFIX)
        assert b >= 0 and prim.geom_type[b] == mujoco.mjtGeom.mjGEOM_BOX
        verts = mesh_vertices_in_body(model, g)
        body = model.geom_bodyid[g]
        world = datas[0].xpos[body] + verts @ datas[0].xmat[body].reshape(3, 3).T
        local = (world - datas[1].geom_xpos[b]) @ datas[1].geom_xmat[b].reshape(3, 3)
        assert (np.abs(local) <= prim.geom_size[b] + 1e-9).all()
        assert np.abs(local).max(axis=0) == pytest.approx(prim.geom_size[b], abs=1e-9)
        assert prim.geom_contype[_geom(prim, name)] == prim.geom_conaffinity[_geom(prim, name)] == 0
    foot_box = _geom(prim, "r_foot_mesh" + BOX_SUFFIX)
    np.testing.assert_allclose(np.abs(prim.geom_quat[foot_box]), [1, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(prim.body_mass, model.body_mass)
    np.testing.assert_allclose(prim.body_inertia, model.body_inertia)


def test_self_collisions_off_floor_kept(modes):
    """MuJoCo's collision detection: at the zero pose the two shin meshes overlap ("model"
    finds the contact, "primitives" none); lowered into the floor both find the shins' floor
    contacts."""
    model = modes["model"].model
    air = model.qpos0.copy()
    air[2] = 1.0
    assert ("l_shin", "r_shin") in _contacts(model, air)
    assert not _contacts(modes["primitives"].model, air)
    low = air.copy()
    low[2] = 0.12
    for robot in modes.values():
        found = _contacts(robot.model, low)
        assert ("r_shin", "world") in found and ("l_shin", "world") in found


def test_primitives_mujoco_c_matches_mjx(modes):
    """Set down 2 mm above the floor, moving forward, legs held straight (the feet's pairs and
    the boxes against the floor; eulerdamp off as in the closed loop): C and MJX agree."""
    robot = modes["primitives"]
    m = robot.model
    m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_EULERDAMP)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    sole = min((d.xpos[b] + geom_points(m, g) @ d.xmat[b].reshape(3, 3).T)[:, 2].min()
               for b, geoms in zip(robot.foot_bodies, robot.foot_geoms) for g in geoms)
    d.qpos[2] -= sole - 0.002
    d.qvel[0] = 0.2
    mujoco.mj_forward(m, d)
    mx, dx = mjx.put_model(m), mjx.put_data(m, d)
    step = jax.jit(lambda dx: jax.lax.fori_loop(0, 100, lambda _, x: mjx.step(mx, x), dx))
    qpos_mjx = np.asarray(step(dx).qpos)
    for _ in range(100):
        mujoco.mj_step(m, d)
    assert d.ncon > 0                                       # standing on the floor
    np.testing.assert_allclose(qpos_mjx, d.qpos, atol=2e-3)     # MJX in float32
    assert abs(float(d.qpos[0])) > 0.005                    # it moved


def test_digest_names_the_mode(meshed, tmp_path):
    model_file = tmp_path / "model.toml"
    model_file.write_text(meshed.read_text().replace(
        'mjcf = "meshed.xml"', f'mjcf = "{meshed.with_suffix(".xml")}"')
        + '\n[collision]\nmode = "model"\n')
    assert file_digest(model_file) != file_digest(meshed)


@needs_op3
def test_op3_primitives():
    """OP3: no colliding mesh is left; the feet keep their boxes; a box per collision mesh."""
    path = REPO / "specs" / "robots" / "op3.toml"
    prim, model = _load(path, "primitives").model, _load(path, "model").model
    colliding = lambda m: [g for g in range(m.ngeom)  # noqa: E731
                           if m.geom_contype[g] or m.geom_conaffinity[g]]
    meshes = [g for g in colliding(model) if model.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    assert len(meshes) > 20
    assert not [g for g in colliding(prim) if prim.geom_type[g] == mujoco.mjtGeom.mjGEOM_MESH]
    assert len(colliding(prim)) == len(colliding(model))
    for g in meshes:
        fit = fit_box(model, g)
        assert (fit.half_m > 0).all()
    np.testing.assert_allclose(prim.body_mass, model.body_mass)
