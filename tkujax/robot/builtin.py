"""TKU-X, and robots made by its MJCF generator, as robot files (no third-party files).

`write_generated_robot(folder, params)` writes `<name>.xml` (tkujax.model's MJCF of
`params`, with or without the `stand` keyframe) and `<name>.toml` naming its joints, and returns
the TOML's path. `GENERATED_SECOND` is the second robot the tests use: longer legs, a wider
hip and different masses than TKU-X.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mujoco

from tkujax.model import ModelParams, build_mjcf, model_xml
from tkujax.robot.description import LEG_ROLES

TKUX_FEET = {"left": "l_foot", "right": "r_foot"}

# The second robot: 12 % longer thigh, 8 % longer calf, 10 mm wider hip, heavier legs and a
# lighter chest (the total mass still adds up), a deeper stand.
GENERATED_SECOND = dataclasses.replace(
    ModelParams(), thigh_length_m=0.123, calf_length_m=0.119, hip_offset_y_m=0.055,
    leg_mass_kg=1.10, chest_mass_kg=0.5866, stand_hip_to_ankle_m=0.215, stand_lean_deg=4.0)


def tkux_joint(side: str, role: str) -> str:
    """The joint of a leg role in tkujax's MJCF (e.g. "l_hip_yaw")."""
    return f"{side[0]}_{role}"


def robot_toml(mjcf_name: str, name: str, stand: str | None = "stand") -> str:
    """The robot file of a tkujax-generated model (`stand`: its keyframe, or None: computed)."""
    lines = [f'name = "{name}"', f'mjcf = "{mjcf_name}"', 'imu = "imu"']
    for side in ("left", "right"):
        lines.append(f"\n[legs.{side}]")
        lines += [f'{role} = "{tkux_joint(side, role)}"' for role in LEG_ROLES]
        lines.append(f'foot = "{TKUX_FEET[side]}"')
    if stand:
        lines.append(f'\n[stand]\nkeyframe = "{stand}"')
    return "\n".join(lines) + "\n"


def write_generated_robot(folder: str | Path, params: ModelParams | None = None,
                          name: str = "generated", keyframe: bool = True) -> Path:
    """Write a tkujax-generated robot (`params`; None: TKU-X) and its robot file to `folder`;
    keyframe False leaves the `stand` keyframe out (the stand is then computed)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    p = (params or ModelParams()).validate()
    xml = model_xml(p) if keyframe else build_mjcf(p)
    mujoco.MjModel.from_xml_string(xml)          # the generator's own check
    (folder / f"{name}.xml").write_text(xml)
    toml = folder / f"{name}.toml"
    toml.write_text(robot_toml(f"{name}.xml", name, "stand" if keyframe else None))
    return toml
