"""MJX's compile and step time of a robot file with its collisions as written ("model") and
made primitive ("primitives"), and how the two modes' MuJoCo C rollouts of a stand differ.

    TKUJAX_MENAGERIE=/path/to/mujoco_menagerie python scripts/collision_timing.py \
        specs/robots/op3.toml --batch 8 --steps 50 --out op3_collision_timing.json

Per mode: the model's colliding geom pairs, MJX's contacts per step, the jit compile time of
`batch` x `steps` vmapped mjx.step from the settled stand (a scan), and the time of a second
call. The figures are the machine's (docs/robots.md records them).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from tkujax.robot.collision import COLLISION_MODES
from tkujax.robot.description import load_description
from tkujax.robot.loader import load_robot
from tkujax.robot.simsetup import settled_data
from tkujax.robot.stand import stand_pose
from tkujax.sim.mjx_import import mjx


def _rollout(mx, steps: int):
    def one(d):
        def body(d, _):
            d = mjx.step(mx, d)
            return d, d.qpos[2]
        return jax.lax.scan(body, d, None, length=steps)[1]
    return jax.jit(jax.vmap(one))


def time_mode(path: str, mode: str, batch: int, steps: int) -> dict:
    """MJX compile and run time of `batch` x `steps` steps from the stand, in `mode`."""
    desc = dataclasses.replace(load_description(path), collision_mode=mode)
    robot = load_robot(desc)
    model = robot.model
    pose = stand_pose(robot)
    data = settled_data(robot, pose, 0.2)
    t0 = time.perf_counter()
    mx = mjx.put_model(model)
    dx = mjx.put_data(model, data)
    put_s = time.perf_counter() - t0
    batched = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (batch,) + x.shape), dx)
    fn = _rollout(mx, steps)
    t0 = time.perf_counter()
    compiled = fn.lower(batched).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(batched))
    t0 = time.perf_counter()
    z = jax.block_until_ready(compiled(batched))
    run_s = time.perf_counter() - t0
    return dict(mode=mode, ngeom=int(model.ngeom), contacts_per_step=int(dx._impl.ncon)
                if hasattr(dx, "_impl") and hasattr(dx._impl, "ncon") else None,
                put_model_s=round(put_s, 3), compile_s=round(compile_s, 2),
                run_s=round(run_s, 3), step_ms_per_batch=round(1e3 * run_s / steps, 3),
                base_z_end_m=round(float(np.asarray(z)[0, -1]), 5))


def stand_drift(path: str, seconds: float) -> dict:
    """MuJoCo C: the base's position after `seconds` of stand in each mode."""
    out = {}
    for mode in COLLISION_MODES:
        robot = load_robot(dataclasses.replace(load_description(path), collision_mode=mode))
        data = settled_data(robot, stand_pose(robot), seconds)
        out[mode] = [round(float(v), 5) for v in data.qpos[:3]]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("robot")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--steps", type=int, default=50)
    ap.add_argument("--modes", nargs="+", default=list(COLLISION_MODES))
    ap.add_argument("--out")
    args = ap.parse_args()
    result = dict(robot=args.robot, machine=platform.machine(), cores=os.cpu_count(),
                  backend=jax.default_backend(), mujoco=mujoco.__version__, batch=args.batch,
                  steps=args.steps, modes=[time_mode(args.robot, m, args.batch, args.steps)
                                           for m in args.modes],
                  stand_base_xyz_5s=stand_drift(args.robot, 5.0))
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        with open(args.out, "w") as f:
            f.write(text + "\n")


if __name__ == "__main__":
    main()
