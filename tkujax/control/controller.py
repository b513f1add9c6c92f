"""The paper's controller composed: Kalman -> detection -> capture point -> CPG -> IK.

`controller_step` runs once per control period (30 ms). While no push is detected it holds the
stand targets; on the first detection it latches x_Sup and executes one recovery step of length
T (Eq. 13-18), then holds the final pose. `enabled` = 0 gives the paper's "disable" rows with
the same compiled function.

Smooth variant: with gate_temperature > 0 the detection gate is a sigmoid; the step weight is
the running max of the gate (w <- max(w, gate)) and x_Sup accumulates the capture point weighted
by each increase of w, so gradients reach the thresholds. The step's start time is still the discrete instant at which
w crosses 1/2; with gate_temperature = 0 all of this is exactly Algorithm 1.

Sideways pushes (params.lateral_steps = 1, a tkujax extension): the roll is watched too; when
the lateral lean psi = -roll (positive toward +y) leaves (-eps_lateral, eps_lateral) a step is
triggered as well, with y_Sup = capture_point(psi) and the swing foot on the falling side
(`cpg_feet_lateral`). The same single step carries x_Sup (from the pitch) and y_Sup.

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

from tkujax.control.capture_point import band_gate, capture_point, push_gate
from tkujax.control.cpg import cpg_feet, cpg_feet_lateral
from tkujax.control.kalman import (KalmanState, accel_to_angle, accel_variance, gyro_to_rates,
                                   kalman_init, kalman_step)
from tkujax.control.params import ControllerParams
from tkujax.control.solve import solve_legs

# Before a step starts its start time is "far in the future": finite so that sin() of the
# (unselected) CPG branch stays finite and gradients through `where` are never NaN.
_NOT_STARTED_S = 1.0e4


class Sensors(NamedTuple):
    """What the controller reads each period: gyro (..., 3) rad/s, accel (..., 3) m/s^2."""

    gyro: jax.Array
    accel: jax.Array


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ControllerState:
    """kalman: [pitch, roll] filter; time_s: controller clock; step_weight: 0 before the step,
    1 once triggered (in between only with a soft gate); step_start_s: when it started;
    x_sup_m: the latched step length; phi_at_detect: filtered pitch at the trigger (rad)."""

    kalman: KalmanState
    time_s: jax.Array
    step_weight: jax.Array
    step_start_s: jax.Array
    x_sup_m: jax.Array
    y_sup_m: jax.Array
    phi_at_detect: jax.Array


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
    """

    active: jax.Array = 1.0
    x_m: jax.Array = 0.0
    y_m: jax.Array = 0.0
    start_delay_s: jax.Array = 0.0
    from_detection: jax.Array = 0.0
    period_s: jax.Array = 0.0
    onset_s: jax.Array = 0.0


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
        time_s=zero, step_weight=zero, step_start_s=jnp.asarray(_NOT_STARTED_S, dtype),
        x_sup_m=zero, y_sup_m=zero, phi_at_detect=zero)


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
                    enabled: jax.Array = 1.0, override: StepOverride | None = None
                    ) -> tuple[ControllerState, ControllerOutput]:
    """One control period. `enabled` (scalar, 0 or 1) switches the balance strategy on (it
    gates detection). `override`: a commanded step (see `StepOverride`); None = the paper's."""
    # accel_variance is kalman_r exactly when accel_gate = 0 (the paper's mode).
    kalman = kalman_step(state.kalman, gyro_to_rates(sensors.gyro), accel_to_angle(sensors.accel),
                         params, accel_variance(sensors.accel, params))
    phi = kalman.phi[..., 0]
    psi = -kalman.phi[..., 1]                            # lateral lean, positive toward +y
    enabled = jnp.asarray(enabled, phi.dtype)
    lateral_gate = params.lateral_steps * band_gate(psi, -params.eps_lateral, params.eps_lateral,
                                                    params.gate_temperature)
    # Either detector triggers the (single) step: 1 - (1 - a)(1 - b) is "a or b" for 0/1 gates.
    gate = enabled * (1.0 - (1.0 - push_gate(phi, params)) * (1.0 - lateral_gate))
    # The step weight is the running max of the gate: a hard gate latches 0 -> 1 once; a soft
    # gate only grows as far as the inclination actually approached a threshold (summing soft
    # gates instead would let a robot standing still creep past 1/2 and step by itself).
    step_weight = jnp.maximum(state.step_weight, gate)
    trigger = step_weight - state.step_weight          # only the first detection counts
    cp = lambda angle: params.cp_gain * capture_point(  # noqa: E731
        angle, params.leg_length, params.com_height, params.gravity)
    x_new = cp(cp_angle(phi, params))
    x_sup = state.x_sup_m + trigger * x_new
    y_sup = state.y_sup_m + trigger * params.lateral_steps * cp(psi)
    starts_now = (state.step_weight < 0.5) & (step_weight >= 0.5)
    step_start = jnp.where(starts_now, state.time_s, state.step_start_s)
    # cp_update_window > 0: after the first detection x_Sup follows the current angle while the
    # step is young enough and the push is still detected (default 0: latched, Algorithm 1).
    age = state.time_s - step_start
    updating = ((step_weight >= 0.5) & ~starts_now & (params.cp_update_window > 0)
                & (age < params.cp_update_window + 0.5 * params.control_period)
                & (push_gate(phi, params) > 0.5))
    x_sup = jnp.where(updating, x_new, x_sup)
    phi_at_detect = jnp.where(starts_now, phi, state.phi_at_detect)

    # With lateral steps off y_sup is 0 and cpg_feet_lateral equals the paper's cpg_feet; the
    # paper's function is kept on that path so the paper mode is its literal transcription.
    t_step = state.time_s - step_start
    p_paper = cpg_feet(t_step, x_sup, params)
    p_lateral = cpg_feet_lateral(t_step, x_sup, y_sup, params)
    use_lateral = params.lateral_steps > 0
    p_right = jnp.where(use_lateral, p_lateral[0], p_paper[0])
    p_left = jnp.where(use_lateral, p_lateral[1], p_paper[1])
    touchdown = step_start + _land_time(params.step_period, params)
    if override is not None:
        p_right, p_left, touchdown = _override_feet(override, state.time_s, step_start, p_right,
                                                    p_left, touchdown, params)
    targets, reachable = solve_legs(p_right, p_left, params)
    new_state = ControllerState(kalman=kalman, time_s=state.time_s + params.control_period,
                                step_weight=step_weight, step_start_s=step_start, x_sup_m=x_sup,
                                y_sup_m=y_sup, phi_at_detect=phi_at_detect)
    return new_state, ControllerOutput(targets, phi, kalman.phi[..., 1], gate, reachable,
                                       touchdown)


def _land_time(period, params: ControllerParams):
    """Step start -> touchdown: T - gamma T / 2 (end of the swing, `cpg._unit_oscillators`)."""
    return period * (1.0 - 0.5 * params.double_support_ratio)


def _override_feet(ov: StepOverride, time_s, detect_s, p_right, p_left, touchdown,
                   params: ControllerParams):
    """Feet of the commanded step, selected by `where` on ov.active (see StepOverride)."""
    dtype = p_right.dtype
    ov = jax.tree_util.tree_map(lambda v: jnp.asarray(v, dtype), ov)
    # Not detected: detect_s is _NOT_STARTED_S, so t < 0 and the CPG holds the stand pose.
    start = jnp.where(ov.from_detection > 0.5, detect_s, ov.onset_s) + ov.start_delay_s
    period = jnp.where(ov.period_s > 0.0, ov.period_s, params.step_period)
    p_ov = dataclasses.replace(params, step_period=period)
    feet = cpg_feet_lateral(time_s - start, ov.x_m, ov.y_m, p_ov)
    on = ov.active > 0.5
    return (jnp.where(on, feet[0], p_right), jnp.where(on, feet[1], p_left),
            jnp.where(on, start + _land_time(period, params), touchdown))
