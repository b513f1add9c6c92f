"""StableHLO size (characters, one robot, lowered on the project's 2-core CPU, jax 0.10.2) of a
lean MJX physics step of TKU-X, stage by stage, forward and gradient (d of the sum of every
float field of the state with respect to qpos, qvel and ctrl):

  stage              fwd   (+)      grad  (+)
  kinematics         0.631 (+0.631) 1.334 (+1.334)
  com_pos            0.721 (+0.090) 1.719 (+0.385)
  crb                0.749 (+0.028) 1.798 (+0.079)
  factor_m           0.751 (+0.002) 1.807 (+0.009)
  collision          0.823 (+0.072) 1.913 (+0.106)
  make_constraint    0.922 (+0.099) 2.068 (+0.155)
  transmission       0.933 (+0.011) 2.078 (+0.010)
  +velocity          1.045 (+0.112) 2.381 (+0.303)
  +act+acc           1.098 (+0.053) 2.474 (+0.093)
  +solve             1.200 (+0.102) 2.683 (+0.209)
  +euler             1.227 (+0.027) 2.748 (+0.065)

MJX's body-tree kinematics is half of the step's program (8,926 jaxpr equations: one traced
copy of its per-body function per tree level and joint signature, written with scalar quaternion
arithmetic); the contacts and the 1-iteration Newton solver are small.
"""
# ruff: noqa: E501, E741   (research script)

import jax
import jax.numpy as jnp
from tkujax.sim.setup import init
from tkujax.sim import physics
from mujoco.mjx._src import smooth, collision_driver, constraint, solver, forward as F


def main() -> None:
    host, model, index, state = init()
    m = physics.without_sensors(model)
    print(
        "nv",
        host.nv,
        "ncon",
        state._impl.contact.dist.shape if hasattr(state, "_impl") else None,
        "nefc",
        state._impl.efc_J.shape,
    )
    stages = [
        ("kinematics", smooth.kinematics),
        ("com_pos", smooth.com_pos),
        ("crb", smooth.crb),
        ("factor_m", smooth.factor_m),
        ("collision", collision_driver.collision),
        ("make_constraint", constraint.make_constraint),
        ("transmission", smooth.transmission),
    ]


    def upto(k):
        def f(d):
            for _, s in stages[:k]:
                d = s(m, d)
            return d

        return f


    def sz(f, *a):
        l = jax.jit(f).lower(*a)
        return round(len(l.as_text()) / 1e6, 3)


    def loss_of(f):
        return lambda q, v, c: sum(
            jnp.sum(x)
            for x in jax.tree_util.tree_leaves(f(state.replace(qpos=q, qvel=v, ctrl=c)))
            if jnp.issubdtype(x.dtype, jnp.floating)
        )


    prev = (0, 0)
    for k in range(1, len(stages) + 1):
        fw = sz(upto(k), state)
        gr = sz(jax.grad(loss_of(upto(k)), argnums=(0, 1, 2)), state.qpos, state.qvel, state.ctrl)
        print(
            f"{stages[k - 1][0]:18s} fwd {fw:.3f} (+{fw - prev[0]:.3f})  grad {gr:.3f} (+{gr - prev[1]:.3f})",
            flush=True,
        )
        prev = (fw, gr)


    def rest(d):
        d = F.fwd_position(m, d)
        d = F.fwd_velocity(m, d)
        return d


    def act(d):
        d = rest(d)
        d = F.fwd_actuation(m, d)
        d = F.fwd_acceleration(m, d)
        return d


    def sol(d):
        return solver.solve(m, act(d))


    def full(d):
        return F.euler(m, sol(d))


    for name, f in [("+velocity", rest), ("+act+acc", act), ("+solve", sol), ("+euler", full)]:
        fw = sz(f, state)
        gr = sz(jax.grad(loss_of(f), argnums=(0, 1, 2)), state.qpos, state.qvel, state.ctrl)
        print(
            f"{name:18s} fwd {fw:.3f} (+{fw - prev[0]:.3f})  grad {gr:.3f} (+{gr - prev[1]:.3f})",
            flush=True,
        )
        prev = (fw, gr)


if __name__ == "__main__":
    main()
