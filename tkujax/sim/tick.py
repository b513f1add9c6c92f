"""The control half of one closed-loop tick, shared by both physics backends.

Per control period both backends do: read the IMU, add sensor noise, `control_tick` (the
controller, then the servos' target quantisation), write the leg targets into the stand ctrl
vector, advance the physics `substeps` steps with the push applied, and record a `Series` row.

Only the physics half differs, and it cannot be shared: MJX steps inside a traced `lax.scan`
(`rollout_mjx.rollout`), while MuJoCo C steps a whole batch per `mujoco.rollout` call from
numpy, outside any trace (`rollout_mujoco.simulate_mujoco`). Everything the controller sees and
commands goes through the functions here, so the two loops cannot drift apart in it.

The fixed-point controller (the FPGA twin, `RolloutConfig.fixed`) goes through `control_tick_fx`:
it also returns the previous command, which both loops apply for the first
`servo_switch_substep` physics substeps of the tick (the fractional latency).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from tkujax.control.controller import (NOT_STARTED_S, ControllerOutput, ControllerState, Sensors,
                                       StepOverride, land_time, controller_step)
from tkujax.control.fixed import FixedControllerState, FixedPointConfig, controller_step_fx
from tkujax.control.controller_params import ControllerParams
from tkujax.control.walking import walking_step

SERVO_RESOLUTION_RAD = math.radians(360.0 / 4096.0)   # 0.088 deg, Dynamixel MX [paper Table 1]


def quantise_targets(q: jax.Array) -> jax.Array:
    """Round to the servo resolution; the gradient passes straight through."""
    return q + jax.lax.stop_gradient(jnp.round(q / SERVO_RESOLUTION_RAD) * SERVO_RESOLUTION_RAD - q)


def control_tick(ctrl_state: ControllerState, gyro: jax.Array, accel: jax.Array,
                 params: ControllerParams, enabled, quantise: bool,
                 override: StepOverride | None = None, schedule=None, walk=None):
    """One controller update for one robot from its (noisy) IMU reading. `schedule`: an
    optional `tkujax.control.policy.Schedule` (None: the plain controller). `walk`: a
    `tkujax.control.gait.WalkCommand` (ctrl_state then a `walking.WalkingState`; the rollouts
    refuse it with an override or a schedule); None: the standing controller (a Python branch
    on None at trace time, so its program is unchanged).

    Returns (new controller state, leg targets (12,) rad as the servos receive them, the
    controller's output)."""
    if walk is not None:
        ctrl_state, out = walking_step(ctrl_state, Sensors(gyro, accel), params, walk, enabled)
    else:
        ctrl_state, out = controller_step(ctrl_state, Sensors(gyro, accel), params, enabled,
                                          override, schedule)
    legs = quantise_targets(out.leg_targets) if quantise else out.leg_targets
    return ctrl_state, legs, out



def control_tick_fx(ctrl_state: FixedControllerState, gyro: jax.Array, accel: jax.Array,
                    params: ControllerParams, enabled, quantise: bool, fixed: FixedPointConfig):
    """`control_tick` with the fixed-point controller (`tkujax.control.fixed`).

    Returns (new state, leg targets (12,) rad after the latency, the previous command (12,)
    that the servos hold for the first `servo_switch_substep(fixed, substeps)` physics substeps
    of the tick, the controller's output as a `ControllerOutput`). Commanded steps
    (StepOverride) have no fixed-point twin."""
    ctrl_state, out = controller_step_fx(ctrl_state, Sensors(gyro, accel), params, enabled, fixed)
    q = quantise_targets if quantise else (lambda x: x)
    dtype = out.phi.dtype
    dt = jnp.asarray(params.control_period, dtype)
    # When the executed step lands: the float controller's definition, moved later by the
    # whole-tick latency of the command (the fraction shifts it by less than a physics step
    # resolution of the touchdown detection anyway: included for consistency).
    start = jnp.where(ctrl_state.stepping, ctrl_state.step_start_tick.astype(dtype) * dt,
                      jnp.asarray(NOT_STARTED_S, dtype))
    touchdown = start + land_time(params.step_period, params) + fixed.latency_periods * dt
    out_f = ControllerOutput(out.leg_targets, out.phi, out.roll, out.gate, out.reachable,
                             touchdown)
    return ctrl_state, q(out.leg_targets), q(out.leg_targets_prev), out_f
