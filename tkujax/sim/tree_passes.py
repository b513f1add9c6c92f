"""MJX's passes over the body tree (kinematics, com_vel, rne) in a compact program.

`mjx.forward` runs these through `scan.body_tree`, which traces its per-body function once for
every (tree depth, joint signature, parent's signature) group: 11 groups for TKU-X's
kinematics, 11 for com_vel and 10 for rne's accelerations. Together that was over half of one
physics step's program and of its gradient, and XLA's compile time grows with the program
(docs/performance.md). Here the same fields come from MJX's own formulas (`math.rotate`,
`quat_mul`, `axis_angle_to_quat`, `motion_cross`, `inert_mul`), traced once for all bodies:
- kinematics: each body's pose in its parent's frame, its joints applied in order (joint slots
  padded to the widest body with zero-angle hinges at the origin: exact identities); then world
  poses by doubling: a body's pose is composed with its ancestor's and the ancestor pointer
  jumps to that ancestor's own, ceil(log2(depth)) passes unrolled (3 for TKU-X), with no loop
  in the program (a loop over the depth, tried first, ran the GPU gradient step 44 % slower);
- com_vel and rne: the tree's sums (velocities and accelerations down from the world, forces
  up from the leaves) as gathers and sums over static index lists (`_tree_sums`).
Sums and products are associated differently from MJX's parent-by-parent chain, so the fields
agree to float rounding, not bit for bit (tests/test_tree_passes.py: MuJoCo C to 1e-12 and
1e-10 in float64). On one H200 the tuning gradient's cold compile takes 41.0 s against 76.9 s
with MJX's passes (results/bench/README.md, `h200_gradcompile_compact`).

Supported joints: hinge and slide anywhere, free as a body's only joint (MuJoCo allows it on
top-level bodies only). `supports(model)` says whether a model qualifies; `forward` falls back
to `mjx.forward` otherwise.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco.mjx._src import (collision_driver, constraint, math, passive, sensor, smooth,
                             solver, support)
from mujoco.mjx._src import forward as mjx_forward

from .mjx_import import mjx

_FREE, _BALL = int(mujoco.mjtJoint.mjJNT_FREE), int(mujoco.mjtJoint.mjJNT_BALL)
_SLIDE = int(mujoco.mjtJoint.mjJNT_SLIDE)


def supports(model: mjx.Model) -> bool:
    """Whether `kinematics` handles the model: no ball joint, free joints alone in their body,
    no mocap body."""
    types = np.asarray(model.jnt_type)
    free_bodies = np.asarray(model.jnt_bodyid)[types == _FREE]
    return (not np.any(types == _BALL) and model.nmocap == 0
            and bool(np.all(np.asarray(model.body_jntnum)[free_bodies] == 1)))


def _joint_slots(model: mjx.Model) -> np.ndarray:
    """Static (nbody, widest body's joint count) joint ids per body and slot, -1: padding."""
    jntnum, jntadr = np.asarray(model.body_jntnum), np.asarray(model.body_jntadr)
    joint = np.full((model.nbody, max(1, int(jntnum.max(initial=0)))), -1, np.int64)
    for b in range(model.nbody):
        joint[b, :jntnum[b]] = jntadr[b] + np.arange(jntnum[b])
    return joint


def _compose(pos_a, quat_a, pos_b, quat_b):
    """Pose a, then pose b in a's frame (MJX's formulas: a body's pose from its parent's)."""
    return pos_a + math.rotate(pos_b, quat_a), math.quat_mul(quat_a, quat_b)


def kinematics(model: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mujoco.mjx._src.smooth.kinematics` for a model that `supports` accepts."""
    joint = _joint_slots(model)
    parent, types = np.asarray(model.body_parentid), np.asarray(model.jnt_type)
    nbody, slots = joint.shape
    qadr = np.asarray(model.jnt_qposadr)
    pad = joint < 0
    jid = np.where(pad, 0, joint)
    free = ~pad[:, 0] & (types[jid[:, 0]] == _FREE)     # a free joint is its body's only one
    dtype = d.qpos.dtype
    z_axis = jnp.array([0.0, 0.0, 1.0], dtype)
    # Per body and slot: joint position, axis and displacement q - q0 (padding: origin, z, 0).
    no_q = pad | (types[jid] == _FREE)
    jnt_pos = jnp.where(pad[..., None], 0.0, model.jnt_pos[jid]).astype(dtype)
    jnt_axis = jnp.where(pad[..., None], z_axis, model.jnt_axis[jid]).astype(dtype)
    qslot = np.where(no_q, 0, qadr[jid])
    disp = jnp.where(no_q, 0.0, d.qpos[qslot] - model.qpos0[qslot])
    slide = ~pad & (types[jid] == _SLIDE)
    # A free joint's body pose is its qpos (the quaternion normalised, and written back).
    fadr = qadr[np.where(free, jid[:, 0], 0)]
    free_pos = d.qpos[fadr[:, None] + np.arange(3)]
    free_quat = jax.vmap(math.normalize)(d.qpos[fadr[:, None] + 3 + np.arange(4)])

    def local(bpos, bquat, jpos, jaxis, q, sl, fpos, fquat, is_free):
        """The body's pose in its parent's frame, and its joints' anchors and axes in it."""
        pos, quat = bpos, bquat
        anchors, axes = [], []
        for s in range(slots):
            anchor = math.rotate(jpos[s], quat) + pos
            axis = math.rotate(jaxis[s], quat)
            anchors.append(anchor)
            axes.append(axis)
            hinge_quat = math.quat_mul(quat, math.axis_angle_to_quat(jaxis[s], q[s]))
            hinge_pos = anchor - math.rotate(jpos[s], hinge_quat)
            pos = jnp.where(sl[s], pos + axis * q[s], hinge_pos)
            quat = jnp.where(sl[s], quat, hinge_quat)
        anchors, axes = jnp.stack(anchors), jnp.stack(axes)
        anchors = anchors.at[0].set(jnp.where(is_free, fpos, anchors[0]))
        axes = axes.at[0].set(jnp.where(is_free, z_axis, axes[0]))
        return jnp.where(is_free, fpos, pos), jnp.where(is_free, fquat, quat), anchors, axes

    pos, quat, anchors, axes = jax.vmap(local)(
        model.body_pos.astype(dtype), model.body_quat.astype(dtype), jnt_pos, jnt_axis, disp,
        slide, free_pos, free_quat, free)
    # World poses by doubling: each pass composes a body's pose (so far relative to `up`) with
    # that of `up`, then `up` skips to its own `up`; the world (body 0) is the identity, so
    # ceil(log2(depth)) passes, unrolled, with no loop in the program.
    rel_pos, rel_quat = pos, quat
    up = parent.copy()
    while np.any(up != 0):
        rel_pos, rel_quat = jax.vmap(_compose)(rel_pos[up], rel_quat[up], rel_pos, rel_quat)
        up = up[up]
    xpos, xquat = rel_pos, rel_quat
    # Joint anchors and axes: from the body's frame into the world by its parent's pose.
    ppos, pquat = xpos[parent], xquat[parent]
    xanchor = jax.vmap(jax.vmap(_compose_point, (None, None, 0)))(ppos, pquat, anchors)
    xaxis = jax.vmap(jax.vmap(math.rotate, (0, None)))(axes, pquat)
    body_of, slot_of = np.nonzero(~pad)     # row-major: joint ids in order (body_jntadr)
    xanchor, xaxis = xanchor[body_of, slot_of], xaxis[body_of, slot_of]
    xmat = jax.vmap(math.quat_to_mat)(xquat)
    qpos = d.qpos
    if np.any(free):
        qpos = qpos.at[fadr[free][:, None] + 3 + np.arange(4)].set(free_quat[free])

    v_local_to_global = jax.vmap(support.local_to_global)
    xipos, ximat = v_local_to_global(xpos, xquat, model.body_ipos, model.body_iquat)
    d = d.replace(qpos=qpos, xanchor=xanchor, xaxis=xaxis, xpos=xpos)
    d = d.replace(xquat=xquat, xmat=xmat, xipos=xipos, ximat=ximat)
    if model.ngeom:
        geom_xpos, geom_xmat = v_local_to_global(
            xpos[model.geom_bodyid], xquat[model.geom_bodyid], model.geom_pos, model.geom_quat)
        d = d.replace(geom_xpos=geom_xpos, geom_xmat=geom_xmat)
    if model.nsite:
        site_xpos, site_xmat = v_local_to_global(
            xpos[model.site_bodyid], xquat[model.site_bodyid], model.site_pos, model.site_quat)
        d = d.replace(site_xpos=site_xpos, site_xmat=site_xmat)
    return d


def _compose_point(pos, quat, point):
    return pos + math.rotate(point, quat)


def _tree_sums(model: mjx.Model) -> dict:
    """Static (numpy) 0/1 matrices of the tree's sums:
    to_body[b, j]: dof j moves body b (its body is b or an ancestor of b);
    before[i, j]: dof j comes before dof i on the way from the world (an ancestor body's, an
      earlier joint of the same body, or a free joint's translation before its rotation);
    subtree[b, c]: body c is in b's subtree."""
    nbody, nv = model.nbody, model.nv
    parent = np.asarray(model.body_parentid)
    dof_body, dof_jnt = np.asarray(model.dof_bodyid), np.asarray(model.dof_jntid)
    types = np.asarray(model.jnt_type)
    anc = np.zeros((nbody, nbody), bool)          # anc[b, c]: c is b or an ancestor of b
    for b in range(nbody):
        c = b
        while True:
            anc[b, c] = True
            if c == 0:
                break
            c = parent[c]
    to_body = anc[:, dof_body]
    strict = anc & ~np.eye(nbody, dtype=bool)
    # A free joint's dofs: 3 translations, then 3 rotations.
    of_free = types[dof_jnt] == _FREE
    offset = np.arange(nv) - np.asarray(model.jnt_dofadr)[dof_jnt]
    free_trans, free_rot = of_free & (offset < 3), of_free & (offset >= 3)
    same_joint = dof_jnt[:, None] == dof_jnt[None, :]
    before = (strict[dof_body][:, dof_body]
              | ((dof_body[:, None] == dof_body[None, :]) & (dof_jnt[None, :] < dof_jnt[:, None]))
              | (free_rot[:, None] & same_joint & free_trans[None, :]))
    return dict(to_body=to_body, before=before, subtree=anc.T, free_trans=free_trans)


def _masked_sum(mask: np.ndarray, x: jax.Array) -> jax.Array:
    """mask @ x for a static 0/1 matrix `mask` (rows, n), as a gather of each row's entries
    and a sum: exact float additions (a matrix product may run in TF32 on a GPU) and no GEMM
    call for these tiny sizes."""
    width = max(1, int(mask.sum(axis=1).max(initial=0)))
    idx = np.full((mask.shape[0], width), mask.shape[1])       # padding: the zero row below
    for r, row in enumerate(mask):
        cols = np.nonzero(row)[0]
        idx[r, :len(cols)] = cols
    padded = jnp.concatenate((x, jnp.zeros((1,) + x.shape[1:], x.dtype)))
    return padded[idx].sum(axis=1)


def com_vel(model: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mujoco.mjx._src.smooth.com_vel` (cvel, cdof_dot) as sums over the tree's static
    index lists (`_tree_sums`) instead of a scan over body groups."""
    t = _tree_sums(model)
    moved = d.cdof * d.qvel[:, None]                       # each dof's velocity, (nv, 6)
    cvel = _masked_sum(t["to_body"], moved)
    vel_before = _masked_sum(t["before"], moved)
    cdof_dot = jax.vmap(math.motion_cross)(vel_before, d.cdof)
    cdof_dot = jnp.where(t["free_trans"][:, None], 0.0, cdof_dot)
    return d.replace(cvel=cvel, cdof_dot=cdof_dot)


def rne(model: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mujoco.mjx._src.smooth.rne` (flg_acc=False: the bias forces qfrc_bias) with its two
    tree scans as sums over static index lists."""
    t = _tree_sums(model)
    dtype = d.qvel.dtype
    if model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_GRAVITY:
        cacc0 = jnp.zeros(6, dtype)
    else:
        cacc0 = jnp.concatenate((jnp.zeros(3, dtype), -model.opt.gravity.astype(dtype)))
    cacc = cacc0 + _masked_sum(t["to_body"], d.cdof_dot * d.qvel[:, None])

    def frc(cinert, cacc, cvel):
        f = math.inert_mul(cinert, cacc)
        return f + math.motion_cross_force(cvel, math.inert_mul(cinert, cvel))

    loc_cfrc = jax.vmap(frc)(d._impl.cinert, cacc, d.cvel)
    cfrc = _masked_sum(t["subtree"], loc_cfrc)
    qfrc_bias = jax.vmap(jnp.dot)(d.cdof, cfrc[np.asarray(model.dof_bodyid)])
    return d.replace(qfrc_bias=qfrc_bias)


def com_pos(model: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mujoco.mjx._src.smooth.com_pos` (subtree_com, cinert, cdof) with the subtree sums over
    static index lists: MJX's reverse tree scan sums children with a segment sum, a scatter-add
    that a GPU runs with atomics, in an order that changes from run to run
    (tests/test_tree_passes.py checks the fields against MuJoCo C)."""
    t = _tree_sums(model)
    mass = model.body_mass.astype(d.xipos.dtype)
    pos = _masked_sum(t["subtree"], d.xipos * mass[:, None])
    subtree_mass = _masked_sum(t["subtree"], mass[:, None])[:, 0]
    subtree_com = pos / jnp.maximum(subtree_mass, mujoco.mjMINVAL)[:, None]
    subtree_com = jnp.where((subtree_mass < mujoco.mjMINVAL)[:, None], d.xipos, subtree_com)
    root_com = subtree_com[np.asarray(model.body_rootid)]

    @jax.vmap
    def inert_com(inert, ximat, off, body_mass):   # MJX's formula
        h = jnp.cross(off, -jnp.eye(3, dtype=off.dtype))
        inert = math.matmul_unroll(ximat * inert, ximat.T)
        inert += math.matmul_unroll(h, h.T) * body_mass
        inert = inert[(np.array([0, 1, 2, 0, 0, 1]), np.array([0, 1, 2, 1, 2, 2]))]
        return jnp.concatenate([inert, off * body_mass, body_mass[None]])

    cinert = inert_com(model.body_inertia, d.ximat, d.xipos - root_com, mass)
    return d.tree_replace({"subtree_com": subtree_com, "_impl.cinert": cinert,
                           "cdof": _cdof(model, d, root_com)})


def _cdof(model: mjx.Model, d: mjx.Data, root_com: jax.Array) -> jax.Array:
    """Each dof's motion axis in the frame centred at its tree's CoM (MJX's com_pos formulas;
    hinge, slide and free joints, as `supports` allows)."""
    dof_jnt = np.asarray(model.dof_jntid)
    types = np.asarray(model.jnt_type)[dof_jnt]
    offset = np.arange(model.nv) - np.asarray(model.jnt_dofadr)[dof_jnt]
    body = np.asarray(model.jnt_bodyid)[dof_jnt]
    com_offset = root_com[body] - d.xanchor[dof_jnt]                     # (nv, 3)
    hinge = jnp.concatenate([d.xaxis[dof_jnt], jnp.cross(d.xaxis[dof_jnt], com_offset)], -1)
    slide = jnp.concatenate([jnp.zeros_like(com_offset), d.xaxis[dof_jnt]], -1)
    rot_axis = d.xmat[body][np.arange(model.nv), :, np.clip(offset - 3, 0, 2)]   # xmat.T rows
    free_rot = jnp.concatenate([rot_axis, jnp.cross(rot_axis, com_offset)], -1)
    free_trans = jnp.eye(3, 6, 3, dtype=com_offset.dtype)[np.clip(offset, 0, 2)]
    is_free = types == _FREE
    return jnp.where((is_free & (offset < 3))[:, None], free_trans,
                     jnp.where(is_free[:, None], free_rot,
                               jnp.where((types == _SLIDE)[:, None], slide, hinge)))


def crb(model: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mujoco.mjx._src.smooth.crb` (composite inertias, the mass matrix) with the subtree sums
    over static index lists (see `com_pos`)."""
    crb_body = _masked_sum(_tree_sums(model)["subtree"], d._impl.cinert).at[0].set(0.0)
    crb_cdof = jax.vmap(math.inert_mul)(crb_body[np.asarray(model.dof_bodyid)], d.cdof)
    qm = support.make_m(model, crb_cdof, d.cdof, model.dof_armature)
    return d.tree_replace({"_impl.crb": crb_body, "_impl.M": qm})


def fwd_velocity(model: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mjx_forward.fwd_velocity` with `com_vel` and `rne` in place of MJX's."""
    d = d.tree_replace({"_impl.actuator_velocity": d._impl.actuator_moment @ d.qvel,
                        "_impl.ten_velocity": d._impl.ten_J @ d.qvel})
    d = com_vel(model, d)
    d = passive.passive(model, d)
    d = rne(model, d)
    return smooth.tendon_bias(model, d)


def fwd_position(model: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mjx_forward.fwd_position` with `kinematics` in place of MJX's."""
    d = kinematics(model, d)
    d = com_pos(model, d)
    d = smooth.camlight(model, d)
    d = smooth.tendon(model, d)
    d = crb(model, d)
    d = smooth.tendon_armature(model, d)
    d = smooth.factor_m(model, d)
    d = collision_driver.collision(model, d)
    d = constraint.make_constraint(model, d)
    return smooth.transmission(model, d)


def forward(model: mjx.Model, d: mjx.Data) -> mjx.Data:
    """`mjx.forward` with `kinematics`, `com_vel` and `rne` in place of MJX's (`mjx.forward`
    itself when `supports` says no)."""
    if not supports(model):
        return mjx.forward(model, d)
    d = fwd_position(model, d)
    d = sensor.sensor_pos(model, d)
    d = fwd_velocity(model, d)
    d = sensor.sensor_vel(model, d)
    d = mjx_forward.fwd_actuation(model, d)
    d = mjx_forward.fwd_acceleration(model, d)
    if d._impl.efc_J.size == 0:
        return d.replace(qacc=d.qacc_smooth)
    d = solver.solve(model, d)
    return sensor.sensor_acc(model, d)
