"""The robot of a sweep that ran on a robot file, for the commands that read sweeps (map,
compare, replay): `check_robot(manifest, robot, where)`.

A robot sweep's manifest records the robot file's path and sha256 (with its model file's and
the collision mode's: `tkujax.robot.robot_setup.file_digest`) under model_params. The robot a
reading command is given (a Robot: `tkujax.studies.robot_inputs.sweep_robot` loads the
manifest's file, or the --robot file) must be that robot, the same sha256, else a SpecError
names both.
"""

from __future__ import annotations

from tkujax.dialects.validation import SpecError


def recorded_robot(manifest: dict) -> dict | None:
    """{robot, robot_file, robot_sha256} of a robot sweep's manifest, None for TKU-X."""
    model = manifest.get("model_params") or {}
    return model if "robot_sha256" in model else None


def check_robot(manifest: dict, robot, where: str):
    """`robot` (a Robot, or None for TKU-X) after checking that the sweep at `where`
    ran on it; SpecError naming both files otherwise. A TKU-X sweep given the built-in Robot
    is read as TKU-X's (None: the manifest's model)."""
    recorded = recorded_robot(manifest)
    if recorded is None:
        if robot is not None and not robot.builtin:
            raise SpecError(f"--robot: {where} ran on tkujax's own robot (no robot file), "
                            f"--robot gives {robot.source}")
        return None
    if robot is None:
        raise SpecError(f"--robot: {where} ran on the robot file {recorded['robot_file']}: "
                        "give its Robot (tkujax.studies.robot_inputs.sweep_robot loads it)")
    if robot.digest != recorded["robot_sha256"]:
        raise SpecError(f"--robot: {where} ran on {recorded['robot_file']} (sha256 "
                        f"{recorded['robot_sha256'][:12]}...); --robot gives {robot.source} "
                        f"(sha256 {robot.digest[:12]}...)")
    return robot


def same_robot(manifests: list[tuple[str, dict]], robot):
    """`robot` checked against several sweeps ((where, manifest) pairs): SpecError when they
    ran on different robots or on another one."""
    digests = {where: (recorded_robot(m) or {}).get("robot_sha256") for where, m in manifests}
    if len(set(digests.values())) > 1:
        raise SpecError(f"the runs ran on different robots (robot sha256 by run: "
                        f"{ {w: (d or 'tkujax built-in')[:12] for w, d in digests.items()} })")
    for where, manifest in manifests:
        check_robot(manifest, robot, where)
    return robot
