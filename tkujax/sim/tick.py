"""The control half of one closed-loop tick, shared by both physics backends.

Per control period both backends do: read the IMU, add sensor noise, `control_tick` (the
controller, then the servos' target quantisation), write the leg targets into the stand ctrl
vector, advance the physics `substeps` steps with the push applied, and record a `Series` row.

Only the physics half differs, and it cannot be shared: MJX steps inside a traced `lax.scan`
(`rollout_mjx.rollout`), while MuJoCo C steps a whole batch per `mujoco.rollout` call from
numpy, outside any trace (`rollout_mujoco.simulate_mujoco`). Everything the controller sees and
commands goes through the functions here, so the two loops cannot drift apart in it.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from tkujax.control.controller import ControllerState, Sensors, StepOverride, controller_step
from tkujax.control.params import ControllerParams

SERVO_RESOLUTION_RAD = math.radians(360.0 / 4096.0)   # 0.088 deg, Dynamixel MX [paper Table 1]


def quantise_targets(q: jax.Array) -> jax.Array:
    """Round to the servo resolution; the gradient passes straight through."""
    return q + jax.lax.stop_gradient(jnp.round(q / SERVO_RESOLUTION_RAD) * SERVO_RESOLUTION_RAD - q)


def control_tick(ctrl_state: ControllerState, gyro: jax.Array, accel: jax.Array,
                 params: ControllerParams, enabled, quantise: bool,
                 override: StepOverride | None = None):
    """One controller update for one robot from its (noisy) IMU reading.

    Returns (new controller state, leg targets (12,) rad as the servos receive them, the
    controller's output)."""
    ctrl_state, out = controller_step(ctrl_state, Sensors(gyro, accel), params, enabled,
                                      override)
    legs = quantise_targets(out.leg_targets) if quantise else out.leg_targets
    return ctrl_state, legs, out

