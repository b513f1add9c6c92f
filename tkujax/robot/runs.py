"""Robot files for the commands that read sweeps and run tunes: load the robot a sweep ran on
(`sweep_robot`), the one a tune spec names (`tune_robot`), and a robot's LIP (`robot_lip`).

The studies check what they are given (`tkujax.studies.robot_runs.check_robot`: the sha256 the
manifest records; `tkujax.studies.tune.robot.on_robot`: the spec's [robot] file); this module
only finds and loads the files, a layer above them.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from tkujax.robot.closed_loop import robot_setup
from tkujax.robot.loader import geom_points
from tkujax.studies.capturability import LipModel, convex_hull
from tkujax.studies.chunks import read_manifest
from tkujax.studies.robot_runs import recorded_robot
from tkujax.studies.tune.robot import robot_file_of


def sweep_robot(run_dir: str | Path, given: str | None = None):
    """The RobotSetup of `given`, else of the robot file the sweep in `run_dir` recorded, else
    None (a TKU-X sweep); the caller checks it against the manifest."""
    if given is not None:
        return robot_setup(given)
    recorded = recorded_robot(read_manifest(Path(run_dir)) or {})
    return None if recorded is None else robot_setup(recorded["robot_file"])


def tune_robot(raw: dict, given: str | None = None):
    """The RobotSetup of `given`, else of the tune spec's [robot] file (raw: its TOML dict),
    else None."""
    path = given or robot_file_of(raw)
    return None if path is None else robot_setup(path)


def robot_lip(robot) -> LipModel:
    """The LIP of a RobotSetup's settled stand: total mass, whole-body CoM height and (x, y),
    the support polygon the hull of the feet's collision geoms."""
    model, data = robot.setup.host_model, robot.settled
    feet = {int(model.site_bodyid[s]) for s in robot.setup.index.ankle_sites}
    paired = set(model.pair_geom1.tolist()) | set(model.pair_geom2.tolist())
    corners = []
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if b in feet and (model.geom_contype[g] or model.geom_conaffinity[g] or g in paired):
            pts = data.xpos[b] + geom_points(model, g) @ data.xmat[b].reshape(3, 3).T
            corners.append(pts[:, :2])
    com = data.subtree_com[1]
    return LipModel(mass_kg=float(mujoco.mj_getTotalmass(model)), com_height_m=float(com[2]),
                    com_xy_m=np.array(com[:2]),
                    support_polygon=convex_hull(np.concatenate(corners)))
