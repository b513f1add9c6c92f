"""tkujax.sim.tree_passes: MJX's tree passes in a compact program (the tuner's).

References: MuJoCo C's own kinematics (mj_kinematics, float64) for TKU-X away from its stand
pose and for a small model with every supported joint layout (a floating base, a body with two
hinges, a slide, a second tree, a second floating body); MJX's `smooth.kinematics` and its gradient;
and the paper's eight ball pushes run both ways.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco.mjx._src import smooth

from tkujax.control.controller_params import ControllerParams
from tkujax.sim import physics, tree_passes
from tkujax.sim import rollout_mjx as sim
from tkujax.sim.mjx_import import mjx
from tkujax.sim.push import make_push, stack_pushes
from tkujax.sim.setup import init
from tkujax.studies.paper import run_cases

FIELDS = ("xpos", "xquat", "xmat", "xanchor", "xaxis", "xipos", "ximat", "geom_xpos",
          "geom_xmat", "site_xpos", "site_xmat")

LAYOUTS = """
<mujoco>
  <worldbody>
    <body name="base" pos="0 0 1">
      <freejoint/>
      <geom type="box" size=".1 .1 .1" mass="1"/>
      <site name="s0" pos=".05 0 0"/>
      <body name="hip" pos="0 .1 -.1" quat="0.9 0.1 0.2 0.3">
        <joint type="hinge" axis="1 0 0" pos="0 0 .02"/>
        <joint type="hinge" axis="0 1 1" pos=".01 0 0"/>
        <geom type="capsule" size=".02 .1" mass=".5"/>
        <body name="slider" pos="0 0 -.2">
          <joint type="slide" axis="0 0 1"/>
          <joint type="hinge" axis="0 1 0" pos="0 0 .03"/>
          <geom type="sphere" size=".03" pos=".01 0 0" mass=".2"/>
          <site name="s1" pos="0 .02 0" quat="0 1 0 0"/>
        </body>
      </body>
    </body>
    <body name="arm" pos="1 0 .5">
      <joint type="hinge" axis="0 0 1" ref="0.3"/>
      <geom type="box" size=".05 .05 .2" mass=".3"/>
    </body>
    <body name="loose" pos=".2 0 0">
      <freejoint/>
      <geom type="sphere" size=".05" mass=".1"/>
    </body>
  </worldbody>
</mujoco>
"""


def _c_kinematics(host: mujoco.MjModel, qpos: np.ndarray) -> mujoco.MjData:
    data = mujoco.MjData(host)
    data.qpos[:] = qpos
    mujoco.mj_kinematics(host, data)
    return data


def _random_qpos(host: mujoco.MjModel, seed: int) -> np.ndarray:
    """qpos0 moved in every coordinate (free joints' quaternions off unit length, which both
    kinematics normalise)."""
    rng = np.random.default_rng(seed)
    return host.qpos0 + rng.normal(0.0, 0.4, host.nq)


@pytest.mark.parametrize("which", ["tkux", "layouts"])
def test_compact_kinematics_is_mujocos_in_float64(which):
    if which == "tkux":
        host = init()[0]
    else:
        host = mujoco.MjModel.from_xml_string(LAYOUTS)
    with jax.enable_x64(True):
        model = mjx.put_model(host)
        assert tree_passes.supports(model)
        data = mjx.make_data(model)
        ours_fn = jax.jit(lambda q: tree_passes.kinematics(model, data.replace(qpos=q)))
        mjx_fn = jax.jit(lambda q: smooth.kinematics(model, data.replace(qpos=q)))
        for seed in range(3):
            qpos = _random_qpos(host, seed)
            ours, ref = ours_fn(jnp.asarray(qpos)), _c_kinematics(host, qpos)
            for f in FIELDS:
                np.testing.assert_allclose(np.asarray(getattr(ours, f)).reshape(-1),
                                           getattr(ref, f).reshape(-1), atol=1e-12, err_msg=f)
            # MJX writes free joints' normalised quaternions back into qpos (MuJoCo C does not).
            np.testing.assert_allclose(np.asarray(ours.qpos),
                                       np.asarray(mjx_fn(jnp.asarray(qpos)).qpos), atol=1e-15)


@pytest.mark.parametrize("which", ["tkux", "layouts"])
def test_compact_velocity_passes_are_mujocos_in_float64(which):
    """com_vel (cvel, cdof_dot) and rne (qfrc_bias) from sums over the tree's matrices,
    against MuJoCo C's mj_forward, the model moving in every dof."""
    host = init()[0] if which == "tkux" else mujoco.MjModel.from_xml_string(LAYOUTS)
    rng = np.random.default_rng(3)
    with jax.enable_x64(True):
        model = mjx.put_model(host)
        data = mjx.make_data(model)

        @jax.jit
        def run(q, v):
            d = tree_passes.fwd_position(model, data.replace(qpos=q, qvel=v))
            return tree_passes.rne(model, tree_passes.com_vel(model, d))

        for _ in range(2):
            qpos, qvel = _random_qpos(host, 5), rng.normal(0.0, 1.0, host.nv)
            ref = mujoco.MjData(host)
            ref.qpos[:], ref.qvel[:] = qpos, qvel
            mujoco.mj_forward(host, ref)
            ours = run(jnp.asarray(qpos), jnp.asarray(qvel))
            for f in ("cvel", "cdof_dot", "qfrc_bias"):
                np.testing.assert_allclose(np.asarray(getattr(ours, f)), getattr(ref, f),
                                           atol=1e-10, err_msg=f)


@pytest.fixture(scope="module")
def tkux32():
    host, model, _, stand = init()
    qpos = jnp.asarray(_random_qpos(host, 7), jnp.float32)
    return host, model, stand.replace(qpos=qpos)


def test_compact_kinematics_matches_mjx_and_its_gradient(tkux32):
    host, model, state = tkux32
    weights = {f: jnp.asarray(np.random.default_rng(1).normal(size=getattr(state, f).shape),
                              jnp.float32) for f in FIELDS}

    def loss(fn):
        def f(qpos):
            d = fn(model, state.replace(qpos=qpos))
            return sum(jnp.sum(weights[k] * getattr(d, k)) for k in FIELDS)
        return jax.jit(jax.value_and_grad(f))

    (v_ours, g_ours), (v_mjx, g_mjx) = loss(tree_passes.kinematics)(state.qpos), \
        loss(smooth.kinematics)(state.qpos)
    np.testing.assert_allclose(v_ours, v_mjx, rtol=1e-5)
    np.testing.assert_allclose(g_ours, g_mjx, rtol=1e-4, atol=1e-4 * float(jnp.max(
        jnp.abs(g_mjx))))


def test_compact_forward_is_mjx_forward(tkux32):
    """Every float field `mjx.forward` writes, against `tree_passes.forward` on a moving
    TKU-X: a stage MJX adds to its forward in a later version shows up here."""
    host, model, state = tkux32
    lean = physics.without_sensors(model)
    rng = np.random.default_rng(2)
    state = state.replace(qvel=jnp.asarray(rng.normal(0.0, 1.0, host.nv), jnp.float32))
    ours = jax.jit(lambda d: tree_passes.forward(lean, d))(state)
    ref = jax.jit(lambda d: mjx.forward(lean, d))(state)
    leaves = jax.tree_util.tree_leaves_with_path(ref)
    ours_leaves = jax.tree_util.tree_leaves(ours)
    assert len(leaves) == len(ours_leaves)
    for (path, r), o in zip(leaves, ours_leaves):
        if jnp.issubdtype(r.dtype, jnp.floating) and r.size:
            scale = 1.0 + float(jnp.max(jnp.abs(r)))
            np.testing.assert_allclose(np.asarray(o), np.asarray(r), rtol=0,
                                       atol=2e-4 * scale, err_msg=jax.tree_util.keystr(path))


def test_compact_program_is_smaller_than_mjxs(tkux32):
    """What the module is for: one lowered kinematics at most half MJX's size."""
    _, model, state = tkux32

    def size(fn):
        return len(jax.jit(lambda q: fn(model, state.replace(qpos=q)).xpos).lower(
            state.qpos).as_text())

    assert size(tree_passes.kinematics) < 0.5 * size(smooth.kinematics)


def test_unsupported_model_falls_back_to_mjx():
    host = mujoco.MjModel.from_xml_string("""
<mujoco><worldbody><body><joint type="ball"/><geom size=".1" mass="1"/></body></worldbody>
</mujoco>""")
    model = mjx.put_model(host)
    assert not tree_passes.supports(model)
    d = mjx.make_data(model).replace(qpos=jnp.array([0.9, 0.1, 0.2, 0.3]))
    ours, ref = tree_passes.forward(model, d), mjx.forward(model, d)
    np.testing.assert_array_equal(np.asarray(ours.xquat), np.asarray(ref.xquat))


def test_paper_cases_with_compact_kinematics_keep_their_outcomes():
    """The paper's eight ball pushes (`tkujax paper`, 2.4 s each): MJX's kinematics and the
    compact one give the same falls, and inclinations within float32 rounding's growth."""
    ours = run_cases(config=sim.RolloutConfig(program=sim.ProgramOptions(tree_passes="compact")))
    ref = run_cases()
    np.testing.assert_array_equal(ours[2]["fell"], ref[2]["fell"])
    np.testing.assert_allclose(ours[2]["peak_incl_deg"], ref[2]["peak_incl_deg"], rtol=0.02)


def test_unknown_kinematics_is_named():
    pushes = stack_pushes([make_push(1.0)])
    with pytest.raises(ValueError, match="ProgramOptions.tree_passes.*'fast'"):
        sim.simulate(pushes, np.ones(1, np.float32), ControllerParams.paper(),
                     config=sim.RolloutConfig(program=sim.ProgramOptions(tree_passes="fast")))


def test_physics_without_sensors_supports_compact():
    assert tree_passes.supports(physics.without_sensors(init()[1]))
