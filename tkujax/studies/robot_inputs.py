"""Robot files for the commands that read sweeps and run tunes: load the robot a sweep ran on
(`sweep_robot`), the one a tune spec names (`tune_robot`; `--robot tkux` names the built-in
TKU-X, `is_builtin`), a robot's LIP (`robot_lip`) and its capture-region geometry
(`capture_feet`, `capture_robot` for `tkujax capture`).

The studies check what they are given (`tkujax.sweeps.sweep_robot.check_robot`: the sha256 the
manifest records; `tkujax.studies.tune.robot_table.on_robot`: the spec's [robot] file); this module
only finds and loads the files, a layer above them.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

from tkujax.robot import robot_from_file
from tkujax.robot.loader import geom_points
from tkujax.analysis.capturability import LipModel, convex_hull, step_reach_m
from tkujax.studies.capture.theory import Feet
from tkujax.sweeps.chunks import read_manifest
from tkujax.sweeps.sweep_robot import recorded_robot
from tkujax.dialects.sweep_spec import load_spec
from tkujax.studies.tune.robot_table import robot_file_of


def sweep_robot(run_dir: str | Path, given: str | None = None):
    """The Robot of `given`, else of the robot file the sweep in `run_dir` recorded, else
    None (a TKU-X sweep); the caller checks it against the manifest."""
    if given is not None:
        return robot_from_file(given)
    recorded = recorded_robot(read_manifest(Path(run_dir)) or {})
    return None if recorded is None else robot_from_file(recorded["robot_file"])


# `--robot tkux`: the built-in TKU-X, where a command takes a robot file.
BUILTIN_ROBOT = "tkux"


def is_builtin(robot_arg: str | Path) -> bool:
    """Whether --robot names the built-in TKU-X (BUILTIN_ROBOT, and no file of that name)."""
    return str(robot_arg).lower() == BUILTIN_ROBOT and not Path(robot_arg).exists()


def tune_robot(raw: dict, given: str | None = None):
    """The Robot of `given`, else of the tune spec's [robot] file (raw: its TOML dict),
    else None (also for `given` BUILTIN_ROBOT: TKU-X)."""
    if given is not None and is_builtin(given):
        return None
    path = given or robot_file_of(raw)
    return None if path is None else robot_from_file(path)


def _foot_points(robot, body: int) -> np.ndarray:
    """(n, 2) world (x, y) of the collision geoms of one foot body at the settled stand."""
    model, data = robot.setup.host_model, robot.settled
    paired = set(model.pair_geom1.tolist()) | set(model.pair_geom2.tolist())
    corners = [data.xpos[body] + geom_points(model, g) @ data.xmat[body].reshape(3, 3).T
               for g in range(model.ngeom) if int(model.geom_bodyid[g]) == body
               and (model.geom_contype[g] or model.geom_conaffinity[g] or g in paired)]
    return np.concatenate(corners)[:, :2]


def robot_lip(robot) -> LipModel:
    """The LIP of a Robot's settled stand: total mass, whole-body CoM height and (x, y),
    the support polygon the hull of the feet's collision geoms."""
    model, data = robot.setup.host_model, robot.settled
    feet = sorted({int(model.site_bodyid[s]) for s in robot.setup.index.ankle_sites})
    com = data.subtree_com[1]
    return LipModel(mass_kg=float(mujoco.mj_getTotalmass(model)), com_height_m=float(com[2]),
                    com_xy_m=np.array(com[:2]),
                    support_polygon=convex_hull(np.concatenate([_foot_points(robot, b)
                                                                for b in feet])))


def capture_feet(robot) -> Feet:
    """A Robot's capture-region geometry (tkujax.studies.capture.theory.Feet): its LIP,
    the settled stand's ankle sites, one sole box around its ankle (the two feet's collision
    footprints relative to their ankles, the right one mirrored, averaged; centred in y) and
    the leg reach l_max of its controller parameters."""
    model, data = robot.setup.host_model, robot.settled
    ankle, boxes = {}, []
    for side, site in zip("rl", robot.setup.index.ankle_sites):
        a = np.array(data.site_xpos[site][:2])
        rel = _foot_points(robot, int(model.site_bodyid[site])) - a
        rel[:, 1] *= -1.0 if side == "r" else 1.0
        ankle[side] = a
        boxes.append([rel[:, 0].min(), rel[:, 0].max(), rel[:, 1].max() - rel[:, 1].min()])
    x0, x1, width = np.mean(boxes, 0)
    hy = 0.5 * width
    sole = np.array([[x0, -hy], [x1, -hy], [x1, hy], [x0, hy]])
    return Feet(lip=robot_lip(robot), ankle=ankle, sole=sole,
                reach_m=step_reach_m(robot.params))


def capture_robot(spec_path: str | Path, given: str | None = None):
    """(Robot, Feet) of `tkujax capture`: the --robot file `given`, else the spec's
    [robot] file; (None, None) for TKU-X."""
    path = given or load_spec(spec_path).robot_file
    if path is None:
        return None, None
    robot = robot_from_file(path)
    return robot, capture_feet(robot)
