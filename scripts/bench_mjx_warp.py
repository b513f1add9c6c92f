"""MJX's two implementations side by side on each robot: JAX (what tkujax runs) and Warp
(`mjx.put_model(m, impl="warp")`, MuJoCo Warp through XLA's FFI; forward only, no gradients).
docs/performance.md, "MuJoCo Warp"; results/bench/*_mjx_warp.json.

    MJX_WARP_ENABLED=true python scripts/bench_mjx_warp.py OUT.json [--batch 4096] [--steps 200]

Per robot (TKU-X, OP3 as `op3.toml` and `op3_fast.toml` describe it, Booster T1) and per
implementation: a batch of copies of the settled stand, holding the stand's targets, stepped
`--steps` times with `mjx.step` in one scan (as Warp's own testspeed does): the cold compile
(trace, lower and compile, in an empty persistent cache and, for Warp, an empty kernel
cache; the first call, where Warp builds and loads its kernels), the run (the compile excluded,
physics steps/s), and the final base position against MuJoCo C's (the same steps from the same
state, float64) as a check that both step the same model. The JSON is rewritten after each row.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ROBOTS = {"tkux": None, "op3": "op3.toml", "op3_fast": "op3_fast.toml", "t1": "t1.toml"}
CONTACTS_PER_WORLD = 48     # Warp's contact buffer per world (TKU-X's stand: 8 touching)
CONSTRAINTS_PER_WORLD = 256


def robot_for(name: str):
    from tkujax.robot import builtin_robot, robot_from_file

    f = ROBOTS[name]
    return builtin_robot() if f is None else robot_from_file(str(ROOT / "specs" / "robots" / f))


def c_reference(robot, steps: int) -> np.ndarray:
    m = robot.host_model
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:], d.ctrl[:] = robot.settled.qpos, robot.settled.qvel, robot.settled.ctrl
    for _ in range(steps):
        mujoco.mj_step(m, d)
    return np.array(d.qpos[:3])


def program(robot, impl: str, batch: int, steps: int):
    from tkujax.sim.mjx_import import mjx

    m = robot.host_model
    mx = mjx.put_model(m, impl=impl)
    qpos = jnp.asarray(robot.settled.qpos, jnp.float32)
    qvel = jnp.asarray(robot.settled.qvel, jnp.float32)
    ctrl = jnp.asarray(robot.settled.ctrl, jnp.float32)
    extra = {} if impl == "jax" else dict(naconmax=CONTACTS_PER_WORLD * batch,
                                         njmax=CONSTRAINTS_PER_WORLD)

    @jax.vmap
    def init(_):
        d = mjx.make_data(m, impl=impl, **extra)
        return d.replace(qpos=qpos, qvel=qvel, ctrl=ctrl)

    d0 = jax.jit(init)(jnp.arange(batch))

    @jax.jit
    def unroll(d):
        def body(d, _):
            return jax.vmap(mjx.step, in_axes=(None, 0))(mx, d), None
        return jax.lax.scan(body, d, None, length=steps)[0].qpos

    return unroll, d0


def row(robot, impl: str, batch: int, steps: int) -> dict:
    from tkujax.sweeps.compile_cache import fresh_compilation_cache

    unroll, d0 = program(robot, impl, batch, steps)
    with fresh_compilation_cache():
        jax.clear_caches()
        t0 = time.perf_counter()
        lowered = unroll.lower(d0)
        t1 = time.perf_counter()
        exe = lowered.compile()
        t2 = time.perf_counter()
        qpos = np.asarray(jax.block_until_ready(exe(d0)))   # Warp builds its kernels here
        t3 = time.perf_counter()
    jax.block_until_ready(exe(d0))
    run_s = time.perf_counter() - t3
    ref = c_reference(robot, steps)
    return dict(impl=impl, batch=batch, steps=steps, lower_s=round(t1 - t0, 2),
                compile_s=round(t2 - t1, 2), first_call_s=round(t3 - t2, 2), run_s=round(run_s, 4),
                steps_per_s=round(batch * steps / run_s),
                base_pos_vs_c_m=float(np.abs(qpos[:, :3] - ref).max()),
                base_z_m=float(qpos[0, 2]), c_base_z_m=float(ref[2]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--robots", default=",".join(ROBOTS))
    ap.add_argument("--impls", default="jax,warp")
    args = ap.parse_args()
    try:                                # Warp's kernels: built cold, in an empty cache
        import tempfile

        import warp as wp

        wp.config.kernel_cache_dir = tempfile.mkdtemp(prefix="warp_kernels_")
        wp.config.quiet = True
    except ImportError:
        pass
    d = jax.devices()[0]
    out = dict(device=getattr(d, "device_kind", d.platform), jax=jax.__version__, rows=[])
    for name in args.robots.split(","):
        robot = robot_for(name)
        for impl in args.impls.split(","):
            try:
                r = row(robot, impl, args.batch, args.steps)
            except Exception as exc:  # noqa: BLE001 -- recorded; the next row runs
                r = dict(impl=impl, error=f"{type(exc).__name__}: {exc}"[:800])
            out["rows"].append(dict(robot=name) | r)
            print(out["rows"][-1], flush=True)
            Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
