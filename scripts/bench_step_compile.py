"""Cold compile of one lean MJX physics step of TKU-X, forward and its VJP, vmapped over a
batch (results/bench/h200_step_compile.jsonl): is a per-substep VJP a program XLA compiles in well under the tuning
gradient's ~96 s? That is the piece a host-driven adjoint (the backward pass as a Python loop
over substeps calling one compiled VJP) would compile, instead of one program holding the
forward loop, its recompute and the backward.

  python scripts/bench_step_compile.py BATCH fwd|vjp [OUT.json]

One program per process, into an empty persistent cache: trace + lower, and XLA's compile,
timed apart; then the compiled program's run time (median of 5).
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


def main(batch: int, which: str, out: str | None) -> None:
    host, model, index, state = init()
    lean = physics.without_sensors(model)
    states = physics.batch_state(state, batch)

    def step(qpos, qvel, ctrl):
        d = mjx.euler(lean, mjx.forward(lean, state.replace(qpos=qpos, qvel=qvel, ctrl=ctrl)))
        return d.qpos, d.qvel

    if which == "fwd":
        fn = jax.vmap(step)
        args = (states.qpos, states.qvel, states.ctrl)
    elif which == "vjp":

        def vjp(qpos, qvel, ctrl, qpos_bar, qvel_bar):
            _, pullback = jax.vjp(step, qpos, qvel, ctrl)
            return pullback((qpos_bar, qvel_bar))

        fn = jax.vmap(vjp)
        args = (
            states.qpos,
            states.qvel,
            states.ctrl,
            jnp.ones_like(states.qpos),
            jnp.ones_like(states.qvel),
        )
    else:
        raise SystemExit(f"which: fwd or vjp, got {which!r}")
    with fresh_compilation_cache():
        t0 = time.perf_counter()
        lowered = jax.jit(fn).lower(*args)
        t1 = time.perf_counter()
        compiled = lowered.compile()
        t2 = time.perf_counter()
    jax.block_until_ready(compiled(*args))
    times = []
    for _ in range(5):
        t = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t)
    row = dict(
        device=str(jax.devices()[0]),
        batch=batch,
        program=which,
        trace_lower_s=round(t1 - t0, 2),
        xla_compile_s=round(t2 - t1, 2),
        stablehlo_chars=len(lowered.as_text()),
        run_ms=round(1e3 * statistics.median(times), 3),
    )
    print(json.dumps(row), flush=True)
    if out:
        with open(out, "a") as f:
            f.write(json.dumps(row) + "\n")


if __name__ == "__main__":
    main(int(sys.argv[1]), sys.argv[2], sys.argv[3] if len(sys.argv) > 3 else None)
