"""TKU-X model parameters: one frozen dataclass, every number with its source.

Sources (see README "Model parameters"):
  [paper]  Liu et al. 2020, Table 1 and Sec. 2/4 (height, mass, DOF, servos, 7 deg lean).
  [DS]     Robotis MX-28 / MX-64 datasheets (stall torque, no-load speed, resolution).
  [BAM]    Rhoban's identified MX-64 actuator model (kp at P=32, armature, friction).
  [est]    Estimate: no public source gives TKU-X link lengths or masses; proportions follow
           Darwin-OP / Robotis OP3 scaled to the paper's height and mass.
  [fit]    Identified by `tkujax.studies.calibrate` (CMA-ES on the MuJoCo C backend) from the
           paper's Tables 4-5 and the 7 deg stand lean, inside the bounds of
           tkujax/studies/calibrate/fit_vector.py (results/calibration/). `ModelParams()` is the
           calibrated robot; `ModelParams.estimated()` is the earlier estimate (every [fit]
           number back at its [est] value).
"""

from __future__ import annotations

import dataclasses
import math


@dataclasses.dataclass(frozen=True)
class ServoParams:
    """A Dynamixel servo as a MuJoCo position actuator plus joint passive terms.

    Damping is the DC motor's back-EMF line through the datasheet stall torque and no-load
    speed (torque falls linearly to zero at the no-load speed), so both datasheet numbers hold.
    """

    kp_nm_per_rad: float
    stall_torque_nm: float
    no_load_speed_rad_s: float
    armature_kgm2: float
    friction_loss_nm: float
    # Explicit joint damping (N·m·s/rad); None (default) = the back-EMF line above. Used by the
    # calibration (tkujax.studies.calibrate) to fit e.g. BAM's identified 0.66 for the MX-64.
    damping_override_nms_per_rad: float | None = None

    @property
    def damping_nms_per_rad(self) -> float:
        if self.damping_override_nms_per_rad is not None:
            return self.damping_override_nms_per_rad
        return self.stall_torque_nm / self.no_load_speed_rad_s


RPM = 2.0 * math.pi / 60.0

# MX-64, legs. kp: BAM duty = err*P*0.158 at P=32, torque = kt*12V/R*duty -> 24.9 N·m/rad.
# Stall 6.0 N·m, 63 rpm [DS]; armature 0.012 kg·m², Coulomb friction 0.09 N·m [BAM].
MX64 = ServoParams(kp_nm_per_rad=24.9, stall_torque_nm=6.0, no_load_speed_rad_s=63 * RPM,
                   armature_kgm2=0.012, friction_loss_nm=0.09)
# MX-28, arms/head/waist. Stall 2.5 N·m, 55 rpm [DS]; kp by the same firmware law scaled to
# its stall torque (0.158*32*2.5); armature and friction [est] (smaller motor, 193:1).
MX28 = ServoParams(kp_nm_per_rad=12.6, stall_torque_nm=2.5, no_load_speed_rad_s=55 * RPM,
                   armature_kgm2=0.005, friction_loss_nm=0.05)
# The legs' MX-64 as calibrated [fit]: effective stiffness 16.8 N·m/rad (bound 8-32: P = 32 in
# series with ~50 N·m/rad of gear/horn/bracket compliance; pinned by the 0.6 s wavering
# recoveries without control) and damping 0.868 N·m·s/rad (bound 0.5-1.0, between BAM's 0.66
# and the back-EMF 0.909; not pinned by the data).
MX64_FIT = dataclasses.replace(MX64, kp_nm_per_rad=16.8, damping_override_nms_per_rad=0.868)

MODEL_VARIANTS = ("calibrated", "estimated")
# The earlier estimate of every [fit] field (ModelParams.estimated()).
ESTIMATED = dict(foot_length_m=0.140, foot_forward_offset_m=0.010, pelvis_mass_kg=0.60,
                 chest_mass_kg=0.85, leg_mass_kg=1.025, chest_com_frac=0.5, leg_servo=MX64,
                 accel_lowpass_hz=0.0)


@dataclasses.dataclass(frozen=True)
class ModelParams:
    """Geometry (m), masses (kg) and options of the TKU-X model. Defaults: see module doc."""

    # --- heights, sole to head top in the straight pose; they add up to the paper's 564.5 mm.
    ankle_height_m: float = 0.035        # [est] ankle axis above sole (OP3 ~30, Darwin 33.5 mm)
    calf_length_m: float = 0.110         # [est] knee to ankle (Darwin 93, OP3 110 mm, scaled)
    thigh_length_m: float = 0.110        # [est] hip to knee
    pelvis_height_m: float = 0.040       # [est] hip axis to waist-yaw joint
    chest_height_m: float = 0.160        # [est] waist-yaw joint to neck (FPGA board 112 mm
    #                                      + battery)
    neck_height_m: float = 0.020         # [est] neck to head bottom
    head_radius_m: float = 0.04475       # [est] head as a sphere; closes the 564.5 mm [paper]
    # --- widths and the foot
    hip_offset_y_m: float = 0.045        # [est] d_y, waist centre to hip joint (OP3 35+19,
    #                                      Darwin 37)
    torso_half_width_m: float = 0.060    # [est]
    torso_half_depth_m: float = 0.045    # [est]
    shoulder_offset_y_m: float = 0.080   # [est]
    upper_arm_length_m: float = 0.100    # [est]
    forearm_length_m: float = 0.110      # [est]
    foot_length_m: float = 0.151         # [fit] bound 100-160 mm (est 140; Sigmaban 158, OP3 127)
    foot_width_m: float = 0.085          # [est]
    # [fit] foot centre ahead of the ankle axis, bound +-35 mm (est +10 mm): the toe is 48 mm
    # ahead of the ankle, the heel 103 mm behind. Pinned by the fall / no-fall rows.
    foot_forward_offset_m: float = -0.0274
    # --- masses; the segments must add up to total_mass_kg.
    total_mass_kg: float = 4.5           # [paper]
    pelvis_mass_kg: float = 0.7134       # [fit] pelvis plate + waist servo (est 0.60)
    chest_mass_kg: float = 0.7426        # [fit] FPGA board, circuit board, battery (est 0.85);
                                         # chest share of pelvis + chest 0.51, bound 0.45-0.80
    head_mass_kg: float = 0.25           # [est] 2 MX-28 + CMOS camera
    arm_mass_kg: float = 0.375           # [est] each: 4 MX-28 (0.3 kg) + brackets
    leg_mass_kg: float = 1.022           # [fit] each: 6 MX-64 (0.78 kg) + brackets + foot;
                                         # bound 0.92-1.10 (est 1.025)
    # Fractions of one leg's mass, hip-yaw link .. foot (servo placement: hip yaw, hip roll+pitch
    # block, thigh, shin+knee, ankle block, foot). [est]
    leg_mass_fractions: tuple[float, ...] = (0.12, 0.13, 0.24, 0.24, 0.13, 0.14)
    # Height of the chest CoM as a fraction of chest_height_m above the waist joint (0.5 = the
    # box centre) [fit], bound 0.3-0.8 (est 0.5; not pinned by the data).
    chest_com_frac: float = 0.526
    # --- stand posture
    stand_lean_deg: float = 7.0          # [paper] upper body leans forward ~7 deg
    stand_hip_to_ankle_m: float = 0.200  # [est] d_z in the stand pose (knees bent, IK margin)
    # --- contact and simulation
    floor_friction: float = 1.0          # [est] rubber sole on a hard floor
    timestep_s: float = 0.002            # 2 ms (Playground humanoids)
    solver_iterations: int = 1           # Newton, 1 iteration: reverse-mode differentiable
    ls_iterations: int = 4
    # --- the IMU's own low-pass (a MEMS sensor's digital low-pass filter, e.g. the MPU-6050's
    # DLPF at 5-260 Hz), first order, applied per physics step before the controller samples
    # the reading every 30 ms. 0 = none: the controller reads the instantaneous value.
    # Accelerometer: [fit] 7.5 Hz: all 8 paper rows hold at all 15 hit phases from <= 5 to
    # 8 Hz, and over 3 contact times too from 7 Hz (results/calibration/imu_bandwidth; the
    # paper gives no sensor, the MPU-6050's DLPF offers 5 and 10 Hz). Unfiltered,
    # the 30 ms sample catches the 20 ms ball pulse at some phases and not at others, and reads
    # its linear acceleration as a lean (a push from the front as a forward lean). Gyro: [est]
    # none (a rate gyro's bandwidth is far above the robot's motion).
    accel_lowpass_hz: float = 7.5
    gyro_lowpass_hz: float = 0.0
    leg_servo: ServoParams = MX64_FIT
    arm_servo: ServoParams = MX28

    @classmethod
    def estimated(cls, **overrides) -> ModelParams:
        """The model before calibration: every [fit] field at its earlier [est] value."""
        return dataclasses.replace(cls(**overrides), **{**ESTIMATED, **overrides}).validate()

    def validate(self) -> ModelParams:
        """Raise ValueError naming the first bad field; return self."""
        signed = {"foot_forward_offset_m"}   # a signed offset, checked below
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name in signed:
                continue
            if f.name.endswith(("_m", "_kg")) and not (isinstance(value, (int, float))
                                                     and math.isfinite(value) and value > 0):
                raise ValueError(f"ModelParams.{f.name} must be a positive finite number, "
                                 f"got {value!r}")
        fr = self.leg_mass_fractions
        if len(fr) != 6 or any(x <= 0 for x in fr) or abs(sum(fr) - 1.0) > 1e-6:
            raise ValueError("ModelParams.leg_mass_fractions must be 6 positive numbers summing "
                             f"to 1, got {fr!r} (sum {sum(fr):.6f})")
        parts = (self.pelvis_mass_kg + self.chest_mass_kg + self.head_mass_kg
                 + 2 * self.arm_mass_kg + 2 * self.leg_mass_kg)
        if abs(parts - self.total_mass_kg) > 1e-6 * self.total_mass_kg + 1e-9:
            raise ValueError(
                "ModelParams mass split does not add up: pelvis + chest + head + 2*arm + 2*leg "
                f"= {parts:.4f} kg but total_mass_kg = {self.total_mass_kg:.4f} kg")
        leg = self.thigh_length_m + self.calf_length_m
        if not (0.5 * leg <= self.stand_hip_to_ankle_m < leg):
            raise ValueError(f"ModelParams.stand_hip_to_ankle_m must be in [{0.5 * leg:.3f}, "
                             f"{leg:.3f}) m (half to full leg length), got "
                             f"{self.stand_hip_to_ankle_m!r}")
        if not (-20.0 <= self.stand_lean_deg <= 20.0):
            raise ValueError(f"ModelParams.stand_lean_deg must be in [-20, 20] deg, "
                             f"got {self.stand_lean_deg!r}")
        if not (0.1 <= self.chest_com_frac <= 0.9):
            raise ValueError(f"ModelParams.chest_com_frac must be in [0.1, 0.9], "
                             f"got {self.chest_com_frac!r}")
        if not (0.0005 <= self.timestep_s <= 0.01):
            raise ValueError(f"ModelParams.timestep_s must be in [0.0005, 0.01] s, "
                             f"got {self.timestep_s!r}")
        if not (0.0 < self.floor_friction <= 3.0):
            raise ValueError(f"ModelParams.floor_friction must be in (0, 3], "
                             f"got {self.floor_friction!r}")
        if self.solver_iterations < 1 or self.ls_iterations < 1:
            raise ValueError("ModelParams.solver_iterations and ls_iterations must be >= 1")
        nyquist_hz = 0.5 / self.timestep_s
        for name in ("accel_lowpass_hz", "gyro_lowpass_hz"):
            hz = getattr(self, name)
            if not (isinstance(hz, (int, float)) and (hz == 0.0 or 1.0 <= hz <= nyquist_hz)):
                raise ValueError(f"ModelParams.{name} must be 0 (no filter) or in [1, "
                                 f"{nyquist_hz:g}] Hz (the physics step's Nyquist), got {hz!r}")
        off = self.foot_forward_offset_m
        if not (isinstance(off, (int, float)) and abs(off) < 0.5 * self.foot_length_m):
            raise ValueError("ModelParams.foot_forward_offset_m must be in (-foot_length_m/2, "
                             f"foot_length_m/2) = (+-{0.5 * self.foot_length_m:g}) m, got {off!r}")
        return self

    @classmethod
    def from_overrides(cls, items: list[str] | dict, variant: str = "calibrated") -> ModelParams:
        """ModelParams with `KEY=VALUE` overrides (CLI) or a {key: value} dict; validated.
        variant: the base, "calibrated" (ModelParams()) or "estimated" (ModelParams.estimated()).

        Unknown keys and non-numbers raise ValueError naming the key."""
        if variant not in MODEL_VARIANTS:
            raise ValueError(f"model variant must be one of {MODEL_VARIANTS}, got {variant!r}")
        pairs = items.items() if isinstance(items, dict) else [_split(i) for i in items]
        numeric = {f.name: f.type for f in dataclasses.fields(cls)
                   if f.name not in ("leg_mass_fractions", "leg_servo", "arm_servo")}
        values = {}
        for key, value in pairs:
            if key not in numeric:
                raise ValueError(f"unknown model parameter {key!r}; allowed: {sorted(numeric)}")
            try:
                values[key] = (int(value) if numeric[key] in ("int", int) else float(value))
            except (TypeError, ValueError):
                raise ValueError(f"model parameter {key} must be a number, got {value!r}") from None
        base = cls.estimated() if variant == "estimated" else cls()
        return dataclasses.replace(base, **values).validate()

    def imu_lowpass_alpha(self, name: str) -> float:
        """Per-physics-step gain of the first-order IMU filter `name` ("accel" or "gyro"):
        y += alpha (x - y), alpha = 1 - exp(-2 pi f_c dt), the exact discretisation of the RC
        filter for an input held over each step. 0 when the filter is off."""
        hz = getattr(self, f"{name}_lowpass_hz")
        return 0.0 if hz == 0.0 else 1.0 - math.exp(-2.0 * math.pi * hz * self.timestep_s)

    @property
    def height_m(self) -> float:
        """Sole to top of head in the straight pose."""
        return (self.ankle_height_m + self.calf_length_m + self.thigh_length_m
                + self.pelvis_height_m + self.chest_height_m + self.neck_height_m
                + 2 * self.head_radius_m)


def _split(item: str) -> tuple[str, str]:
    if "=" not in item:
        raise ValueError(f"model override must be KEY=VALUE, got {item!r}")
    key, value = item.split("=", 1)
    return key.strip(), value.strip()
