"""The controller's geometry read from a robot's model, and a ControllerParams for it.

Lengths come from MuJoCo's kinematics, never from names: the thigh is the distance between the
hip-pitch and knee axes, the calf between the knee and ankle-pitch axes; the hip centre is the
point nearest the three hip axes, the ankle centre the point nearest the two ankle axes. At the
stand: d_y is half the lateral distance between the hip centres (base frame), d_z the vertical
hip-to-ankle distance (world, mean of both legs), the leg length l the distance from the ankle
midpoint to the whole-body CoM, and the CoM height h its height above the floor (Eq. 6-10).
"""

from __future__ import annotations

import dataclasses
import math

import mujoco
import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.robot.description import ANKLE_ROLES, HIP_ROLES
from tkujax.robot.loader import LEG_ORDER, RobotModel, ankle_point, axis_point, zero_pose_data


@dataclasses.dataclass(frozen=True)
class RobotGeometry:
    """A robot's leg geometry (m) and stand lean (rad), as the controller uses them."""

    thigh_length_m: float
    calf_length_m: float
    hip_offset_y_m: float          # d_y
    hip_to_ankle_z_m: float        # d_z at the stand
    leg_length_m: float            # l: ankle midpoint to CoM at the stand
    com_height_m: float            # h: CoM above the floor at the stand
    stand_lean_rad: float          # the base's pitch at the stand (forward > 0)
    hip_centre_base_m: tuple[float, float, float]   # left hip centre in the base frame
    mass_kg: float

    @property
    def reach_m(self) -> float:
        return self.thigh_length_m + self.calf_length_m


def _axis_gap(data: mujoco.MjData, j_from: int, j_to: int) -> float:
    """Distance between two parallel-ish joint axes: the anchors' offset across the axis."""
    u = data.xaxis[j_from] / np.linalg.norm(data.xaxis[j_from])
    d = data.xanchor[j_to] - data.xanchor[j_from]
    return float(np.linalg.norm(d - np.dot(d, u) * u))


def link_lengths(robot: RobotModel) -> tuple[float, float]:
    """(thigh, calf) in m, each the mean of both legs (pose independent)."""
    data = zero_pose_data(robot.model, robot.root_body)
    pitch, knee, ankle = (robot.column(r) for r in ("hip_pitch", "knee", "ankle_pitch"))
    j = robot.leg_joints
    thigh = np.mean([_axis_gap(data, row[pitch], row[knee]) for row in j])
    calf = np.mean([_axis_gap(data, row[knee], row[ankle]) for row in j])
    return float(thigh), float(calf)


def hip_and_ankle_centres(robot: RobotModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """(hips (2, 3), ankles (2, 3)) in world coordinates of `data` (after kinematics)."""
    hips, ankles = [], []
    hip_cols, ankle_cols = robot.columns(HIP_ROLES), robot.columns(ANKLE_ROLES)
    for row in robot.leg_joints:
        hips.append(axis_point(data.xanchor[row[hip_cols]], data.xaxis[row[hip_cols]]))
        ankles.append(ankle_point(data, row[robot.column("knee")], list(row[ankle_cols])))
    return np.array(hips), np.array(ankles)


def base_pitch_roll(quat: np.ndarray) -> tuple[float, float]:
    """Pitch (forward > 0) and roll of a body from its quaternion, as tkujax.sim.physics."""
    w, x, y, z = quat
    zx, zy, zz = 2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)
    return math.atan2(zx, zz), math.atan2(-zy, zz)


def floor_height_m(robot: RobotModel) -> float:
    g = robot.floor_geom
    return float(robot.model.geom_pos[g][2]) if g >= 0 else 0.0


def measure_geometry(robot: RobotModel, qpos: np.ndarray) -> RobotGeometry:
    """The geometry of `robot` standing at `qpos`."""
    model = robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    hips, ankles = hip_and_ankle_centres(robot, data)
    root = robot.root_body
    rot = data.xmat[root].reshape(3, 3)
    hips_base = (hips - data.xpos[root]) @ rot
    left = LEG_ORDER.index("left")
    com = data.subtree_com[root]
    ankle_mid = 0.5 * (data.site_xpos[robot.ankle_sites[0]] + data.site_xpos[robot.ankle_sites[1]])
    thigh, calf = link_lengths(robot)
    return RobotGeometry(
        thigh_length_m=thigh, calf_length_m=calf,
        hip_offset_y_m=float(0.5 * abs(hips_base[left, 1] - hips_base[1 - left, 1])),
        hip_to_ankle_z_m=float(np.mean(hips[:, 2] - ankles[:, 2])),
        leg_length_m=float(np.linalg.norm(com - ankle_mid)),
        com_height_m=float(com[2] - floor_height_m(robot)),
        stand_lean_rad=base_pitch_roll(data.qpos[_root_qpos(robot) + 3:_root_qpos(robot) + 7])[0],
        hip_centre_base_m=tuple(float(v) for v in hips_base[left]),
        mass_kg=float(model.body_subtreemass[root]))


def _root_qpos(robot: RobotModel) -> int:
    return int(robot.model.jnt_qposadr[robot.model.body_jntadr[robot.root_body]])


# The ranges of ControllerParams.validate() for the fields scaled from a robot's geometry,
# closed a hair inside where validate's range is open; clamp_derived keeps each default in them.
EPS = 1e-6
DERIVED_RANGES = {
    "step_period": (0.05, 2.0), "lift_height": (0.0, 0.1),
    "cp_trigger_forward_m": (0.0, 0.5), "cp_trigger_backward_m": (0.0, 0.5),
    "cp_trigger_lateral_m": (0.0, 0.5),
    "standing_lean": (-math.pi / 2 + EPS, math.pi / 2 - EPS),
    "cp_angle_offset": (-math.pi / 2 + EPS, math.pi / 2 - EPS),
    "eps_forward": (0.0, math.pi / 2 - EPS), "eps_backward": (0.0, math.pi / 2 - EPS),
    "hip_offset_y": (EPS, 2.0), "thigh_length": (EPS, 2.0), "calf_length": (EPS, 2.0),
    "leg_length": (EPS, 2.0), "com_height": (EPS, 2.0),
}


def clamp_derived(values: dict) -> tuple[dict, tuple[str, ...]]:
    """`values` with each derived field inside its range (DERIVED_RANGES, and hip_to_ankle_z
    within the reach), and what was clamped and why, one line per field."""
    out, notes = dict(values), []
    for key, (lo, hi) in DERIVED_RANGES.items():
        if key in out and not lo <= out[key] <= hi:
            clamped = min(max(out[key], lo), hi)
            notes.append(f"{key}: the scaled default {out[key]:.6g} is outside [{lo:.6g}, "
                         f"{hi:.6g}]; clamped to {clamped:.6g}")
            out[key] = clamped
    reach = out["thigh_length"] + out["calf_length"]
    if not 0 < out["hip_to_ankle_z"] <= reach:
        clamped = min(max(out["hip_to_ankle_z"], EPS), reach)
        notes.append(f"hip_to_ankle_z: {out['hip_to_ankle_z']:.6g} m is outside (0, "
                     f"thigh + calf = {reach:.6g}] m; clamped to {clamped:.6g}")
        out["hip_to_ankle_z"] = clamped
    return out, tuple(notes)


def scaled_defaults(geo: RobotGeometry,
                    reference: ControllerParams | None = None) -> tuple[ControllerParams,
                                                                        tuple[str, ...]]:
    """`controller_params_for`, and the lines saying which derived defaults were clamped."""
    ref = reference or ControllerParams.paper()
    scale_t = math.sqrt(geo.com_height_m / ref.com_height)
    scale_l = geo.reach_m / (ref.thigh_length + ref.calf_length)
    lean = geo.stand_lean_rad
    values, notes = clamp_derived(dict(
        step_period=ref.step_period * scale_t, lift_height=ref.lift_height * scale_l,
        cp_trigger_forward_m=ref.cp_trigger_forward_m * scale_l,
        cp_trigger_backward_m=ref.cp_trigger_backward_m * scale_l,
        cp_trigger_lateral_m=ref.cp_trigger_lateral_m * scale_l,
        standing_lean=lean, cp_angle_offset=lean,
        eps_forward=max(0.0, lean + (ref.eps_forward - ref.standing_lean)),
        eps_backward=max(0.0, ref.eps_backward + ref.standing_lean - lean),
        hip_offset_y=geo.hip_offset_y_m, hip_to_ankle_z=geo.hip_to_ankle_z_m,
        thigh_length=geo.thigh_length_m, calf_length=geo.calf_length_m,
        leg_length=geo.leg_length_m, com_height=geo.com_height_m))
    return dataclasses.replace(ref, **values).validate(), notes


def controller_params_for(geo: RobotGeometry,
                          reference: ControllerParams | None = None) -> ControllerParams:
    """The paper's controller with `geo`'s geometry and defaults scaled from TKU-X
    (`reference`, default ControllerParams.paper()):

    - step period T x sqrt(h / h_ref) (the pendulum's time scale);
    - lift height H_Sup and the capture-point trigger distances x reach / reach_ref;
    - the standing lean and the capture point's angle offset = the robot's stand lean, and the
      thresholds at the same angles from it as TKU-X's (12 deg = lean + 5 deg forward, -2 deg =
      lean - 9 deg backward; neither threshold can pass 0, where it is held: a robot leaning
      more than 5 deg backward keeps the forward threshold at 0);
    - each inside its allowed range (`clamp_derived`; `scaled_defaults` says what it clamped).
    For TKU-X's own geometry this is the reference itself."""
    return scaled_defaults(geo, reference)[0]
