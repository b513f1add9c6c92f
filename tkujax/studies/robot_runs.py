"""The robot of a sweep that ran on a robot file, for the commands that read sweeps (map,
compare, replay, capture): `sweep_robot(manifest, given, where)`.

A robot sweep's manifest records the robot file's path and sha256 (with its model file's and
the collision mode's: `tkujax.robot.closed_loop.file_digest`) under model_params. A `--robot`
given to a reading command must be that robot (the same sha256), else a SpecError names both;
without `--robot` the recorded path is used, and refused when the file changed since.
`robot_lip(robot)` is the linear inverted pendulum of a robot file's settled stand (the LIP
theory the maps and capture regions overlay).
"""

from __future__ import annotations

import mujoco
import numpy as np

from tkujax.studies.capturability import LipModel, convex_hull
from tkujax.studies.validation import SpecError


def recorded_robot(manifest: dict) -> dict | None:
    """{robot, robot_file, robot_sha256} of a robot sweep's manifest, None for TKU-X."""
    model = manifest.get("model_params") or {}
    return model if "robot_sha256" in model else None


def check_robot(manifest: dict, given: str | None, where: str) -> str | None:
    """The robot file to use for the sweep at `where` (None: TKU-X), after the checks above."""
    from tkujax.robot.closed_loop import file_digest

    recorded = recorded_robot(manifest)
    if recorded is None:
        if given is not None:
            raise SpecError(f"--robot: {where} ran on tkujax's own robot (no robot file), "
                            f"--robot gives {given}")
        return None
    path = given or recorded["robot_file"]
    try:
        digest = file_digest(path)
    except (OSError, ValueError) as err:
        raise SpecError(f"--robot: {where} ran on {recorded['robot_file']}, which cannot be "
                        f"read now ({err}); give the robot file with --robot") from None
    if digest != recorded["robot_sha256"]:
        what = f"--robot gives {given}" if given else "the file has changed since"
        raise SpecError(f"--robot: {where} ran on {recorded['robot_file']} (sha256 "
                        f"{recorded['robot_sha256'][:12]}...); {what} (sha256 {digest[:12]}...)")
    return path


def sweep_robot(manifest: dict, given: str | None, where: str):
    """The RobotSetup of the sweep at `where` (None: TKU-X), checked as `check_robot`."""
    path = check_robot(manifest, given, where)
    if path is None:
        return None
    from tkujax.robot.closed_loop import robot_setup
    return robot_setup(path)


def same_robot(manifests: list[tuple[str, dict]], given: str | None) -> str | None:
    """The one robot file of several sweeps ((where, manifest) pairs); SpecError when they ran
    on different robots or `given` differs from theirs."""
    digests = {where: (recorded_robot(m) or {}).get("robot_sha256") for where, m in manifests}
    if len(set(digests.values())) > 1:
        raise SpecError(f"the runs ran on different robots (robot sha256 by run: "
                        f"{ {w: (d or 'tkujax built-in')[:12] for w, d in digests.items()} })")
    path = None
    for where, manifest in manifests:
        path = check_robot(manifest, given, where)
    return path


def robot_lip(robot) -> LipModel:
    """The LIP of a RobotSetup's settled stand: total mass, whole-body CoM height and (x, y),
    the support polygon the hull of the feet's collision geoms."""
    from tkujax.robot.loader import geom_points

    model, data = robot.setup.host_model, robot.settled
    feet = {int(model.site_bodyid[s]) for s in robot.setup.index.ankle_sites}
    corners = []
    for g in range(model.ngeom):
        b = int(model.geom_bodyid[g])
        if b in feet and (model.geom_contype[g] or model.geom_conaffinity[g]
                          or g in set(model.pair_geom1.tolist()) | set(model.pair_geom2.tolist())):
            pts = data.xpos[b] + geom_points(model, g) @ data.xmat[b].reshape(3, 3).T
            corners.append(pts[:, :2])
    com = data.subtree_com[1]
    return LipModel(mass_kg=float(mujoco.mj_getTotalmass(model)), com_height_m=float(com[2]),
                    com_xy_m=np.array(com[:2]), support_polygon=convex_hull(
                        np.concatenate(corners)))
