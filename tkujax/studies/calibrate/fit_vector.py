"""The fitted parameter vector: names, physically plausible bounds (with reasons), and its
mapping to ModelParams, ControllerParams and the ball pushes.

Hard constraints hold by construction: the mass split keeps 4.5 kg exactly (legs, arms and head
fixed or compensated inside the pelvis + chest), no length that enters the 564.5 mm height is
touched, the servo torque/speed limits are the datasheet ones; the 7 deg +- 1 deg settled stand
lean is checked by the loss (targets.STAND_LEAN_DEG).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams


@dataclasses.dataclass(frozen=True)
class Param:
    name: str
    lo: float
    hi: float
    default: float      # today's estimate (the value of ModelParams() / ControllerParams.paper())
    log: bool = False   # searched in log10 space
    why: str = ""


PARAMS = (
    Param("foot_forward_offset_m", -0.035, 0.035, 0.010, why=
          "foot centre vs ankle axis: the ankle anywhere in the middle half of the sole "
          "(+-L/4 of a 140 mm foot); sets the toe and heel margins"),
    Param("foot_length_m", 0.10, 0.16, 0.140, why=
          "Darwin-OP 104, OP3 127, Sigmaban 158 mm (kid-size humanoids of this height)"),
    Param("leg_kp", 8.0, 32.0, 24.9, why=
          "effective MX-64 stiffness N·m/rad: firmware P=32 gives 24.9 [BAM]; up to P=41, down "
          "to P=32 in series with a ~12 N·m/rad gear/horn/bracket compliance plus the 0.33 deg "
          "backlash (not modelled explicitly)"),
    Param("leg_damping", 0.5, 1.0, 0.909, why=
          "MX-64 joint damping N·m·s/rad: BAM identified 0.66, the datasheet line gives 0.909; "
          "+-25 % around that range"),
    Param("chest_com_frac", 0.3, 0.8, 0.5, why=
          "chest CoM height as a fraction of the 160 mm chest (battery low .. board high)"),
    Param("leg_mass_kg", 0.92, 1.10, 1.025, why=
          "one leg: 6 MX-64 = 0.78 kg + brackets and foot >= 0.14 kg; the difference goes to "
          "the pelvis + chest so the total stays 4.5 kg"),
    Param("chest_share", 0.45, 0.80, 0.85 / 1.45, why=
          "chest share of pelvis + chest mass (pelvis >= 0.2 kg: waist MX-28 + plate)"),
    Param("push_height_m", 0.28, 0.43, 0.36, why=
          "ball contact height: anywhere on the chest (0.275-0.435 m in the stand pose)"),
    Param("impulse_factor", 0.9, 1.5, 1.0, why=
          "impulse delivered / ball momentum m·v = (1+e)/(1+m/M_eff), restitution e 0.2-0.6, "
          "effective robot mass at the chest 1-4.5 kg; tkujax.sim.ball_rig's rig gives 1.02-1.12"),
    Param("kalman_q", -5.0, -3.0, -4.0, log=True, why=
          "Kalman process noise rad^2 per 30 ms (log10): gyro noise and drift, (0.18-1.8 deg)^2"),
    Param("kalman_r", -3.5, -1.5, math.log10(3e-3), log=True, why=
          "accelerometer-angle variance rad^2 (log10): (1-10 deg)^2"),
    # The hit from the front, relative to the hit from behind (push_height_m, impulse_factor
    # describe the latter): the ball meets the chest's back and front, whose shapes and
    # stiffness differ, and the paper gives neither contact. Neutral values: one hit for both.
    Param("front_height_offset_m", -0.05, 0.05, 0.0, why=
          "the front hit's contact height minus the back hit's (the chest's front and back "
          "differ in shape; the paper gives neither height)"),
    Param("front_impulse_ratio", 0.8, 1.25, 1.0, why=
          "the front hit's impulse factor / the back hit's (restitution and effective mass at "
          "the chest's front vs its back)"),
)
# Names whose value above changes nothing (the model before they existed): archives and specs
# written before them lack them, and read as these values (`complete`).
NEUTRAL = {"front_height_offset_m": 0.0, "front_impulse_ratio": 1.0}
NAMES = tuple(p.name for p in PARAMS)
# What a fit moves unless it names its parameters: all but the NEUTRAL ones (added later).
DEFAULT_FIT = tuple(n for n in NAMES if n not in NEUTRAL)
LO = np.array([p.lo for p in PARAMS])
HI = np.array([p.hi for p in PARAMS])
DEFAULT = np.array([p.default for p in PARAMS])

# The readings of Algorithm 1 (model selection): which angle enters Eq. 7-10, and whether x_Sup is
# latched at the first detection or updated until the swing starts (gamma T / 2 = 30 ms).
READINGS = {
    "deviation/latched": dict(cp_excess=0.0, cp_update_window=0.0),
    "deviation/updated": dict(cp_excess=0.0, cp_update_window=0.03),
    "excess/latched": dict(cp_excess=1.0, cp_update_window=0.0),
    "excess/updated": dict(cp_excess=1.0, cp_update_window=0.03),
    "absolute/latched": dict(cp_excess=0.0, cp_update_window=0.0, cp_angle_offset=0.0),
}


def to_unit(x: np.ndarray) -> np.ndarray:
    return (np.asarray(x, float) - LO) / (HI - LO)


def from_unit(u: np.ndarray) -> np.ndarray:
    return LO + np.clip(np.asarray(u, float), 0.0, 1.0) * (HI - LO)


def as_dict(x: np.ndarray) -> dict:
    return {n: float(v) for n, v in zip(NAMES, x)}


def complete(x: dict) -> dict:
    """x with the NEUTRAL names it lacks (a candidate archived before they existed)."""
    return {**NEUTRAL, **x}


def model_params(x) -> ModelParams:
    v = as_dict(x) if not isinstance(x, dict) else x
    base = ModelParams()
    leg = float(v["leg_mass_kg"])
    rest = base.total_mass_kg - 2 * leg - 2 * base.arm_mass_kg - base.head_mass_kg
    chest = round(v["chest_share"] * rest, 9)
    pelvis = rest - chest
    servo = dataclasses.replace(base.leg_servo, kp_nm_per_rad=float(v["leg_kp"]),
                                damping_override_nms_per_rad=float(v["leg_damping"]))
    return dataclasses.replace(
        base, foot_forward_offset_m=float(v["foot_forward_offset_m"]),
        foot_length_m=float(v["foot_length_m"]), chest_com_frac=float(v["chest_com_frac"]),
        leg_mass_kg=leg, chest_mass_kg=chest, pelvis_mass_kg=pelvis, leg_servo=servo).validate()


def controller_params(x, reading: str, model: ModelParams | None = None) -> ControllerParams:
    v = as_dict(x) if not isinstance(x, dict) else x
    p = ControllerParams.paper(model if model is not None else model_params(v))
    q = 10 ** v["kalman_q"] if PARAMS[NAMES.index("kalman_q")].log else v["kalman_q"]
    r = 10 ** v["kalman_r"] if PARAMS[NAMES.index("kalman_r")].log else v["kalman_r"]
    return dataclasses.replace(p, kalman_q=float(q), kalman_r=float(r),
                               **READINGS[reading]).validate()


def base_vector() -> np.ndarray:
    """The vector of today's default model and controller (ModelParams(), ControllerParams()):
    the values of the parameters a calibration holds fixed. Read from the dataclasses rather than
    DEFAULT, so it follows the default model when that changes."""
    from tkujax.sim.push import BallContact

    m, c, ball = ModelParams(), ControllerParams(), BallContact()
    v = dict(foot_forward_offset_m=m.foot_forward_offset_m, foot_length_m=m.foot_length_m,
             leg_kp=m.leg_servo.kp_nm_per_rad, leg_damping=m.leg_servo.damping_nms_per_rad,
             chest_com_frac=m.chest_com_frac, leg_mass_kg=m.leg_mass_kg,
             chest_share=m.chest_mass_kg / (m.chest_mass_kg + m.pelvis_mass_kg),
             push_height_m=ball.height_m, impulse_factor=ball.impulse_factor,
             kalman_q=math.log10(c.kalman_q), kalman_r=math.log10(c.kalman_r),
             front_height_offset_m=ball.front_height_offset_m,
             front_impulse_ratio=ball.front_impulse_ratio)
    return np.array([float(v[n]) for n in NAMES])
