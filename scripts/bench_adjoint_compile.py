"""Does a hand-built adjoint compile faster than JAX's autodiff of the same rollout? (results/bench/h200_adjoint_compile.jsonl)

A physics-only rollout of TKU-X (the lean MJX step, holding actuator targets `theta`, N
substeps from the settled stand), loss = the mean pelvis height over the substeps, batch B.
Its gradient with respect to theta, built two ways:

  autodiff  jax.grad of a lax.scan whose step is jax.checkpoint'ed (the tuner's remat=substep)
  adjoint   a forward scan that stores each substep's state (qpos, qvel, qacc_warmstart), then
            a reverse scan whose body is jax.vjp of one step at the stored state

  python scripts/bench_adjoint_compile.py BATCH N_STEPS autodiff|adjoint [OUT.jsonl]

and `autodiff_data`: the whole MJX state (mjx.Data) as the carry, as in the closed loop
(jax.checkpoint per step). Its adjoint peer, `adjoint_data`, ran at commit 83b01a8 (`git show
83b01a8:results/bench/adjoint_compile.py`): it imports tkujax/sim/adjoint.py, removed since.

One program per process, into an empty persistent cache: trace + lower and XLA's compile timed
apart, the run time (median of 3), and the gradient (to compare the two).
"""
# ruff: noqa: E501   (research script)

import json
import statistics
import sys
import time

import jax
import jax.numpy as jnp

from tkujax.sim import physics
from tkujax.sim.mjx_import import mjx
from tkujax.sim.setup import init
from tkujax.sweeps.compile_cache import fresh_compilation_cache


def main(batch: int, n_steps: int, how: str, out: str | None) -> None:
    host, model, index, state = init()
    lean = physics.without_sensors(model)
    theta0 = jnp.asarray(host.key("stand").ctrl, jnp.float32)

    def step(x, theta):
        qpos, qvel, warm = x
        d = state.replace(qpos=qpos, qvel=qvel, qacc_warmstart=warm, ctrl=theta)
        d = mjx.euler(lean, mjx.forward(lean, d))
        return (d.qpos, d.qvel, d.qacc_warmstart)

    x0 = (state.qpos, state.qvel, state.qacc_warmstart)

    def loss_autodiff(theta):
        def body(x, _):
            x = jax.checkpoint(step)(x, theta)
            return x, x[0][2]

        _, z = jax.lax.scan(body, x0, None, length=n_steps)
        return jnp.mean(z)

    def grad_adjoint(theta):
        def fwd(x, _):
            return step(x, theta), x

        x_end, xs = jax.lax.scan(fwd, x0, None, length=n_steps)  # xs[t]: the state before step t
        dz = 1.0 / n_steps  # d loss / d (pelvis z after each step)

        def bwd(carry, x_t):
            lam, g = carry  # lam: d loss / d (state after this step)
            lam = (lam[0].at[2].add(dz), lam[1], lam[2])
            _, pullback = jax.vjp(step, x_t, theta)
            lam_x, g_theta = pullback(lam)
            return (lam_x, g + g_theta), None

        zero = jax.tree_util.tree_map(jnp.zeros_like, x_end)
        (_, g), _ = jax.lax.scan(bwd, (zero, jnp.zeros_like(theta)), xs, reverse=True)
        return g

    def loss_data(theta):
        def step_d(d):
            return mjx.euler(lean, mjx.forward(lean, d.replace(ctrl=theta)))

        def body(d, _):
            d = jax.checkpoint(step_d)(d)
            return d, d.qpos[2]

        _, z = jax.lax.scan(body, state, None, length=n_steps)
        return jnp.mean(z)

    fn = {
        "autodiff": jax.vmap(jax.grad(loss_autodiff)),
        "adjoint": jax.vmap(grad_adjoint),
        "autodiff_data": jax.vmap(jax.grad(loss_data)),
    }[how]
    thetas = theta0 + 0.01 * jax.random.normal(jax.random.PRNGKey(0), (batch, theta0.size))
    with fresh_compilation_cache():
        t0 = time.perf_counter()
        lowered = jax.jit(fn).lower(thetas)
        t1 = time.perf_counter()
        compiled = lowered.compile()
        t2 = time.perf_counter()
    g = jax.block_until_ready(compiled(thetas))
    times = []
    for _ in range(3):
        t = time.perf_counter()
        jax.block_until_ready(compiled(thetas))
        times.append(time.perf_counter() - t)
    row = dict(
        device=str(jax.devices()[0]),
        batch=batch,
        n_steps=n_steps,
        how=how,
        trace_lower_s=round(t1 - t0, 2),
        xla_compile_s=round(t2 - t1, 2),
        stablehlo_chars=len(lowered.as_text()),
        run_s=round(statistics.median(times), 4),
        grad_first_push=[float(v) for v in g[0]],
        grad_finite=bool(jnp.all(jnp.isfinite(g))),
    )
    print(json.dumps(row), flush=True)
    if out:
        with open(out, "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main(
        int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], sys.argv[4] if len(sys.argv) > 4 else None
    )
