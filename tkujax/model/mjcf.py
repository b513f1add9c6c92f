"""Generate the TKU-X MJCF from a ModelParams.

Frame conventions (the paper's Fig. 3): x forward, y left, z up. The root body `pelvis` carries
the free joint; its origin is the waist point P_W, at the height of the hip joint centres, which
sit at (0, +-d_y, 0). Every hinge uses MuJoCo's right-hand rule, zero = straight pose:
  * pitch joints turn about +y, so a positive hip pitch swings the leg *backward*; a bent knee
    is positive; roll joints turn about +x; yaw joints about +z.
The three hip axes intersect at the hip joint centre and the two ankle axes at the ankle centre,
so the leg inverse kinematics has an exact closed form.

Collisions: every geom has contype = conaffinity = 0 and the floor contacts are explicit <pair>s
(MJX cost grows with the number of possible contacts): four sole-corner spheres per foot, which
double as the paper's four pressure sensors (a `touch` sensor around each), and the knees, hands,
head, chest and pelvis so that a fall ends on the ground.
"""

from __future__ import annotations

import math

from tkujax.model.model_params import ModelParams, ServoParams

# Names, in actuator order. Legs: right then left, hip yaw .. ankle roll (the paper's leg chain).
HEAD_JOINTS = ("head_pan", "head_tilt")
WAIST_JOINTS = ("waist_yaw",)
ARM_JOINT_SUFFIXES = ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow")
LEG_JOINT_SUFFIXES = ("hip_yaw", "hip_roll", "hip_pitch", "knee", "ankle_pitch", "ankle_roll")
ARM_JOINTS = tuple(f"{s}_{j}" for s in "rl" for j in ARM_JOINT_SUFFIXES)
LEG_ACTUATORS = tuple(f"{s}_{j}" for s in "rl" for j in LEG_JOINT_SUFFIXES)
JOINT_NAMES = HEAD_JOINTS + WAIST_JOINTS + ARM_JOINTS + LEG_ACTUATORS
FSR_SENSORS = tuple(f"{s}_fsr_{i}" for s in "rl" for i in range(1, 5))

_DEG = math.pi / 180.0
# Joint ranges in degrees [est], realistic for a kid-size humanoid (OP3 / Darwin-OP class).
_RANGES_DEG = {
    "head_pan": (-120, 120), "head_tilt": (-60, 60), "waist_yaw": (-90, 90),
    "shoulder_pitch": (-180, 180), "shoulder_roll": (-100, 100), "shoulder_yaw": (-90, 90),
    "elbow": (-140, 10),
    "hip_yaw": (-45, 45), "hip_roll": (-35, 35), "hip_pitch": (-110, 35), "knee": (0, 140),
    "ankle_pitch": (-75, 75), "ankle_roll": (-35, 35),
}
FSR_RADIUS_M = 0.005


def _range(joint: str) -> tuple[float, float]:
    key = joint[2:] if joint[:2] in ("r_", "l_") else joint
    lo, hi = _RANGES_DEG[key]
    return lo * _DEG, hi * _DEG


def _box_inertia(mass: float, sx: float, sy: float, sz: float) -> str:
    """Diagonal inertia of a solid box with full side lengths sx, sy, sz."""
    return " ".join(f"{mass / 12.0 * (b * b + c * c):.6g}" for b, c in ((sy, sz), (sx, sz), (sx, sy)))


def _inertial(pos, mass, size) -> str:
    return (f'<inertial pos="{pos[0]:.6g} {pos[1]:.6g} {pos[2]:.6g}" mass="{mass:.6g}" '
            f'diaginertia="{_box_inertia(mass, *size)}"/>')


def _joint(name: str, axis: str, cls: str) -> str:
    lo, hi = _range(name)
    return f'<joint name="{name}" class="{cls}" axis="{axis}" range="{lo:.6f} {hi:.6f}"/>'


def _servo_default(cls: str, servo: ServoParams) -> str:
    s = servo
    return (f'<default class="{cls}">'
            f'<joint damping="{s.damping_nms_per_rad:.6g}" armature="{s.armature_kgm2:.6g}" '
            f'frictionloss="{s.friction_loss_nm:.6g}" limited="true"/>'
            f'<position kp="{s.kp_nm_per_rad:.6g}" forcerange="{-s.stall_torque_nm:.6g} '
            f'{s.stall_torque_nm:.6g}" forcelimited="true" ctrllimited="true"/></default>')


def _leg(p: ModelParams, side: str) -> str:
    y = p.hip_offset_y_m * (1 if side == "l" else -1)
    m = [p.leg_mass_kg * f for f in p.leg_mass_fractions]
    lt, lc, ah = p.thigh_length_m, p.calf_length_m, p.ankle_height_m
    fl, fw, fx = p.foot_length_m, p.foot_width_m, p.foot_forward_offset_m
    r = FSR_RADIUS_M
    # Sole corners, numbered 1 front-right, 2 front-left, 3 back-left, 4 back-right (seen from above).
    corners = [(fx + fl / 2 - r, -fw / 2 + r), (fx + fl / 2 - r, fw / 2 - r),
               (fx - fl / 2 + r, fw / 2 - r), (fx - fl / 2 + r, -fw / 2 + r)]
    fsr = "".join(
        f'<geom name="{side}_fsr_{i}" type="sphere" size="{r}" pos="{cx:.6g} {cy:.6g} {-ah + r:.6g}" '
        f'class="collision"/>'
        f'<site name="{side}_fsr_{i}" type="sphere" size="{2.0 * r}" pos="{cx:.6g} {cy:.6g} {-ah + r:.6g}"/>'
        for i, (cx, cy) in enumerate(corners, start=1))
    j = lambda n, axis: _joint(f"{side}_{n}", axis, "leg")  # noqa: E731
    return f"""
      <body name="{side}_hip_yaw_link" pos="0 {y:.6g} 0">
        {j("hip_yaw", "0 0 1")}
        {_inertial((0, 0, 0.02), m[0], (0.04, 0.04, 0.04))}
        <body name="{side}_hip_roll_link">
          {j("hip_roll", "1 0 0")}
          {_inertial((0, 0, 0), m[1], (0.04, 0.05, 0.04))}
          <body name="{side}_thigh">
            {j("hip_pitch", "0 1 0")}
            {_inertial((0, 0, -lt / 2), m[2], (0.045, 0.045, lt))}
            <geom type="capsule" fromto="0 0 0 0 0 {-lt:.6g}" size="0.022" class="visual"/>
            <body name="{side}_shin" pos="0 0 {-lt:.6g}">
              {j("knee", "0 1 0")}
              {_inertial((0, 0, -lc / 2), m[3], (0.045, 0.045, lc))}
              <geom name="{side}_knee" type="sphere" size="0.022" pos="0.012 0 0" class="collision"/>
              <geom type="capsule" fromto="0 0 0 0 0 {-lc:.6g}" size="0.02" class="visual"/>
              <body name="{side}_ankle_link" pos="0 0 {-lc:.6g}">
                {j("ankle_pitch", "0 1 0")}
                {_inertial((0, 0, 0), m[4], (0.04, 0.04, 0.04))}
                <body name="{side}_foot">
                  {j("ankle_roll", "1 0 0")}
                  {_inertial((fx / 2, 0, -ah / 2), m[5], (fl * 0.6, fw * 0.6, ah))}
                  <site name="{side}_ankle" size="0.006"/>
                  <geom type="box" size="{fl / 2:.6g} {fw / 2:.6g} 0.004" pos="{fx:.6g} 0 {-ah + 0.004:.6g}"
                        class="visual" rgba="0.15 0.15 0.15 1"/>
                  <geom type="box" size="0.02 0.025 {ah / 2 - 0.004:.6g}" pos="0 0 {-ah / 2:.6g}" class="visual"/>
                  {fsr}
                </body>
              </body>
            </body>
          </body>
        </body>
      </body>"""


def _arm(p: ModelParams, side: str) -> str:
    y = p.shoulder_offset_y_m * (1 if side == "l" else -1)
    lu, lf, ma = p.upper_arm_length_m, p.forearm_length_m, p.arm_mass_kg
    j = lambda n, axis: _joint(f"{side}_{n}", axis, "arm")  # noqa: E731
    return f"""
        <body name="{side}_upper_arm" pos="0 {y:.6g} {p.chest_height_m - 0.025:.6g}">
          {j("shoulder_pitch", "0 1 0")}
          {j("shoulder_roll", "1 0 0")}
          {j("shoulder_yaw", "0 0 1")}
          {_inertial((0, 0, -lu / 2), 0.6 * ma, (0.035, 0.035, lu))}
          <geom type="capsule" fromto="0 0 0 0 0 {-lu:.6g}" size="0.018" class="visual"/>
          <body name="{side}_forearm" pos="0 0 {-lu:.6g}">
            {j("elbow", "0 1 0")}
            {_inertial((0, 0, -lf / 2), 0.4 * ma, (0.03, 0.03, lf))}
            <geom type="capsule" fromto="0 0 0 0 0 {-lf:.6g}" size="0.015" class="visual"/>
            <geom name="{side}_hand" type="sphere" size="0.02" pos="0 0 {-lf:.6g}" class="collision"/>
          </body>
        </body>"""


def build_mjcf(p: ModelParams) -> str:
    """MJCF text of TKU-X for the given (validated) parameters."""
    tw, td = p.torso_half_width_m, p.torso_half_depth_m
    ph, ch = p.pelvis_height_m, p.chest_height_m
    hr, nh = p.head_radius_m, p.neck_height_m
    head_geoms = ["head"]
    body_geoms = ["chest", "pelvis_geom", "r_knee", "l_knee", "r_hand", "l_hand"] + head_geoms
    pairs = "\n    ".join(
        [f'<pair geom1="floor" geom2="{s}_fsr_{i}" condim="3"/>' for s in "rl" for i in range(1, 5)]
        + [f'<pair geom1="floor" geom2="{g}" condim="3"/>' for g in body_geoms])
    actuators = "\n    ".join(
        f'<position name="{n}" joint="{n}" class="{"leg" if n in LEG_ACTUATORS else "arm"}" '
        f'ctrlrange="{_range(n)[0]:.6f} {_range(n)[1]:.6f}"/>' for n in JOINT_NAMES)
    touch = "\n    ".join(f'<touch name="{n}" site="{n}"/>' for n in FSR_SENSORS)
    return f"""<mujoco model="tkux">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{p.timestep_s}" solver="Newton" iterations="{p.solver_iterations}"
          ls_iterations="{p.ls_iterations}" integrator="Euler">
    <flag eulerdamp="disable"/>
  </option>
  <visual><global offwidth="640" offheight="480"/></visual>
  <default>
    <geom contype="0" conaffinity="0" rgba="0.75 0.75 0.8 1"/>
    <default class="visual"><geom group="1" mass="0"/></default>
    <default class="collision"><geom group="3" mass="0" rgba="0.9 0.3 0.2 1"/></default>
    {_servo_default("leg", p.leg_servo)}
    {_servo_default("arm", p.arm_servo)}
  </default>
  <asset>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.2 0.3 0.4" rgb2="0.3 0.4 0.5"
             width="256" height="256"/>
    <material name="grid" texture="grid" texrepeat="8 8" reflectance="0.1"/>
  </asset>
  <worldbody>
    <light pos="0 -1 2" dir="0 0.5 -1" directional="true"/>
    <geom name="floor" type="plane" size="5 5 0.1" material="grid"
          friction="{p.floor_friction} 0.005 0.0001"/>
    <body name="pelvis" pos="0 0 {p.ankle_height_m + p.stand_hip_to_ankle_m:.6g}">
      <freejoint name="root"/>
      {_inertial((0, 0, ph / 2), p.pelvis_mass_kg, (2 * td, 2 * tw, ph))}
      <site name="waist" size="0.01"/>
      <site name="imu" size="0.008" rgba="1 0.8 0 1"/>
      <geom name="pelvis_geom" type="sphere" size="{td:.6g}" pos="0 0 {ph / 2:.6g}" class="collision"/>
      <geom type="box" size="{td:.6g} {tw:.6g} {ph / 2:.6g}" pos="0 0 {ph / 2:.6g}" class="visual"/>
      <body name="chest" pos="0 0 {ph:.6g}">
        {_joint("waist_yaw", "0 0 1", "arm")}
        {_inertial((0, 0, p.chest_com_frac * ch), p.chest_mass_kg, (2 * td, 2 * tw, ch))}
        <geom name="chest" type="box" size="{td:.6g} {tw:.6g} {ch / 2:.6g}" pos="0 0 {ch / 2:.6g}"
              class="collision"/>
        <geom type="box" size="{td:.6g} {tw:.6g} {ch / 2:.6g}" pos="0 0 {ch / 2:.6g}" class="visual"
              rgba="0.2 0.35 0.7 1"/>
        <body name="head" pos="0 0 {ch:.6g}">
          {_joint("head_pan", "0 0 1", "arm")}
          {_joint("head_tilt", "0 1 0", "arm")}
          {_inertial((0, 0, nh + hr), p.head_mass_kg, (1.6 * hr, 1.6 * hr, 1.6 * hr))}
          <geom name="head" type="sphere" size="{hr:.6g}" pos="0 0 {nh + hr:.6g}" class="collision"/>
          <geom type="sphere" size="{hr:.6g}" pos="0 0 {nh + hr:.6g}" class="visual"/>
          <geom type="box" size="0.01 0.02 0.01" pos="{hr:.6g} 0 {nh + hr:.6g}" class="visual"
                rgba="0.1 0.1 0.1 1"/>
        </body>
        {_arm(p, "r")}
        {_arm(p, "l")}
      </body>
      {_leg(p, "r")}
      {_leg(p, "l")}
    </body>
  </worldbody>
  <contact>
    {pairs}
  </contact>
  <actuator>
    {actuators}
  </actuator>
  <sensor>
    <gyro name="gyro" site="imu"/>
    <accelerometer name="accel" site="imu"/>
    {touch}
  </sensor>
</mujoco>
"""
