"""The controller while walking: Kalman -> capture point -> the gait's CPG -> IK.

`walking_step` is `controller.controller_step` with the standing robot's one recovery step
replaced by the gait (`tkujax.control.gait`): the Kalman filter, the push detection and the
capture point run as when standing (the detection gate is recorded), the feet follow the walking
CPG, the legs' IK (with the hip yaws of the heading hold, `solve.solve_legs_yaw`) and the stance
feedback are the standing controller's. Recovery while walking
(command.recovery = 1, and `enabled`) moves the next footstep instead of adding a step
(`tkujax.control.walk_recovery`: the capture point against the undisturbed gait's at the same
phase), and with command.recovery_hurry the step that took it lands sooner (`gait.hurry`); the
offset a step took is recorded as x_sup_m, y_sup_m (step_weight 1 from the first).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from tkujax.control.controller import (ControllerOutput, ControllerState, Sensors,
                                       controller_init, detect_push, stance_offsets)
from tkujax.control.gait import (MAX_TURN_RAD, GaitState, WalkCommand, advance, gait_feet,
                                 gait_init, gait_yaws, hurry, touchdown_time)
from tkujax.control.kalman import accel_to_angle, accel_variance, gyro_to_rates, kalman_step
from tkujax.control.controller_params import ControllerParams
from tkujax.control.solve import solve_legs_yaw
from tkujax.control.walk_recovery import (RecoveryState, move_footsteps, recovery_update,
                                          walking_capture_point)

@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class WalkingState:
    """The standing controller's state (its Kalman filter and clock; x_sup_m / y_sup_m: the
    last footstep offset; step_weight: 1 once one was applied), the gait's, the recovery's and
    the heading (rad): the yaw integrated from the gyro since the start (`yaw_rate`)."""

    controller: ControllerState
    gait: GaitState
    recovery: RecoveryState
    heading_rad: jax.Array

    @property
    def x_sup_m(self):
        return self.controller.x_sup_m

    @property
    def y_sup_m(self):
        return self.controller.y_sup_m

    @property
    def step_weight(self):
        return self.controller.step_weight

    @property
    def time_s(self):
        return self.controller.time_s


def walking_init(params: ControllerParams, command: WalkCommand,
                 dtype=jnp.float32) -> WalkingState:
    """The robot standing in its stand keyframe, the gait before its first step."""
    return WalkingState(controller=controller_init(params, dtype),
                        gait=gait_init(command, dtype), recovery=RecoveryState.init(dtype),
                        heading_rad=jnp.zeros((), dtype))


def walking_step(state: WalkingState, sensors: Sensors, params: ControllerParams,
                 command: WalkCommand, enabled: jax.Array = 1.0
                 ) -> tuple[WalkingState, ControllerOutput]:
    """One control period while walking. `enabled` (0 or 1) switches the balance strategy on:
    push detection, stance feedback and (with command.recovery) the footstep offsets; the gait
    runs either way."""
    ctrl = state.controller
    kalman = kalman_step(ctrl.kalman, gyro_to_rates(sensors.gyro), accel_to_angle(sensors.accel),
                         params, accel_variance(sensors.accel, params))
    phi = kalman.phi[..., 0]
    psi = -kalman.phi[..., 1]
    rates = gyro_to_rates(sensors.gyro)
    pitch_rate, psi_rate = rates[..., 0], -rates[..., 1]
    enabled = jnp.asarray(enabled, phi.dtype)
    det = detect_push(phi, psi, pitch_rate, psi_rate, params)
    gate = enabled * (1.0 - (1.0 - det.pitch_gate) * (1.0 - det.lateral_gate))
    xi = walking_capture_point(phi, psi, pitch_rate, psi_rate, params)
    on = enabled * jnp.asarray(command.recovery, phi.dtype)
    steady = state.gait.count >= jnp.asarray(command.ramp_steps, phi.dtype)
    recovery, _ = recovery_update(state.recovery, xi, ctrl.time_s, command, params, on, steady,
                                  state.gait.lead_s)
    turn = jnp.clip(-jnp.asarray(command.heading_gain, phi.dtype) * state.heading_rad,
                    -MAX_TURN_RAD, MAX_TURN_RAD)
    gait, started = advance(state.gait, ctrl.time_s, command, turn=turn)
    recovery, gait, moved = move_footsteps(recovery, gait, started, ctrl.time_s, command,
                                           params.control_period)
    offset = recovery.applied
    # A step that took an offset lands sooner (command.recovery_hurry; 0: nominal timing).
    gait = hurry(gait, ctrl.time_s, command, on * jnp.any(offset != 0.0), params.control_period)
    p_right, p_left = gait_feet(gait, ctrl.time_s, command, params)
    yaw_right, yaw_left = gait_yaws(gait, ctrl.time_s, command, params)
    targets, reachable = solve_legs_yaw(p_right, p_left, yaw_right, yaw_left, params)
    targets = targets + enabled * stance_offsets(phi - params.standing_lean, pitch_rate,
                                                 kalman.phi[..., 1], rates[..., 1], params)
    new_ctrl = dataclasses.replace(
        ctrl, kalman=kalman, time_s=ctrl.time_s + params.control_period,
        step_weight=jnp.where(moved, 1.0, ctrl.step_weight).astype(ctrl.step_weight.dtype),
        x_sup_m=jnp.where(moved, offset[0], ctrl.x_sup_m).astype(ctrl.x_sup_m.dtype),
        y_sup_m=jnp.where(moved, offset[1], ctrl.y_sup_m).astype(ctrl.y_sup_m.dtype))
    out = ControllerOutput(targets, phi, kalman.phi[..., 1], gate, reachable,
                           touchdown_time(gait, command))
    heading = state.heading_rad + params.control_period * yaw_rate(sensors.gyro, kalman.phi)
    return WalkingState(controller=new_ctrl, gait=gait, recovery=recovery,
                        heading_rad=heading.astype(state.heading_rad.dtype)), out


def yaw_rate(gyro, pitch_roll) -> jax.Array:
    """The world yaw rate (rad/s) from the body-frame gyro (3,) and the filtered [pitch, roll]:
    the z row of R_y(pitch) R_x(roll) applied to the rate."""
    pitch, roll = pitch_roll[..., 0], pitch_roll[..., 1]
    return (-jnp.sin(pitch) * gyro[..., 0]
            + jnp.cos(pitch) * (jnp.sin(roll) * gyro[..., 1] + jnp.cos(roll) * gyro[..., 2]))
