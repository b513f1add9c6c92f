"""The TKU-X robot model: parameters, MJCF generation, the `stand` keyframe, leg geometry."""

from __future__ import annotations

import dataclasses
import functools
import math

import mujoco
import numpy as np

from tkujax.model.mjcf import (ARM_JOINTS, FSR_SENSORS, HEAD_JOINTS, JOINT_NAMES, LEG_ACTUATORS,
                               WAIST_JOINTS, build_mjcf)
from tkujax.model.model_params import MODEL_VARIANTS, MX28, MX64, ModelParams, ServoParams

__all__ = [
    "ARM_JOINTS", "FSR_SENSORS", "HEAD_JOINTS", "JOINT_NAMES", "LEG_ACTUATORS", "WAIST_JOINTS",
    "MODEL_VARIANTS", "MX28", "MX64", "ModelParams", "ServoParams", "LegGeometry", "build_mjcf",
    "leg_geometry",
    "load_model", "model_xml", "pendulum_lengths", "stand_joint_angles",
]


@dataclasses.dataclass(frozen=True)
class LegGeometry:
    """The paper's leg quantities (Fig. 3, 11), metres."""

    d_y: float    # waist centre P_W to hip joint, lateral
    d_z: float    # hip joint to ankle joint, vertical, stand pose
    thigh: float  # l_t
    calf: float   # l_c


def leg_geometry(params: ModelParams | None = None) -> LegGeometry:
    p = (params or ModelParams()).validate()
    return LegGeometry(d_y=p.hip_offset_y_m, d_z=p.stand_hip_to_ankle_m,
                       thigh=p.thigh_length_m, calf=p.calf_length_m)


def stand_joint_angles(params: ModelParams | None = None) -> dict[str, float]:
    """Joint angles of the `stand` keyframe (rad).

    The pelvis (and everything above it) is pitched forward by the stand lean; each ankle sits
    d_z straight below its hip in the world and the soles are flat. With the thigh making an
    angle a with the vertical (cos a = d_z^2 + l_t^2 - l_c^2 over 2 l_t d_z), in this model's sign
    convention (positive pitch swings a hanging link backward): hip_pitch = -a - lean,
    knee = a + b, ankle_pitch = -b, where b is the calf's angle with the vertical.
    """
    p = (params or ModelParams()).validate()
    lt, lc, dz = p.thigh_length_m, p.calf_length_m, p.stand_hip_to_ankle_m
    lean = math.radians(p.stand_lean_deg)
    a = math.acos((dz * dz + lt * lt - lc * lc) / (2 * lt * dz))   # thigh forward of vertical
    b = math.acos((dz * dz + lc * lc - lt * lt) / (2 * lc * dz))   # calf backward of vertical
    q = {name: 0.0 for name in JOINT_NAMES}
    for s in "rl":
        q[f"{s}_hip_pitch"] = -a - lean
        q[f"{s}_knee"] = a + b
        q[f"{s}_ankle_pitch"] = -b
        # Arms hang with slightly bent elbows, held a little away from the body.
        q[f"{s}_elbow"] = -0.3
        q[f"{s}_shoulder_roll"] = 0.12 if s == "l" else -0.12
    return q


def _keyframe_xml(model: mujoco.MjModel, p: ModelParams) -> str:
    q = stand_joint_angles(p)
    qpos = np.array(model.qpos0)
    lean = math.radians(p.stand_lean_deg)
    qpos[:3] = (0.0, 0.0, p.ankle_height_m + p.stand_hip_to_ankle_m)
    qpos[3:7] = (math.cos(lean / 2), 0.0, math.sin(lean / 2), 0.0)  # pitch forward about +y
    for name, angle in q.items():
        qpos[model.jnt_qposadr[model.joint(name).id]] = angle
    ctrl = [q[model.actuator(i).name] for i in range(model.nu)]
    fmt = lambda v: " ".join(f"{x:.9g}" for x in v)  # noqa: E731
    return f'<keyframe><key name="stand" qpos="{fmt(qpos)}" ctrl="{fmt(ctrl)}"/></keyframe>'


@functools.lru_cache(maxsize=16)
def model_xml(params: ModelParams | None = None) -> str:
    """Complete MJCF text, `stand` keyframe included."""
    p = (params or ModelParams()).validate()
    xml = build_mjcf(p)
    bare = mujoco.MjModel.from_xml_string(xml)
    return xml.replace("</mujoco>", _keyframe_xml(bare, p) + "\n</mujoco>")


def load_model(params: ModelParams | None = None) -> mujoco.MjModel:
    """Compile TKU-X. Raises ValueError naming the parameter when `params` is invalid."""
    return mujoco.MjModel.from_xml_string(model_xml(params))


@functools.lru_cache(maxsize=16)
def pendulum_lengths(params: ModelParams | None = None) -> tuple[float, float]:
    """(leg_length_m, com_height_m) of the stand keyframe for the paper's Eq. 6-10.

    leg_length l: distance from the mid-point of the ankle joints to the whole-body CoM;
    com_height h: CoM height above the floor (the LIP height).
    """
    model = load_model(params)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("stand").id)
    mujoco.mj_forward(model, data)
    com = data.subtree_com[model.body("pelvis").id]
    ankles = 0.5 * (data.site("r_ankle").xpos + data.site("l_ankle").xpos)
    return float(np.linalg.norm(com - ankles)), float(com[2])
