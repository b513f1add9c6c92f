"""A small grid of pushes on a robot file's model, MuJoCo C, control off and on: fall counts.

    python scripts/robot_push_grid.py specs/robots/op3.toml [--out results.json]

Impulses 0.2-2.0 N s (10 levels) from 8 directions at the CoM height, 20 ms half-sine, onset
0.5 s, 3 s episodes, the controller `controller_params_for` the robot (scaled defaults).
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import jax.numpy as jnp
import numpy as np

from tkujax.robot.robot_setup import robot_setup
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push
from tkujax.sim.rollout_mujoco import simulate_mujoco


def grid_pushes(height_m: float, impulses, azimuths_deg) -> tuple[Push, np.ndarray, np.ndarray]:
    imp, az = np.meshgrid(np.asarray(impulses, float), np.asarray(azimuths_deg, float))
    imp, az = imp.ravel(), az.ravel()
    n = imp.size
    f = lambda v: jnp.asarray(v, jnp.float32)  # noqa: E731
    return Push(impulse_ns=f(imp), azimuth_rad=f(np.radians(az)), height_m=f(np.full(n, height_m)),
                duration_s=f(np.full(n, 0.02)), onset_s=f(np.full(n, 0.5))), imp, az


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("robot")
    ap.add_argument("--out")
    ap.add_argument("--duration", type=float, default=3.0)
    args = ap.parse_args()
    r = robot_setup(args.robot)
    impulses = np.round(np.linspace(0.2, 2.0, 10), 3)
    azimuths = np.arange(0, 360, 45)
    pushes, imp, az = grid_pushes(r.params.com_height, impulses, azimuths)
    result = dict(robot=r.name, digest=r.digest, machine=platform.processor() or platform.machine(),
                  com_height_m=r.params.com_height, impulses_ns=impulses.tolist(),
                  azimuths_deg=azimuths.tolist(), n=int(imp.size))
    for label, on in (("off", 0.0), ("on", 1.0)):
        t0 = time.time()
        _, o = simulate_mujoco(pushes, np.full(imp.size, on), r.params, robot=r,
                               config=RolloutConfig(duration_s=args.duration))
        fell = np.asarray(o.fell, bool) & ~np.asarray(o.diverged, bool)
        result[label] = dict(
            falls=int(fell.sum()), diverged=int(np.asarray(o.diverged).sum()),
            wall_s=round(time.time() - t0, 1),
            falls_by_impulse={f"{i:g}": int(fell[imp == i].sum()) for i in impulses},
            falls_by_azimuth={f"{a:g}": int(fell[az == a].sum()) for a in azimuths})
    print(json.dumps(result, indent=1))
    if args.out:
        with open(args.out, "w") as fh:
            json.dump(result, fh, indent=1)


if __name__ == "__main__":
    main()
