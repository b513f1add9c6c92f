"""External force detection: inclination from gyro + accelerometer (Sec. 3.1, Eq. 1-2).

Frames: the IMU frame is the body frame, x forward, y left, z up. Pitch and roll are carried
together as arrays whose last axis is [pitch, roll], so one scalar Kalman filter, applied
elementwise, handles both axes.

Sign conventions (MuJoCo right-hand rule):
  pitch > 0: rotation about +y, the top leans forward (toward +x);
  roll  > 0: rotation about +x, the top leans to the right (toward -y).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from tkujax.control.controller_params import ControllerParams
from tkujax.control.safe_math import safe_atan2, safe_norm, safe_sqrt


def accel_to_angle(accel: jax.Array) -> jax.Array:
    """Inclination [pitch, roll] (rad) from the accelerometer's specific force.

    Args:
      accel: (..., 3) specific force in the IMU frame (m/s^2, any scale); reads (0, 0, +g) when
        level and at rest.
    Returns:
      (..., 2) [pitch, roll] in rad.

    Derivation: with body->world rotation R = R_y(pitch) R_x(roll), the specific force at rest
    f_w = (0, 0, g) is seen in the body as f_b = R^T f_w
        = (-g sin(pitch), g cos(pitch) sin(roll), g cos(pitch) cos(roll)),
    so roll = atan2(a_y, a_z) and pitch = atan2(-a_x, sqrt(a_y^2 + a_z^2)), both exact for
    this Euler order. With roll = 0 the pitch reduces to atan2(-a_x, a_z) (the per-axis form);
    the sqrt form avoids overestimating pitch by 1/cos(roll) when both are present.
    """
    ax, ay, az = accel[..., 0], accel[..., 1], accel[..., 2]
    pitch = safe_atan2(-ax, safe_sqrt(ay * ay + az * az))
    roll = safe_atan2(ay, az)
    return jnp.stack([pitch, roll], axis=-1)


def gyro_to_rates(gyro: jax.Array) -> jax.Array:
    """[pitch_rate, roll_rate] (rad/s) from the gyroscope.

    Args:
      gyro: (..., 3) body angular velocity (rad/s) in the IMU frame.
    Returns:
      (..., 2) [gyro_y, gyro_x]: pitch is a rotation about body +y, roll about body +x. Exact
      for the pitch rate only at zero roll (small-angle model, as in the paper's Eq. 1).
    """
    return jnp.stack([gyro[..., 1], gyro[..., 0]], axis=-1)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class KalmanState:
    """Scalar Kalman filter state, elementwise over the last axis [pitch, roll].

    phi: (..., 2) inclination estimate, rad.
    p:   (..., 2) estimate error variance, rad^2.
    """

    phi: jax.Array
    p: jax.Array


def kalman_init(phi0: jax.Array, params: ControllerParams,
                p0: jax.Array | None = None) -> KalmanState:
    """Filter state at the initial inclination.

    Args:
      phi0: (..., 2) initial [pitch, roll], rad (e.g. one accelerometer reading).
      params: supplies kalman_r, the default initial variance (one accelerometer reading's).
      p0: optional initial variance (rad^2), broadcast to phi0's shape.
    """
    phi0 = jnp.asarray(phi0)
    phi0 = phi0.astype(jnp.result_type(phi0.dtype, float))
    p0 = params.kalman_r if p0 is None else p0
    return KalmanState(phi=phi0, p=jnp.broadcast_to(jnp.asarray(p0, phi0.dtype), phi0.shape))


def accel_variance(accel: jax.Array, params: ControllerParams) -> jax.Array:
    """(...) measurement variance R (rad^2) for one accelerometer sample (a tkujax extension).

    The accelerometer angle is only the inclination when the specific force is gravity alone.
    A push (or the robot's own motion) adds an acceleration a_h and the angle is off by about
    a_h / g, while the magnitude |a| departs from g by about a_h^2 / (2 g). Attitude
    estimators therefore inflate R with that departure e = |a| - g (adaptive measurement
    noise): R_eff = kalman_r * (1 + (e / accel_gate)^2), i.e. R doubles at e = accel_gate, and a
    large departure (the impact itself, tens of m/s^2) removes the sample (K ~ 0). With
    accel_gate = 0 (the paper's mode, the default) R_eff = kalman_r exactly.
    Smooth in every argument; the double `where` keeps the unselected branch finite.
    """
    gate = params.accel_gate
    on = gate > 0
    dev = (safe_norm(accel[..., 0], accel[..., 1], accel[..., 2]) - params.gravity
           ) / jnp.where(on, gate, 1.0)
    return jnp.where(on, params.kalman_r * (1.0 + dev * dev), params.kalman_r)


def kalman_step(state: KalmanState, gyro_rate: jax.Array, accel_angle: jax.Array,
                params: ControllerParams, accel_r: jax.Array | None = None) -> KalmanState:
    """One 30 ms update of Eq. 1-2 with A = 1, B = control_period, H = 1.

    Args:
      state: previous estimate, fields (..., 2).
      gyro_rate: (..., 2) [pitch_rate, roll_rate], rad/s (the input omega_Gyro, Eq. 1).
      accel_angle: (..., 2) [pitch, roll] from `accel_to_angle`, rad (the measurement, Eq. 2).
      params: control_period (s), kalman_q and kalman_r (rad^2).
      accel_r: optional (...) measurement variance of this sample (`accel_variance`), shared
        by pitch and roll; None uses params.kalman_r (the paper).
    Returns:
      The posterior state.
    """
    # Predict: integrate the gyro over one period; the gyro's noise and bias grow the variance.
    phi = state.phi + params.control_period * gyro_rate
    p = state.p + params.kalman_q
    # Update with the accelerometer angle. p + r > 0 because r > 0 (validate()).
    r = params.kalman_r if accel_r is None else jnp.asarray(accel_r)[..., None]
    k = p / (p + r)
    phi = phi + k * (accel_angle - phi)
    p = (1.0 - k) * p
    return KalmanState(phi=phi, p=p)
