"""Exact leg targets for a robot whose leg chain is not TKU-X's (hips pitch-roll-yaw, five-joint
legs): the controller's TKU-X joint angles -> the foot pose they ask for -> the robot's IK.

The controller writes TKU-X's leg (tkujax.control.ik's convention). `chain_targets` takes its
joint angles to the ankle centre and foot orientation they put relative to the stand
(`tkux_fk`), asks the robot's leg for the same change from its own stand, and solves the
robot's joints by damped Gauss-Newton on its forward kinematics (`chain_fk`: the product of
exponentials of its joint axes, read from MuJoCo at the zero pose), from the linear map's guess
(tkujax.robot.leg_map). NEWTON_STEPS iterations, fixed (no Python branch on traced values);
a non-finite solution falls back to the guess. Pure JAX (jit / vmap / grad); MuJoCo C's rollout
calls the same function (`chain_targets_host`). `tests/test_robot_chains.py` measures the
round trip through MuJoCo's kinematics.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

NEWTON_STEPS = 4
DAMPING = 1e-6           # of the normal equations, in units of the weighted Jacobian squared


@dataclasses.dataclass(frozen=True, eq=False)
class LegChain:
    """A robot's legs for `chain_targets` (numpy; legs right then left, roles in order).

    axes, anchors: (2, n, 3) joint axes and points at the zero pose, base frame (roles in
    order); chain: (2, n) the roles' columns in chain order from the base (T1: pitch first);
    ankle0, foot0: (2, 3) ankle centre and (2, 3, 3) foot rotation at the zero pose;
    stand_q: (2, n) the robot's stand angles; stand_p, stand_r: its ankle and foot there;
    ctrl_stand_p, ctrl_stand_r: the controller's leg at its stand (relative to its hip);
    thigh_m, calf_m: the controller's leg; weight_m: rotation's weight (the leg's reach);
    matrix, offsets: the linear map (the Newton start); lo, hi: (2, n) joint ranges."""

    axes: np.ndarray
    anchors: np.ndarray
    chain: tuple[tuple[int, ...], tuple[int, ...]]
    ankle0: np.ndarray
    foot0: np.ndarray
    stand_q: np.ndarray
    stand_p: np.ndarray
    stand_r: np.ndarray
    ctrl_stand_p: np.ndarray
    ctrl_stand_r: np.ndarray
    thigh_m: float
    calf_m: float
    weight_m: float
    matrix: np.ndarray
    offsets: np.ndarray
    lo: np.ndarray
    hi: np.ndarray


def _axis_rot(axis: jax.Array, angle: jax.Array) -> jax.Array:
    """Rodrigues: the rotation by `angle` about the unit `axis`."""
    k = jnp.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]],
                  dtype=angle.dtype)
    return (jnp.eye(3, dtype=angle.dtype) + jnp.sin(angle) * k
            + (1.0 - jnp.cos(angle)) * (k @ k))


def chain_fk(q, axes, anchors, ankle0, foot0, order):
    """(ankle centre (3,), foot rotation (3, 3)) of a serial chain of hinges at angles q (n,):
    the product of exponentials of the zero pose's axes through their anchors, applied in
    chain order from the base (`order`: the columns of q, static)."""
    rot = jnp.eye(3, dtype=q.dtype)
    trans = jnp.zeros(3, dtype=q.dtype)
    for i in order:
        r_i = _axis_rot(jnp.asarray(axes[i], q.dtype), q[i])
        t_i = jnp.asarray(anchors[i], q.dtype) - r_i @ jnp.asarray(anchors[i], q.dtype)
        trans = trans + rot @ t_i
        rot = rot @ r_i
    return rot @ jnp.asarray(ankle0, q.dtype) + trans, rot @ jnp.asarray(foot0, q.dtype)


def tkux_fk(q, thigh_m, calf_m):
    """(ankle centre relative to the hip centre, foot rotation) of TKU-X's leg at q (6,)."""
    ex = jnp.array([1.0, 0.0, 0.0], q.dtype)
    ey = jnp.array([0.0, 1.0, 0.0], q.dtype)
    ez = jnp.array([0.0, 0.0, 1.0], q.dtype)
    r01 = _axis_rot(ez, q[0]) @ _axis_rot(ex, q[1])
    r2 = r01 @ _axis_rot(ey, q[2])
    ankle = r2 @ (jnp.array([0.0, 0.0, -thigh_m], q.dtype)
                  + _axis_rot(ey, q[3]) @ jnp.array([0.0, 0.0, -calf_m], q.dtype))
    foot = r01 @ _axis_rot(ey, q[2] + q[3] + q[4]) @ _axis_rot(ex, q[5])
    return ankle, foot


def _rot_error(target, current):
    """Small-angle rotation vector turning `current` into `target` (world frame)."""
    m = target @ current.T
    return 0.5 * jnp.stack([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])


def spd_solve(h, b):
    """x with h x = b for a small symmetric positive definite h (n, n), n static: Gaussian
    elimination without pivoting (stable for SPD), unrolled in plain jnp ops. jnp.linalg.solve
    calls LAPACK, and on jaxlib's CPU runtime two batched LAPACK solves in one program can
    deadlock (4,096 lanes, 2 cores: tests/test_leg_chain_solve.py)."""
    n = h.shape[0]
    a = jnp.concatenate([h, b[:, None]], axis=1)
    for i in range(n):
        a = a.at[i].set(a[i] / a[i, i])
        a = a - jnp.outer(a[:, i].at[i].set(0.0), a[i])
    return a[:, n]


def _solve_leg(chain: LegChain, side: int, q_ctrl, guess):
    """The robot leg's angles for the controller leg's angles q_ctrl (6,), from `guess`."""
    dtype = q_ctrl.dtype
    p_c, r_c = tkux_fk(q_ctrl, chain.thigh_m, chain.calf_m)
    target_p = jnp.asarray(chain.stand_p[side], dtype) + p_c - jnp.asarray(
        chain.ctrl_stand_p[side], dtype)
    target_r = r_c @ jnp.asarray(chain.ctrl_stand_r[side], dtype).T @ jnp.asarray(
        chain.stand_r[side], dtype)
    args = (chain.axes[side], chain.anchors[side], chain.ankle0[side], chain.foot0[side],
            chain.chain[side])
    w = jnp.asarray([1.0, 1.0, 1.0] + [chain.weight_m] * 3, dtype)

    def residual(q):
        p, r = chain_fk(q, *args)
        return w * jnp.concatenate([target_p - p, _rot_error(target_r, r)])

    q = guess
    for _ in range(NEWTON_STEPS):
        e = residual(q)
        jac = -jax.jacfwd(residual)(q)
        h = jac.T @ jac
        h = h + DAMPING * (jnp.trace(h) + 1e-12) * jnp.eye(h.shape[0], dtype=dtype)
        q = q + spd_solve(h, jac.T @ e)
    q = jnp.clip(q, jnp.asarray(chain.lo[side], dtype), jnp.asarray(chain.hi[side], dtype))
    return jnp.where(jnp.all(jnp.isfinite(q)), q, guess)


def chain_targets(chain: LegChain, legs: jax.Array) -> jax.Array:
    """The robot's leg targets (2n,) for the controller's (12,) (module doc); batched by vmap."""
    dtype = legs.dtype
    guess = (jnp.matmul(jnp.asarray(chain.matrix, dtype), legs,
                        precision=jax.lax.Precision.HIGHEST) + jnp.asarray(chain.offsets, dtype))
    n = chain.axes.shape[1]
    right = _solve_leg(chain, 0, legs[:6], guess[:n])
    left = _solve_leg(chain, 1, legs[6:], guess[n:])
    return jnp.concatenate([right, left])


@functools.lru_cache(maxsize=8)
def _host_fn(chain: LegChain):
    return jax.jit(jax.vmap(functools.partial(chain_targets, chain)))


def chain_targets_host(chain: LegChain, legs: np.ndarray) -> np.ndarray:
    """`chain_targets` of a batch (m, 12) of numpy targets, as numpy (MuJoCo C's rollout)."""
    return np.asarray(_host_fn(chain)(jnp.asarray(legs, jnp.float32)), np.float64)
