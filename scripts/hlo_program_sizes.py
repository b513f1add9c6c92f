"""StableHLO sizes (characters, one robot) of one lean MJX physics step and the controller step,
forward and gradient, lowered on the project's CPU (jax 0.10.2). The
figures are in docs/performance.md:
  step fwd 1.19 M, step grad 2.67 M (2.69 M wrt qpos, qvel, ctrl), controller 0.09 M / 0.17 M.
"""
# ruff: noqa: E741, E501   (research script)

import jax
import jax.numpy as jnp
import time
from tkujax.sim.setup import init
from tkujax.sim.mjx_import import mjx
from tkujax.sim import physics
from tkujax.control.controller import controller_init, controller_step, Sensors
from tkujax.control.controller_params import ControllerParams


def main() -> None:
    host, model, index, state = init()
    lean = physics.without_sensors(model)


    def sz(f, *a):
        t = time.perf_counter()
        l = jax.jit(f).lower(*a)
        return len(l.as_text()) / 1e6, round(time.perf_counter() - t, 1)


    def step(d):
        return mjx.euler(lean, mjx.forward(lean, d))


    def f_step(d):
        return jnp.sum(step(d).qpos)


    print("step fwd", sz(lambda d: step(d).qpos, state))
    print("step grad", sz(jax.grad(lambda q: f_step(state.replace(qpos=q))), state.qpos))
    print(
        "step vjp wrt qpos,qvel,ctrl",
        sz(
            jax.grad(lambda q, v, c: f_step(state.replace(qpos=q, qvel=v, ctrl=c)), argnums=(0, 1, 2)),
            state.qpos,
            state.qvel,
            state.ctrl,
        ),
    )
    p = ControllerParams.paper()
    cs = controller_init(p)


    def ctl(g, a):
        s, out = controller_step(cs, Sensors(g, a), p, 1.0)
        return jnp.sum(out.leg_targets)


    print("controller fwd", sz(ctl, jnp.zeros(3), jnp.array([0, 0, 9.81])))
    print("controller grad", sz(jax.grad(ctl, argnums=(0, 1)), jnp.zeros(3), jnp.array([0, 0, 9.81])))


if __name__ == "__main__":
    main()
