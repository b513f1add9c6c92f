"""The paper's controller composed: Kalman -> detection -> capture point -> CPG -> IK.

`controller_step` runs once per control period (30 ms). While no push is detected it holds the
stand targets; on the first detection it latches x_Sup and executes one recovery step of length
T (Eq. 13-18), then holds the final pose. `enabled` = 0 gives the paper's "disable" rows with
the same compiled function.

Smooth variant: with gate_temperature > 0 the detection gate is a sigmoid; the step weight is
the running max of the gate (w <- max(w, gate)) and x_Sup accumulates the capture point weighted
by each increase of w, so gradients reach the thresholds. The step's start time is still the
discrete instant at which w crosses 1/2; with gate_temperature = 0 all of this is exactly
Algorithm 1.

Sideways pushes (params.lateral_steps = 1, a tkujax extension): the roll is watched too; when
the lateral lean psi = -roll (positive toward +y) leaves (-eps_lateral, eps_lateral) a step is
triggered as well, with y_Sup = capture_point(psi) and the swing foot on the falling side
(`cpg_feet_lateral`). The same single step carries x_Sup (from the pitch) and y_Sup. A negative
params.cp_gain_lateral turns the first step into the widening step: y_Sup changes sign, so the
foot on the push's side steps outward (`ControllerParams` docstring).

Recovery extensions (tkujax; all off in `ControllerParams()` / `.paper()`, which run exactly
Algorithm 1): a rate-aware capture point (`cp_rate_blend`, `cp_lookahead_s`), a capture-point
trigger (`cp_trigger`), stance feedback on the ankles and hips (`stance_*`) and further steps
(`max_steps`). Every option is a traced leaf selected by `where`, so one compiled program
serves every setting. Later steps (2..max_steps) alternate the swing foot and move both feet
from where the last step left them (`later_step_feet`); the first step keeps the paper's CPG.

Step timing with a gradient (a tkujax extension, off by default): with `TimingGradientParams`
(`with_timing_gradient(params)`), the first step's start time is, for the gradient only, the
crossing time interpolated between the two ticks around the trigger: the detection value e
(`detection_value`: how far the trigger quantity is beyond its band, > 0 exactly when the hard
gate fires) was e_prev <= 0 at the previous tick and e > 0 now, so it crossed 0 at the fraction
f = e_prev / (e_prev - e) of the period before this tick. Straight-through: the start time's
value stays the hard controller's (this tick's time; `t + (t_x - stop_gradient(t_x))` adds
exactly 0), its gradient is that of t_x = t - (1 - f) dt. The option is the params' type, read
at trace time (a Python `isinstance`, never a traced branch): plain `ControllerParams` trace
the program they always did, and the state's `detect_prev` is None there.

Step override (a tkujax extension, for capture-region studies): `controller_step(...,
override=StepOverride(...))` sends the one recovery step to a commanded target instead of the
capture point, with the same CPG shape (`cpg_feet_lateral`), IK and servos. Every field is a
traced leaf (vmap/grad over targets); `active` = 0 selects the paper path with `where`, so one
compiled function serves both. `override=None` is the paper path itself (a Python branch on
None, never on a traced value). Detection, x_Sup and y_Sup are still computed and latched
(they record what the controller *would* have done), but they no longer move the feet.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from tkujax.control.capture_point import band_gate, capture_point_rate, push_gate
from tkujax.control.cpg import unit_oscillators, cpg_feet, cpg_feet_lateral
from tkujax.control.kalman import (KalmanState, accel_to_angle, accel_variance, gyro_to_rates,
                                   kalman_init, kalman_step)
from tkujax.control.controller_params import ControllerParams
from tkujax.control.policy import Schedule, recovery_inputs, scheduled_params
from tkujax.control.solve import solve_legs

# Before a step starts its start time is "far in the future": finite so that sin() of the
# (unselected) CPG branch stays finite and gradients through `where` are never NaN.
NOT_STARTED_S = 1.0e4


class Sensors(NamedTuple):
    """What the controller reads each period: gyro (..., 3) rad/s, accel (..., 3) m/s^2."""

    gyro: jax.Array
    accel: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ControllerState:
    """kalman: [pitch, roll] filter; time_s: controller clock; step_weight: 0 before the step,
    1 once triggered (in between only with a soft gate); step_start_s: when it started;
    x_sup_m: the latched step length; phi_at_detect: filtered pitch at the trigger (rad).
    steps: `StepsState`, the bookkeeping of further steps (max_steps > 1). detect_prev: the
    previous tick's `detection_value` with `TimingGradientParams`; None otherwise."""

    kalman: KalmanState
    time_s: jax.Array
    step_weight: jax.Array
    step_start_s: jax.Array
    x_sup_m: jax.Array
    y_sup_m: jax.Array
    phi_at_detect: jax.Array
    steps: StepsState
    detect_prev: jax.Array | None = None


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class TimingGradientParams(ControllerParams):
    """ControllerParams whose first step's start time carries the gradient of the interpolated
    trigger crossing (module docstring). The same fields and forward values."""


def with_timing_gradient(params: ControllerParams) -> TimingGradientParams:
    """params as TimingGradientParams (the same field values)."""
    return TimingGradientParams(**{f.name: getattr(params, f.name)
                                   for f in dataclasses.fields(ControllerParams)})


def has_timing_gradient(params: ControllerParams) -> bool:
    """Whether the step start carries the interpolated crossing's gradient (static)."""
    return isinstance(params, TimingGradientParams)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class StepsState:
    """count: steps started (0, 1, 2, ...); feet_from / feet_to: (4,) ankle displacements from
    the stand pose [x_right, y_right, x_left, y_left] (m) at the start and the end of the
    current step; swing_left: 1 when the left foot swings in the current step."""

    count: jax.Array
    feet_from: jax.Array
    feet_to: jax.Array
    swing_left: jax.Array

    @staticmethod
    def init(dtype=jnp.float32) -> StepsState:
        zero = jnp.zeros((), dtype)
        return StepsState(count=zero, feet_from=jnp.zeros((4,), dtype),
                          feet_to=jnp.zeros((4,), dtype), swing_left=jnp.ones((), dtype))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class StepOverride:
    """A commanded recovery step (all fields scalars; batch by stacking).

    active: 1 = use it, 0 = the controller's own step. x_m, y_m: swing-ankle displacement
    relative to its stand pose (the feet end (x, y) apart relative to the stand; the swing foot
    is the left one when y_m >= 0, else the right one, as `cpg_feet_lateral`). The step starts
    at start_delay_s after the push onset (from_detection = 0) or after the controller's
    detection (from_detection = 1; no detection, no step). period_s: the step period T (<= 0:
    params.step_period). onset_s: the push onset on the controller clock (the rollouts fill it
    in from the Push).

    steps: 1 = one step (the above), 2 = a second commanded step: the first step's support foot
    swings by (x2_m, y2_m) (the same frame as x_m, y_m: +y is left, so a right-foot second step
    widens the stance with y2_m < 0), starting delay2_s after the first touchdown, with the same
    period; it is added to where the first step left the feet (relative to the waist the new
    swing foot moves by +(x2, y2)/2 and the other by -(x2, y2)/2, as in `cpg_feet_lateral`), so
    it lands (x2 - x, y2 - y) from its stand place beside the first step's foot (x2 = 2 x: a
    step as long again); the touchdown becomes the second one. With steps = 1 the x2_m, y2_m,
    delay2_s fields are ignored and the feet are bit-identical to one step.
    """

    active: jax.Array = 1.0
    x_m: jax.Array = 0.0
    y_m: jax.Array = 0.0
    start_delay_s: jax.Array = 0.0
    from_detection: jax.Array = 0.0
    period_s: jax.Array = 0.0
    onset_s: jax.Array = 0.0
    steps: jax.Array = 1.0
    x2_m: jax.Array = 0.0
    y2_m: jax.Array = 0.0
    delay2_s: jax.Array = 0.0


class ControllerOutput(NamedTuple):
    leg_targets: jax.Array   # (12,) rad, tkujax.model.LEG_ACTUATORS order
    phi: jax.Array           # filtered pitch, rad
    roll: jax.Array          # filtered roll, rad
    gate: jax.Array          # detection gate this period, [0, 1]
    reachable: jax.Array     # IK reached the CPG's targets
    touchdown_s: jax.Array = None  # when the executed step lands (controller clock, s); ~1e4: none


def controller_init(params: ControllerParams, dtype=jnp.float32) -> ControllerState:
    """Initial state of a robot standing in its `stand` keyframe (filter at the standing lean)."""
    zero = jnp.zeros((), dtype)
    return ControllerState(
        kalman=kalman_init(jnp.stack([jnp.asarray(params.standing_lean, dtype), zero]), params),
        time_s=zero, step_weight=zero, step_start_s=jnp.asarray(NOT_STARTED_S, dtype),
        x_sup_m=zero, y_sup_m=zero, phi_at_detect=zero, steps=StepsState.init(dtype),
        detect_prev=jnp.asarray(-1.0, dtype) if has_timing_gradient(params) else None)


def cp_angle(phi: jax.Array, params: ControllerParams) -> jax.Array:
    """The angle entering Eq. 7-10: phi - cp_angle_offset (cp_excess = 0, default), or the excess
    over the threshold on phi's side (cp_excess = 1): phi - eps_forward / phi + eps_backward."""
    mid = 0.5 * (params.eps_forward - params.eps_backward)
    excess = phi - jnp.where(phi >= mid, params.eps_forward, -params.eps_backward)
    return jnp.where(params.cp_excess > 0.5, excess, phi - params.cp_angle_offset)


def stand_leg_targets(params: ControllerParams) -> jax.Array:
    """(12,) leg targets of the stand pose (feet at (0, -+d_y, -d_z))."""
    p_right, p_left = cpg_feet(jnp.asarray(-1.0), jnp.asarray(0.0), params)
    return solve_legs(p_right, p_left, params)[0]


def controller_step(state: ControllerState, sensors: Sensors, params: ControllerParams,
                    enabled: jax.Array = 1.0, override: StepOverride | None = None,
                    schedule: Schedule | None = None
                    ) -> tuple[ControllerState, ControllerOutput]:
    """One control period. `enabled` (scalar, 0 or 1) switches the balance strategy on (it
    gates detection and stance feedback). `override`: a commanded step (see `StepOverride`);
    None = the controller's own. `schedule`: gains and thresholds as functions of the filtered
    state (`tkujax.control.policy`); None = the fields of `params` (a Python branch at trace
    time: the program without a schedule is unchanged)."""
    # accel_variance is kalman_r exactly when accel_gate = 0 (the paper's mode).
    kalman = kalman_step(state.kalman, gyro_to_rates(sensors.gyro), accel_to_angle(sensors.accel),
                         params, accel_variance(sensors.accel, params))
    phi = kalman.phi[..., 0]
    psi = -kalman.phi[..., 1]                            # lateral lean, positive toward +y
    rates = gyro_to_rates(sensors.gyro)
    pitch_rate, psi_rate = rates[..., 0], -rates[..., 1]
    if schedule is not None:
        # After the Kalman step (which the schedule cannot change): this period's estimate;
        # "mlpr" also reads the controller's own recovery state as the period starts.
        recovery = (recovery_inputs(state.time_s, state.step_start_s, state.step_weight,
                                    state.steps.swing_left, params)
                    if schedule.kind == "mlpr" else None)
        params = scheduled_params(schedule, params, phi - params.standing_lean, pitch_rate,
                                  kalman.phi[..., 1], rates[..., 1], recovery)
    enabled = jnp.asarray(enabled, phi.dtype)
    det = detect_push(phi, psi, pitch_rate, psi_rate, params)
    # Either detector triggers the (first) step: 1 - (1 - a)(1 - b) is "a or b" for 0/1 gates.
    gate = enabled * (1.0 - (1.0 - det.pitch_gate) * (1.0 - det.lateral_gate))
    # The step weight is the running max of the gate: a hard gate latches 0 -> 1 once; a soft
    # gate only grows as far as the inclination actually approached a threshold (summing soft
    # gates instead would let a robot standing still creep past 1/2 and step by itself).
    step_weight = jnp.maximum(state.step_weight, gate)
    trigger = step_weight - state.step_weight          # only the first detection counts
    x_sup = state.x_sup_m + trigger * det.x_new
    y_sup = state.y_sup_m + trigger * params.lateral_steps * det.y_new
    starts_now = (state.step_weight < 0.5) & (step_weight >= 0.5)
    step_start = jnp.where(starts_now, state.time_s, state.step_start_s)
    detect_prev = None
    if state.detect_prev is not None:      # static: TimingGradientParams (module docstring)
        detect_prev = detection_value(det, phi, psi, params)
        step_start = step_start + crossing_time_offset(
            starts_now, state.detect_prev, detect_prev, state.time_s, params.control_period)
    # cp_update_window > 0: after the first detection x_Sup follows the current capture point
    # while the step is young enough and the push is still detected (default 0: latched).
    age = state.time_s - step_start
    updating = ((step_weight >= 0.5) & ~starts_now & (params.cp_update_window > 0)
                & (age < params.cp_update_window + 0.5 * params.control_period)
                & (det.pitch_gate > 0.5) & (state.steps.count < 1.5))
    x_sup = jnp.where(updating, det.x_new, x_sup)
    phi_at_detect = jnp.where(starts_now, phi, state.phi_at_detect)
    steps = _first_step_bookkeeping(state.steps, step_weight >= 0.5, x_sup, y_sup, params)
    steps, step_start = _later_steps(steps, state.time_s, step_start, step_weight, det, enabled,
                                     params)

    # With lateral steps off y_sup is 0 and cpg_feet_lateral equals the paper's cpg_feet (with
    # no support shift); the paper's function is kept on that path so the paper mode is its
    # literal transcription.
    t_step = state.time_s - step_start
    p_paper = cpg_feet(t_step, x_sup, params)
    p_lateral = cpg_feet_lateral(t_step, x_sup, y_sup, params)
    use_lateral = (params.lateral_steps > 0) | (params.step_shift_m > 0)
    p_right = jnp.where(use_lateral, p_lateral[0], p_paper[0])
    p_left = jnp.where(use_lateral, p_lateral[1], p_paper[1])
    later = later_step_feet(t_step, steps, params)
    p_right = jnp.where(steps.count > 1.5, later[0], p_right)
    p_left = jnp.where(steps.count > 1.5, later[1], p_left)
    touchdown = step_start + land_time(params.step_period, params)
    if override is not None:
        p_right, p_left, touchdown = override_feet(override, state.time_s, step_start, p_right,
                                                    p_left, touchdown, params)
    targets, reachable = solve_legs(p_right, p_left, params)
    targets = targets + enabled * stance_offsets(phi - params.standing_lean, pitch_rate,
                                                 kalman.phi[..., 1], rates[..., 1], params)
    new_state = ControllerState(kalman=kalman, time_s=state.time_s + params.control_period,
                                step_weight=step_weight, step_start_s=step_start, x_sup_m=x_sup,
                                y_sup_m=y_sup, phi_at_detect=phi_at_detect, steps=steps,
                                detect_prev=detect_prev)
    return new_state, ControllerOutput(targets, phi, kalman.phi[..., 1], gate, reachable,
                                       touchdown)


class Detection(NamedTuple):
    """pitch_gate / lateral_gate: [0, 1] detectors of this period; x_new / y_new: the step the
    controller would take now (m, cp_gain applied, and cp_gain_lateral to y_new); x_cp / y_cp:
    the rate-aware capture point relative to the ankles' midpoint, sagittal / lateral (m, no
    gain, no lookahead)."""

    pitch_gate: jax.Array
    lateral_gate: jax.Array
    x_new: jax.Array
    y_new: jax.Array
    x_cp: jax.Array
    y_cp: jax.Array


def detect_push(phi, psi, pitch_rate, psi_rate, params: ControllerParams) -> Detection:
    """Detectors and step targets: the paper's angle thresholds (cp_trigger = 0) or the
    capture point leaving the support (cp_trigger = 1), selected by `where`."""
    theta = cp_angle(phi, params)
    x_new = params.cp_gain * capture_point_rate(theta, pitch_rate, params)
    y_new = params.cp_gain_lateral * (params.cp_gain * capture_point_rate(psi, psi_rate, params))
    # Where the capture point is now (no lookahead): the trigger asks whether standing would
    # still survive, which is a question about the present state.
    now = dataclasses.replace(params, cp_lookahead_s=0.0)
    x_cp = capture_point_rate(phi - params.standing_lean, pitch_rate, now)
    y_cp = capture_point_rate(psi, psi_rate, now)
    tau_m = params.gate_temperature * params.leg_length     # rad -> m at the pendulum's length
    on_cp = params.cp_trigger > 0.5
    pitch_gate = jnp.where(
        on_cp, band_gate(x_cp, -params.cp_trigger_backward_m, params.cp_trigger_forward_m, tau_m),
        push_gate(phi, params))
    lateral_gate = params.lateral_steps * jnp.where(
        on_cp, band_gate(y_cp, -params.cp_trigger_lateral_m, params.cp_trigger_lateral_m, tau_m),
        band_gate(psi, -params.eps_lateral, params.eps_lateral, params.gate_temperature))
    return Detection(pitch_gate, lateral_gate, x_new, y_new, x_cp, y_cp)


def detection_value(det: Detection, phi, psi, params: ControllerParams) -> jax.Array:
    """How far the trigger quantity is beyond its band (m for the capture-point trigger, rad for
    the angle trigger; the larger of pitch and, with lateral steps, lateral): > 0 exactly when
    the hard gate fires, negative inside the band."""
    on_cp = params.cp_trigger > 0.5
    pitch = jnp.where(on_cp, jnp.maximum(det.x_cp - params.cp_trigger_forward_m,
                                         -params.cp_trigger_backward_m - det.x_cp),
                      jnp.maximum(phi - params.eps_forward, -params.eps_backward - phi))
    lateral = jnp.where(on_cp, jnp.abs(det.y_cp) - params.cp_trigger_lateral_m,
                        jnp.abs(psi) - params.eps_lateral)
    return jnp.where(params.lateral_steps > 0, jnp.maximum(pitch, lateral), pitch)


def crossing_time_offset(starts_now, e_prev, e_now, time_s, period_s) -> jax.Array:
    """0.0 in value; the gradient of the crossing time t_x = time_s - (1 - f) period_s, f =
    e_prev / (e_prev - e_now), on the tick where the step starts after a crossing (e_prev <= 0
    < e_now); a zero gradient elsewhere (NaN-free: the division's inputs are guarded)."""
    crossed = starts_now & (e_prev <= 0.0) & (e_now > 0.0)
    denom = jnp.where(crossed, e_prev - e_now, -1.0)
    frac = jnp.where(crossed, jnp.clip(e_prev / denom, 0.0, 1.0), 1.0)
    t_cross = time_s - (1.0 - frac) * period_s
    return jnp.where(crossed, t_cross - jax.lax.stop_gradient(t_cross), 0.0)


def stance_offsets(pitch_dev, pitch_rate, roll, roll_rate, params: ControllerParams):
    """(..., 12) offsets added to the leg targets (LEG_ACTUATORS order): ankle and hip pitch
    feedback on the pitch deviation from the standing lean and the gyro pitch rate, ankle-roll
    feedback on the roll and its rate, each saturated smoothly at +-stance_limit (tanh).

    Signs: a positive ankle-pitch offset turns the shin backward over a flat foot (the ankle's
    right-hand-rule axis is +y), so a positive stance_ankle_kp pushes the toes down and the CoP
    forward when the robot leans forward (the ankle strategy); likewise a positive
    stance_roll_kp moves the CoP toward the side the robot leans to. All gains 0: exactly 0.
    """
    lim = params.stance_limit
    sat = lambda u: lim * jnp.tanh(u / lim)                       # noqa: E731
    ankle = sat(params.stance_ankle_kp * pitch_dev + params.stance_ankle_kd * pitch_rate)
    hip = sat(params.stance_hip_kp * pitch_dev + params.stance_hip_kd * pitch_rate)
    ankle_roll = sat(params.stance_roll_kp * roll + params.stance_roll_kd * roll_rate)
    zero = jnp.zeros_like(ankle)
    one_leg = jnp.stack([zero, zero, hip, zero, ankle, ankle_roll], -1)
    return jnp.concatenate([one_leg, one_leg], -1)


def _first_step_feet(x_sup, y_sup, params: ControllerParams):
    """(4,) end displacements [x_r, y_r, x_l, y_l] of the first step, as `cpg_feet_lateral`
    (y_sup = 0 without lateral steps), and whether the left foot swings."""
    y = params.lateral_steps * y_sup
    swing_left = y >= 0.0
    s = jnp.where(swing_left, 1.0, -1.0)
    half_x, half_y = 0.5 * x_sup, 0.5 * y
    return jnp.stack([-s * half_x, -s * half_y, s * half_x, s * half_y], -1), swing_left


def _first_step_bookkeeping(steps: StepsState, stepping, x_sup, y_sup, params) -> StepsState:
    """Record the first step (count 1, where its feet end) while it is the current one."""
    feet_to, swing_left = _first_step_feet(x_sup, y_sup, params)
    first = stepping & (steps.count < 1.5)
    return StepsState(count=jnp.where(first, 1.0, steps.count).astype(steps.count.dtype),
                      feet_from=jnp.where(first, 0.0,
                                          steps.feet_from).astype(steps.feet_from.dtype),
                      feet_to=jnp.where(first, feet_to, steps.feet_to).astype(steps.feet_to.dtype),
                      swing_left=jnp.where(first, swing_left.astype(steps.swing_left.dtype),
                                           steps.swing_left))


def _later_steps(steps: StepsState, time_s, step_start, step_weight, det: Detection, enabled,
                 params: ControllerParams):
    """Start step k + 1 (the other foot) once step k has finished (t >= T) and the capture point
    is still beyond the new support by the trigger distances, up to max_steps steps.

    The capture point is taken relative to the waist, over the middle of the stand feet; after
    a step the feet end at feet_to, so the support reaches max/min(x_r, x_l) + the trigger
    distance. The new step ends with the feet x_new apart around the waist (as the first step),
    the swing foot ahead; its sideways part only moves the swing foot outward (legs never cross).
    """
    x_r, y_r, x_l, y_l = (steps.feet_to[..., i] for i in range(4))
    lat = params.lateral_steps
    beyond = ((det.x_cp > jnp.maximum(x_r, x_l) + params.cp_trigger_forward_m)
              | (det.x_cp < jnp.minimum(x_r, x_l) - params.cp_trigger_backward_m)
              | ((lat > 0) & ((det.y_cp > y_l + params.cp_trigger_lateral_m)
                              | (det.y_cp < y_r - params.cp_trigger_lateral_m))))
    finished = (step_weight >= 0.5) & (time_s - step_start >= params.step_period)
    go = finished & beyond & (steps.count + 0.5 < params.max_steps) & (enabled > 0.5)
    swing_left = 1.0 - steps.swing_left
    s = jnp.where(swing_left > 0.5, 1.0, -1.0)
    half_x = 0.5 * det.x_new
    half_y = s * jnp.maximum(s * 0.5 * lat * det.y_new, 0.0)     # outward only
    swing = jnp.stack([half_x, half_y], -1)
    support = -swing
    feet_to = jnp.where(swing_left > 0.5, jnp.concatenate([support, swing], -1),
                        jnp.concatenate([swing, support], -1))
    dtype = steps.count.dtype
    new = StepsState(count=jnp.where(go, steps.count + 1.0, steps.count).astype(dtype),
                     feet_from=jnp.where(go, steps.feet_to, steps.feet_from).astype(dtype),
                     feet_to=jnp.where(go, feet_to, steps.feet_to).astype(dtype),
                     swing_left=jnp.where(go, swing_left, steps.swing_left).astype(dtype))
    return new, jnp.where(go, time_s, step_start)


def later_step_feet(t_step, steps: StepsState, params: ControllerParams):
    """Ankle targets (p_right, p_left) of step 2.. at time t_step into it: both feet move from
    feet_from to feet_to with the CPG's quarter-sine profile (Eq. 13/16) and the swing foot
    lifts by H_Sup (Eq. 15/18), as `cpg_feet_lateral` does from the stand pose."""
    unit_x, _, unit_z = unit_oscillators(jnp.asarray(t_step, steps.feet_to.dtype), params)
    d = steps.feet_from + (steps.feet_to - steps.feet_from) * unit_x
    lift = params.lift_height * unit_z
    d_y, d_z = params.hip_offset_y, params.hip_to_ankle_z
    left_swings = steps.swing_left > 0.5
    p_right = jnp.stack([d[..., 0], -d_y + d[..., 1], -d_z + jnp.where(left_swings, 0.0, lift)], -1)
    p_left = jnp.stack([d[..., 2], d_y + d[..., 3], -d_z + jnp.where(left_swings, lift, 0.0)], -1)
    return p_right, p_left


def land_time(period, params: ControllerParams):
    """Step start -> touchdown: T - gamma T / 2 (end of the swing, `cpg.unit_oscillators`)."""
    return period * (1.0 - 0.5 * params.double_support_ratio)


def override_feet(ov: StepOverride, time_s, detect_s, p_right, p_left, touchdown,
                   params: ControllerParams):
    """Feet of the commanded step, selected by `where` on ov.active (see StepOverride)."""
    dtype = p_right.dtype
    ov = jax.tree_util.tree_map(lambda v: jnp.asarray(v, dtype), ov)
    # Not detected: detect_s is NOT_STARTED_S, so t < 0 and the CPG holds the stand pose.
    start = jnp.where(ov.from_detection > 0.5, detect_s, ov.onset_s) + ov.start_delay_s
    period = jnp.where(ov.period_s > 0.0, ov.period_s, params.step_period)
    p_ov = dataclasses.replace(params, step_period=period)
    feet = cpg_feet_lateral(time_s - start, ov.x_m, ov.y_m, p_ov)
    land1 = start + land_time(period, params)
    # A second step (steps = 2): the first step's support foot swings by (x2, y2), starting
    # delay2_s after the first touchdown, added to where the first step left the feet.
    start2 = land1 + ov.delay2_s
    feet2 = cpg_feet_lateral(time_s - start2, ov.x2_m, ov.y2_m, p_ov, swing_left=ov.y_m < 0.0)
    stand = cpg_feet_lateral(jnp.full_like(time_s, -1.0), jnp.zeros_like(ov.x2_m),
                             jnp.zeros_like(ov.y2_m), p_ov)
    two = ov.steps > 1.5
    feet = (jnp.where(two, feet[0] + (feet2[0] - stand[0]), feet[0]),
            jnp.where(two, feet[1] + (feet2[1] - stand[1]), feet[1]))
    land = jnp.where(two, start2 + land_time(period, params), land1)
    on = ov.active > 0.5
    return (jnp.where(on, feet[0], p_right), jnp.where(on, feet[1], p_left),
            jnp.where(on, land, touchdown))
