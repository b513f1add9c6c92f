"""The fall test's capsules and cylinders: their lowest points (`tkujax.sim.recording.axial_lows`)
against MuJoCo's own geometry (the signed distance to a floor plane, `mj_geomDistance`, and the
lowest vertex of a finely sampled surface), and a Booster T1 kneeling on its shanks judged
fallen on both backends, MJX's closed loop against MuJoCo C's (skipped without a Menagerie
checkout: TKUJAX_MENAGERIE or ../shared/models beside the repository)."""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from tkujax.sim.closed_loop import lowest_body_point
from tkujax.sim.metrics import FALL_BODY_CLEARANCE_M, FALL_PELVIS_HEIGHT_M
from tkujax.sim.mjx_import import mjx
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push
from tkujax.sim.recording import axial_lows
from tkujax.sim.rollout_mjx import simulate
from tkujax.sim.rollout_mujoco import simulate_mujoco
from tkujax.sim.setup import fall_geom_fields

from test_robot_chains import HAVE_T1
from test_robot_file import REPO

needs_t1 = pytest.mark.skipif(not HAVE_T1, reason="no Menagerie booster_t1 (TKUJAX_MENAGERIE)")

# Axes (unnormalised): vertical, horizontal, and tilted both ways; capsules and cylinders.
AXES = [(0, 0, 1), (1, 0, 0), (0.3, -0.2, 1.0), (1.0, 0.7, -0.4), (0.05, 0.0, -1.0)]
SIZES = [(0.03, 0.075), (0.05, 0.12), (0.02, 0.01), (0.08, 0.2), (0.04, 0.05)]


def _model(kind: str) -> str:
    geoms = []
    for i, (axis, (r, h)) in enumerate(zip(AXES, SIZES)):
        geoms.append(f'<body pos="{0.5 * i} 0 0.6"><geom name="g{i}" type="{kind}" '
                     f'size="{r} {h}" zaxis="{axis[0]} {axis[1]} {axis[2]}"/></body>')
    return ('<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>'
            + "".join(geoms) + "</worldbody></mujoco>")


def _sampled_low(d: mujoco.MjData, g: int, kind: str, r: float, h: float) -> float:
    """The lowest of a fine sample of the geom's surface (its own frame -> world)."""
    th = np.linspace(0.0, 2 * np.pi, 4001)
    if kind == "cylinder":       # rims and faces' rings
        rr = np.linspace(0.0, r, 101)[:, None]
        pts = [np.stack([rr * np.cos(th), rr * np.sin(th), np.full_like(rr * th, z)], -1)
               for z in (-h, h)]
    else:                        # the end hemispheres
        ph = np.linspace(0.0, np.pi, 2001)[:, None]
        pts = [np.stack([r * np.sin(ph) * np.cos(th), r * np.sin(ph) * np.sin(th),
                         z + r * np.cos(ph) + 0 * th], -1) for z in (-h, h)]
    local = np.concatenate([p.reshape(-1, 3) for p in pts])
    world = d.geom_xpos[g] + local @ d.geom_xmat[g].reshape(3, 3).T
    return float(world[:, 2].min())


@pytest.mark.parametrize("kind", ["capsule", "cylinder"])
def test_axial_lows_match_mujoco_geometry(kind):
    m = mujoco.MjModel.from_xml_string(_model(kind))
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    ids = np.arange(1, m.ngeom)
    fields = fall_geom_fields(m, ids)
    assert fields[f"{kind}_geoms"].tolist() == ids.tolist()
    sizes = fields[f"{kind}_sizes"]
    np.testing.assert_allclose(sizes, SIZES)
    capsule = kind == "capsule"
    low_np = axial_lows(np, d.geom_xpos[ids, 2], d.geom_xmat[ids, 8], sizes, capsule)
    low_jnp = axial_lows(jnp, jnp.asarray(d.geom_xpos[ids, 2]), jnp.asarray(d.geom_xmat[ids, 8]),
                         jnp.asarray(sizes), capsule)
    dist = np.array([mujoco.mj_geomDistance(m, d, 0, int(g), 2.0, None) for g in ids])
    sampled = np.array([_sampled_low(d, int(g), kind, *SIZES[i]) for i, g in enumerate(ids)])
    np.testing.assert_allclose(low_np, dist, atol=1e-9)
    np.testing.assert_allclose(low_np, sampled, atol=2e-5)
    np.testing.assert_allclose(np.asarray(low_jnp), low_np, atol=1e-6)


def test_axial_lows_gradient_finite_at_a_vertical_cylinder():
    import jax

    grad = jax.grad(lambda az: axial_lows(jnp, jnp.zeros(1), az, jnp.array([[0.05, 0.1]]),
                                          False)[0])(jnp.ones(1))
    assert np.isfinite(np.asarray(grad)).all()


@pytest.fixture(scope="module")
def kneeling_t1():
    """Booster T1 kneeling on its shanks (knees bent 1.6 rad, the shanks 1 mm above the floor
    by MuJoCo's own distance), its actuators limp (no gain, no bias) so that it stays down: its
    RobotSetup whose MuJoCo C rollout starts there, and the floor geom."""
    import copy
    import dataclasses

    from tkujax.robot.robot_setup import robot_setup

    robot = robot_setup(REPO / "specs" / "robots" / "t1.toml")
    m = copy.deepcopy(robot.setup.host_model)
    m.actuator_gainprm[:] = 0.0
    m.actuator_biasprm[:] = 0.0
    d = mujoco.MjData(m)
    mujoco.mj_copyData(d, m, robot.settled)
    for side in ("Left", "Right"):
        d.qpos[m.jnt_qposadr[m.joint(f"{side}_Knee_Pitch").id]] = 1.6
        d.qpos[m.jnt_qposadr[m.joint(f"{side}_Hip_Pitch").id]] = 0.0
    d.qvel[:] = 0.0
    floor = int(np.flatnonzero(m.geom_type == mujoco.mjtGeom.mjGEOM_PLANE)[0])
    mujoco.mj_kinematics(m, d)
    shank = min(mujoco.mj_geomDistance(m, d, floor, int(g), 2.0, None)
                for g in robot.setup.index.cylinder_geoms)
    d.qpos[2] -= shank - 0.001
    mujoco.mj_forward(m, d)
    return dataclasses.replace(robot, settled=d,
                               setup=robot.setup._replace(host_model=m)), floor


def _lowest_by_mujoco(m, qpos: np.ndarray, floor: int, geoms) -> float:
    d = mujoco.MjData(m)
    d.qpos[:] = qpos
    mujoco.mj_kinematics(m, d)
    return min(mujoco.mj_geomDistance(m, d, floor, int(g), 2.0, None) for g in geoms)


@needs_t1
def test_t1_kneeling_on_its_shanks_is_fallen(kneeling_t1):
    """Only the shanks' cylinders are near the floor (the pelvis, the head's sphere and the
    trunk's box are well clear), so the fall rests on the cylinders: MJX's reading of the
    start and MuJoCo C's series agree with MuJoCo's distances, and the rollout is a fall."""
    robot, floor = kneeling_t1
    m, d, idx = robot.setup.host_model, robot.settled, robot.setup.index
    assert idx.cylinder_geoms.size >= 8      # arms, hips and shanks
    others = [*idx.sphere_geoms, *idx.box_geoms, *idx.mesh_geoms]
    every = [*others, *idx.cylinder_geoms, *idx.capsule_geoms]
    assert _lowest_by_mujoco(m, d.qpos, floor, others) > 0.1
    assert d.qpos[2] > FALL_PELVIS_HEIGHT_M
    np.testing.assert_allclose(_lowest_by_mujoco(m, d.qpos, floor, every), 0.001, atol=1e-9)
    low = lowest_body_point(idx, mjx.put_data(m, d))          # MJX's reading
    np.testing.assert_allclose(float(low), 0.001, atol=1e-5)
    f = lambda x: np.full(1, x, np.float32)  # noqa: E731
    push = Push(impulse_ns=f(0.0), azimuth_rad=f(0.0), height_m=f(0.5), duration_s=f(0.02),
                onset_s=f(0.1))
    series, out = simulate_mujoco(push, np.zeros(1), robot.params, robot=robot,
                                  config=RolloutConfig(duration_s=0.15, record_qpos=True))
    qpos = np.asarray(series.qpos[0])
    reference = [_lowest_by_mujoco(m, q, floor, every) for q in qpos]
    # The series reads the kinematics of the state one physics step before the recorded qpos
    # (as MJX's d.xpos holds): the robot sinks by well under a millimetre in that step.
    np.testing.assert_allclose(series.lowest_body_z[0], reference, atol=5e-4)
    first = qpos[0]
    assert first[2] > FALL_PELVIS_HEIGHT_M and _lowest_by_mujoco(m, first, floor, others) > 0.1
    assert float(series.lowest_body_z[0, 0]) < FALL_BODY_CLEARANCE_M
    assert out.fell.tolist() == [True]


@pytest.mark.slow
@needs_t1
def test_t1_kneeling_is_fallen_on_mjx_as_on_mujoco_c(kneeling_t1):
    """The MJX closed loop from the same kneeling start: its lowest points are MuJoCo C's and
    the push is a fall (the MJX model and start state put from the limp model)."""
    import dataclasses

    import jax

    robot, _ = kneeling_t1
    m, d = robot.setup.host_model, robot.settled
    device = jax.local_devices()[0]
    robot = dataclasses.replace(robot, setup=robot.setup._replace(
        device_model=mjx.put_model(m, device=device),
        stand_state=mjx.put_data(m, d, device=device)))
    f = lambda x: np.full(1, x, np.float32)  # noqa: E731
    push = Push(impulse_ns=f(0.0), azimuth_rad=f(0.0), height_m=f(0.5), duration_s=f(0.02),
                onset_s=f(0.1))
    config = RolloutConfig(duration_s=0.15)
    c_series, c_out = simulate_mujoco(push, np.zeros(1), robot.params, robot=robot,
                                      config=config)
    series, out = simulate(push, np.zeros(1), robot.params, robot=robot, config=config)
    np.testing.assert_allclose(np.asarray(series.lowest_body_z), c_series.lowest_body_z,
                               atol=2e-4)
    assert np.asarray(out.fell).tolist() == c_out.fell.tolist() == [True]
