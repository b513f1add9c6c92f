"""Controller parameters of the Liu et al. 2020 balance controller, as one JAX pytree.

Every field is a data leaf (a Python float or a JAX scalar), so a jitted controller can be
called with different parameter *values* without recompiling, and `jax.grad` can
differentiate with respect to any of them. SI units and radians throughout.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np

# The controller's period (paper Sec. 4: 30 ms; it ticks at t = k * period), every robot's: the
# rollout's RolloutConfig.control_period_s, which sets `ControllerParams.control_period` for
# the controller it runs. A parameter file may restate it, never change it (`validate`).
CONTROL_PERIOD_S = 0.030


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ControllerParams:
    """Parameters of the balance controller (Sec. 3, Table 2, Sec. 4 of the paper).

    Timing
      control_period        s      controller and Kalman sampling time (30 ms, Sec. 4): the
                                   rollout's period (RolloutConfig.control_period_s, which the
                                   rollout writes here), not a free parameter: `validate`
                                   admits CONTROL_PERIOD_S only.
      step_period           s      T, duration of the recovery step (0.3 s, Sec. 3.3).
      double_support_ratio  -      gamma, double-support share of T (0.2, Sec. 3.3).
      lift_height           m      H_Sup, swing-foot lift (3 cm, Sec. 3.3).
    Push detection / capture point (Sec. 3.2, Sec. 4)
      eps_forward           rad    epsilon_1: push from the back when phi > eps_forward (12 deg).
      eps_backward          rad    epsilon_2: push from the front when phi < -eps_backward (2 deg).
      standing_lean         rad    inclination of the standing robot (leans ~7 deg forward).
      cp_angle_offset       rad    subtracted from phi before Eq. 7-10, so the capture point uses
                                   the deviation from the standing lean. Default = standing_lean;
                                   0 gives the paper's literal absolute angle. The paper is
                                   ambiguous; which one reproduces it is decided in the
                                   integration, with the step lengths of Tables 4-5 (1.09-4.15 cm)
                                   as evidence. For reference (l = 0.27 m, h = 0.29 m), x_Sup ~=
                                   0.55 m/rad * angle for small angles: the absolute angle gives
                                   >= 11.3 cm forward at the 12 deg threshold and >= 1.9 cm
                                   backward at -2 deg; the deviation gives >= 4.8 cm / >= 8.6 cm.
      cp_excess             -      0 (default): the angle of Eq. 7-10 is phi - cp_angle_offset;
                                   1: it is the excess over the threshold that was crossed,
                                   phi - eps_forward forward, phi + eps_backward backward (one of
                                   the readings of Algorithm 1 compared by
                                   tkujax.studies.calibrate).
      cp_update_window      s      0 (default): x_Sup is latched at the first detection; > 0: it
                                   is recomputed from the current angle each period while the
                                   step is at most this old and the push is still detected
                                   (gamma T / 2 = "updated until the swing starts").
      cp_gain               -      multiplies x_Sup (1.0 = paper).
      gate_temperature      rad    0: hard threshold gate (Algorithm 1); > 0: sigmoid gate width.
      gravity               m/s^2  g of Eq. 6 and 10.
    Kalman filter (Sec. 3.1, Eq. 1-2), scalar model A = 1, B = control_period, H = 1
      kalman_q              rad^2  process noise variance added per control period: gyro noise
                                   and bias drift over one 30 ms step. [fit] 2.35e-4 =
                                   (0.88 deg)^2, bound 1e-5..1e-3 (estimate 1e-4).
      kalman_r              rad^2  variance of the accelerometer inclination, including the error
                                   from the robot's own accelerations. [fit] 2.3e-3 =
                                   (2.7 deg)^2, bound 3e-4..3e-2 (estimate 3e-3). q/r ~ 0.1
                                   gives a steady-state gain ~0.27. Both fitted by
                                   tkujax.studies.calibrate; they are weakly pinned (they move
                                   the Kalman peak by ~1 deg over their whole range).
                                   KALMAN_ESTIMATED holds the estimate.
      accel_gate            m/s^2  robust detection (tkujax extension; 0 = off, the paper): the
                                   accelerometer's R is inflated by (1 + ((|a| - g)/accel_gate)^2)
                                   so that samples taken during an impact barely move the angle
                                   (`kalman.accel_variance`). A float leaf: traceable, gridable.
    Recovery extensions (tkujax; every default is "off" and gives the paper's controller)
      cp_rate_blend         -      weight of the MEASURED pitch/roll rate (gyro) in Eq. 8 against
                                   the energy-balance rate of Eq. 9-10: phidot = (1 - b) phidot_E
                                   + b phidot_gyro (Pratt 2006, Englsberger 2011). 0 = paper.
      cp_lookahead_s        s      step to the capture point predicted this far ahead by the LIP,
                                   xi(t) = xi0 exp(omega t), omega = sqrt(g/h) (Koolen 2012);
                                   0 = off.
      cp_trigger            -      0 (paper): step when phi leaves (-eps_2, eps_1); 1: step when
                                   the rate-aware capture point leaves the support, i.e. exceeds
                                   cp_trigger_forward_m ahead of / cp_trigger_backward_m behind
                                   the ankle (and cp_trigger_lateral_m sideways, with lateral
                                   steps): no step while standing still would survive.
      cp_trigger_forward_m  m      forward trigger distance (the default toe is ~48 mm ahead).
      cp_trigger_backward_m m      backward trigger distance (the default heel is ~103 mm behind).
      cp_trigger_lateral_m  m      sideways trigger distance (outer sole edge ~ d_y + 42 mm).
      cp_gain_lateral       -      multiplies the sideways part of the first step, y_Sup, on top
                                   of cp_gain (with lateral steps). 1 (default): the foot on the
                                   falling side steps toward the capture point. Negative: the
                                   foot on the push's side, the unloaded one, steps outward by
                                   |cp_gain_lateral| times that distance, widening the stance,
                                   while the support hip moves the waist back toward the push
                                   (the widening step: on OP3 the step toward the capture point
                                   adds falls and this one saves some; results/op3/README.md).
                                   Later steps take it too (their sideways part moves a foot
                                   outward only, so the other foot's next step is sagittal).
      stance_ankle_kp       rad/rad      ankle-pitch feedback on the pitch deviation
                                   phi - standing_lean, added to both ankles, before and after
                                   the step (the ankle strategy); 0 = paper.
      stance_ankle_kd       rad/(rad/s)  ankle-pitch feedback on the gyro pitch rate.
      stance_hip_kp         rad/rad      hip-pitch feedback on the pitch deviation (hip strategy).
      stance_hip_kd         rad/(rad/s)  hip-pitch feedback on the gyro pitch rate.
      stance_roll_kp        rad/rad      ankle-roll feedback on the roll (both ankles).
      stance_roll_kd        rad/(rad/s)  the same on the gyro roll rate.
      stance_limit          rad    bound of each stance offset (a smooth tanh saturation).
      step_shift_m          m      the waist's shift toward the support foot during the first
                                   (or commanded) recovery step: a half-cosine ramp over the
                                   first double support, held through the swing, back over the
                                   last (`cpg.support_shift`); 0 = paper. A heavy robot needs it
                                   to lift a foot at all (Booster T1 rolls over the lifted foot
                                   without it; tests/test_weight_shift.py).
      max_steps             -      1 (paper): one step; 2 or 3: once a step has finished and the
                                   capture point is still beyond the new support's edge (the
                                   trigger distances from the front / rear foot), the other foot
                                   steps again, up to max_steps steps.
    Geometry (Fig. 3, Fig. 7, Fig. 11); defaults are the default model's numbers
      hip_offset_y          m      d_y, waist P_W to hip joint centre (lateral).
      hip_to_ankle_z        m      d_z, hip joint centre to ankle centre in the stand pose.
      thigh_length          m      l_t.
      calf_length           m      l_c.
      leg_length            m      l, ankle-to-CoM distance of the pendulum (Eq. 7-10).
      com_height            m      h, CoM height (Eq. 6).
    """

    control_period: float = CONTROL_PERIOD_S
    step_period: float = 0.3
    double_support_ratio: float = 0.2
    lift_height: float = 0.03
    eps_forward: float = math.radians(12.0)
    eps_backward: float = math.radians(2.0)
    standing_lean: float = math.radians(7.0)
    cp_angle_offset: float = math.radians(7.0)
    cp_excess: float = 0.0
    cp_update_window: float = 0.0
    cp_gain: float = 1.0
    gate_temperature: float = 0.0
    lateral_steps: float = 0.0
    eps_lateral: float = math.radians(4.0)
    gravity: float = 9.81
    kalman_q: float = 2.35e-4
    kalman_r: float = 2.3e-3
    accel_gate: float = 0.0
    cp_rate_blend: float = 0.0
    cp_lookahead_s: float = 0.0
    cp_trigger: float = 0.0
    cp_trigger_forward_m: float = 0.05
    cp_trigger_backward_m: float = 0.10
    cp_trigger_lateral_m: float = 0.09
    cp_gain_lateral: float = 1.0
    stance_ankle_kp: float = 0.0
    stance_ankle_kd: float = 0.0
    stance_hip_kp: float = 0.0
    stance_hip_kd: float = 0.0
    stance_roll_kp: float = 0.0
    stance_roll_kd: float = 0.0
    stance_limit: float = 0.3
    max_steps: float = 1.0
    step_shift_m: float = 0.0
    hip_offset_y: float = 0.045
    hip_to_ankle_z: float = 0.20
    thigh_length: float = 0.11
    calf_length: float = 0.11
    leg_length: float = 0.27
    com_height: float = 0.29

    @classmethod
    def paper(cls, model_params=None, variant: str = "calibrated") -> ControllerParams:
        """The paper's values, with the geometry of the TKU-X model (default: the default one).
        variant "estimated": the Kalman noises before calibration (KALMAN_ESTIMATED)."""
        if variant not in ("calibrated", "estimated"):
            raise ValueError(f"variant must be 'calibrated' or 'estimated', got {variant!r}")
        # Imported here: the model package is heavier and not needed by the pure math.
        from tkujax.model import leg_geometry, pendulum_lengths

        geo = leg_geometry(model_params)
        leg_length, com_height = pendulum_lengths(model_params)
        p = dataclasses.replace(
            cls(),
            hip_offset_y=float(geo.d_y), hip_to_ankle_z=float(geo.d_z),
            thigh_length=float(geo.thigh), calf_length=float(geo.calf),
            leg_length=float(leg_length), com_height=float(com_height),
            **(KALMAN_ESTIMATED if variant == "estimated" else {}))
        return p.validate()

    @classmethod
    def recommended(cls, model_params=None) -> ControllerParams:
        """The recommended recovery controller: the paper's architecture with the recovery
        extensions on (rate-aware capture point and trigger, stance feedback, up to two steps,
        sideways steps, the accelerometer gate), tuned by CMA-ES through MJX, last over the
        calibration's ensemble of 39 plausible robots with the no-harm weight
        (`tkujax tune specs/tune/tune_recovery_ensemble.toml`, NVIDIA H100;
        results/tune_recovery_ensemble/, whose params_after.json holds these values).
        Geometry and Kalman noises as `paper`."""
        return dataclasses.replace(cls.paper(model_params), **RECOMMENDED).validate()

    def validate(self) -> ControllerParams:
        """Check ranges on concrete values; raises ValueError naming the field. Returns self.

        For use at the edges (construction, configuration), not inside jit: traced fields
        cannot be checked and raise TypeError.
        """

        def val(name: str) -> float:
            v = getattr(self, name)
            if isinstance(v, jax.core.Tracer):
                raise TypeError(f"ControllerParams.validate() needs concrete values; "
                                f"{name} is traced (call it outside jit)")
            a = np.asarray(v)
            if a.shape != ():
                raise ValueError(f"ControllerParams.{name} must be a scalar, got shape {a.shape}")
            return float(a)

        def check(name: str, ok, rng: str) -> None:
            v = val(name)
            # `not ok(v)` also rejects NaN, whose comparisons are all False.
            if not ok(v):
                raise ValueError(f"ControllerParams.{name} must be in {rng}, got {v!r}")

        half_pi = math.pi / 2
        check("control_period", lambda v: math.isclose(v, CONTROL_PERIOD_S, rel_tol=0.0,
                                                       abs_tol=1e-12),
              f"{{{CONTROL_PERIOD_S}}} s (the robot's control period, the rollout's; leave the "
              "key out)")
        check("step_period", lambda v: 0.0 < v <= 2.0, "(0, 2] s")
        check("double_support_ratio", lambda v: 0.0 <= v < 0.9, "[0, 0.9)")
        check("lift_height", lambda v: 0.0 <= v <= 0.1, "[0, 0.1] m")
        check("eps_forward", lambda v: 0.0 <= v < half_pi, "[0, pi/2) rad")
        check("eps_backward", lambda v: 0.0 <= v < half_pi, "[0, pi/2) rad")
        check("standing_lean", lambda v: -half_pi < v < half_pi, "(-pi/2, pi/2) rad")
        check("cp_angle_offset", lambda v: -half_pi < v < half_pi, "(-pi/2, pi/2) rad")
        check("cp_excess", lambda v: v in (0.0, 1.0), "{0, 1}")
        check("cp_update_window", lambda v: 0.0 <= v <= 2.0, "[0, 2] s")
        check("cp_gain", lambda v: 0.0 <= v <= 10.0, "[0, 10]")
        check("cp_gain_lateral", lambda v: -3.0 <= v <= 3.0, "[-3, 3]")
        check("step_shift_m", lambda v: 0.0 <= v <= 0.25, "[0, 0.25] m")
        check("gate_temperature", lambda v: 0.0 <= v <= 1.0, "[0, 1] rad")
        check("lateral_steps", lambda v: v in (0.0, 1.0), "{0, 1}")
        check("eps_lateral", lambda v: 0.0 <= v < half_pi, "[0, pi/2) rad")
        check("gravity", lambda v: 0.0 < v < 100.0, "(0, 100) m/s^2")
        check("kalman_q", lambda v: 0.0 <= v < math.inf, "[0, inf) rad^2")
        check("kalman_r", lambda v: 0.0 < v < math.inf, "(0, inf) rad^2")
        check("accel_gate", lambda v: 0.0 <= v <= 100.0, "[0, 100] m/s^2 (0 = off)")
        check("cp_rate_blend", lambda v: 0.0 <= v <= 1.0, "[0, 1]")
        check("cp_lookahead_s", lambda v: 0.0 <= v <= 0.5, "[0, 0.5] s")
        check("cp_trigger", lambda v: v in (0.0, 1.0), "{0, 1}")
        for name in ("cp_trigger_forward_m", "cp_trigger_backward_m", "cp_trigger_lateral_m"):
            check(name, lambda v: 0.0 <= v <= 0.5, "[0, 0.5] m")
        for name in ("stance_ankle_kp", "stance_hip_kp", "stance_roll_kp"):
            check(name, lambda v: -5.0 <= v <= 5.0, "[-5, 5] rad/rad")
        for name in ("stance_ankle_kd", "stance_hip_kd", "stance_roll_kd"):
            check(name, lambda v: -1.0 <= v <= 1.0, "[-1, 1] rad/(rad/s)")
        check("stance_limit", lambda v: 0.0 < v <= 1.0, "(0, 1] rad")
        check("max_steps", lambda v: v in (1.0, 2.0, 3.0), "{1, 2, 3}")
        for name in ("hip_offset_y", "thigh_length", "calf_length", "leg_length", "com_height"):
            check(name, lambda v: 0.0 < v <= 2.0, "(0, 2] m")
        reach = val("thigh_length") + val("calf_length")
        check("hip_to_ankle_z", lambda v: 0.0 < v <= reach,
              f"(0, thigh_length + calf_length] = (0, {reach:g}] m")
        return self


# ControllerParams' fields by meaning, each in one group (the pytree stays flat: parameter
# files, manifests and spec hashes name the fields as they are):
#   TIMING_FIELDS    the rollout's period (validate admits CONTROL_PERIOD_S only);
#   PHYSICAL_FIELDS  the world's constants;
#   GEOMETRY_FIELDS  what the robot gives: measured from a robot file's model at its stand
#                    (tkujax.robot.geometry), TKU-X's from its ModelParams (`paper`);
#   MODE_FIELDS      discrete switches ({0, 1}; max_steps {1, 2, 3}): floats selected by `where`
#                    inside the controller, so one compiled program serves every setting;
#   GAIN_FIELDS      the rest: thresholds, gains, timings and noises (tuned, scheduled, traced).
TIMING_FIELDS = ("control_period",)
PHYSICAL_FIELDS = ("gravity",)
GEOMETRY_FIELDS = ("standing_lean", "hip_offset_y", "hip_to_ankle_z", "thigh_length",
                   "calf_length", "leg_length", "com_height")
MODE_FIELDS = ("cp_excess", "lateral_steps", "cp_trigger", "max_steps")
GAIN_FIELDS = tuple(f.name for f in dataclasses.fields(ControllerParams)
                    if f.name not in TIMING_FIELDS + PHYSICAL_FIELDS + GEOMETRY_FIELDS
                    + MODE_FIELDS)


# The Kalman noises before calibration (ControllerParams.paper(..., variant="estimated")).
KALMAN_ESTIMATED = dict(kalman_q=1e-4, kalman_r=3e-3)


# The recommended set (`ControllerParams.recommended()`): the CMA-ES run over the calibration's
# robot ensemble with the no-harm weight, results/tune_recovery_ensemble (values exactly as its
# params_after.json; it started from the third run of results/tune_recovery).
RECOMMENDED = dict(
    step_period=0.2401550468562934,
    double_support_ratio=0.004891208419776472,
    lift_height=0.07852125642359459,
    cp_gain=3.347652426797696,
    lateral_steps=1.0,
    accel_gate=0.06284315875567265,
    cp_rate_blend=0.999576176313371,
    cp_lookahead_s=0.004291368070195955,
    cp_trigger=1.0,
    cp_trigger_forward_m=0.030178805806837915,
    cp_trigger_backward_m=0.2817903883756898,
    cp_trigger_lateral_m=0.15023490028143624,
    stance_ankle_kp=0.23155860265353817,
    stance_ankle_kd=0.09606521460528103,
    stance_hip_kp=0.08718691474956342,
    stance_hip_kd=0.009712262949108139,
    stance_roll_kp=-0.38401757389040403,
    stance_roll_kd=0.08180953998937987,
    max_steps=2.0,
)
