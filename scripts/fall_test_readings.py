"""The fall test reading each boxed mesh by its box (as before) and by its mesh's own vertices
(tkujax.robot.fall_geoms), on the same MuJoCo C trajectories: random pushes up to --max-ns
from every direction at the CoM height +-10 %, 10-80 ms, onset 0.3 s, 2 s, the robot's
controller on (or its scaled defaults with --defaults). Prints how many pushes each reading
calls a fall, and how many only one of them does.

    python scripts/fall_test_readings.py specs/robots/op3.toml --n 1024 --max-ns 2.27
"""

from __future__ import annotations

import argparse
import json

import mujoco
import numpy as np

from tkujax.robot.fall_geoms import floor_geoms, primitive_low
from tkujax.robot.loader import load_robot
from tkujax.robot.robot_setup import robot_from_file
from tkujax.sim.metrics import FALL_BODY_CLEARANCE_M, FALL_PELVIS_HEIGHT_M
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push
from tkujax.sim.rollout_mujoco import simulate_mujoco


def _fell(m, qpos_series, box_geoms, point_geoms) -> bool:
    d = mujoco.MjData(m)
    for q in qpos_series:
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        lows = [primitive_low(m, d, g) for g in box_geoms] + [
            float((d.geom_xpos[g][2] + p @ d.geom_xmat[g].reshape(3, 3)[2]).min())
            for g, p in point_geoms]
        if q[2] < FALL_PELVIS_HEIGHT_M or min(lows) < FALL_BODY_CLEARANCE_M:
            return True
    return False


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("robot_file")
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--max-ns", type=float, required=True, help="the largest impulse, N s")
    ap.add_argument("--defaults", action="store_true", help="the scaled defaults, not the "
                    "robot's controller")
    args = ap.parse_args(argv)
    robot = robot_from_file(args.robot_file)
    m, idx = robot.setup.host_model, robot.setup.index
    by_box = [g for g in floor_geoms(load_robot(args.robot_file))
              if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_MESH]
    by_points = ([*idx.sphere_geoms, *idx.box_geoms, *idx.capsule_geoms, *idx.cylinder_geoms],
                 list(zip(idx.mesh_geoms, idx.mesh_points)))
    rng = np.random.default_rng(5)
    n, h = args.n, float(robot.params.com_height)
    f = lambda x: np.asarray(x, np.float32)  # noqa: E731
    pushes = Push(impulse_ns=f(rng.uniform(0.1 * args.max_ns, args.max_ns, n)),
                  azimuth_rad=f(rng.uniform(0, 2 * np.pi, n)),
                  height_m=f(rng.uniform(0.9 * h, 1.1 * h, n)),
                  duration_s=f(rng.uniform(0.01, 0.08, n)), onset_s=f(np.full(n, 0.3)))
    params = robot.defaults if args.defaults else robot.params
    series, out = simulate_mujoco(pushes, np.ones(n), params, robot=robot,
                                  config=RolloutConfig(duration_s=2.0, record_qpos=True))
    box = np.array([_fell(m, series.qpos[i], by_box, []) for i in range(n)])
    mesh = np.array([_fell(m, series.qpos[i], *by_points) for i in range(n)])
    print(json.dumps(dict(robot=robot.name, n=n, simulator_fell=int(np.sum(out.fell)),
                          box_fell=int(box.sum()), mesh_fell=int(mesh.sum()),
                          box_only=int((box & ~mesh).sum()), mesh_only=int((mesh & ~box).sum()))))


if __name__ == "__main__":
    main()
