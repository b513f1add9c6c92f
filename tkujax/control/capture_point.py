"""Push recovery: capture point of the inverted pendulum (Sec. 3.2, Eq. 5-10, Algorithm 1).

phi is the pitch inclination (rad, > 0 leaning forward). A push from the back tilts the robot
forward (phi > eps_1) and gives x_Sup > 0, a step forward; a push from the front (phi < -eps_2)
gives x_Sup < 0, a step backward. Everything is elementwise over any batch shape of phi.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.control.controller_params import ControllerParams


def capture_point(phi: jax.Array, leg_length, com_height, g=9.81) -> jax.Array:
    """Capture point x_Sup (m) of Eq. 6-10 for the inclination phi.

    Args:
      phi: (...) pendulum angle from vertical, rad.
      leg_length: l, ankle-to-CoM distance, m (> 0).
      com_height: h, CoM height, m (> 0).
      g: gravitational acceleration, m/s^2 (> 0).
    Returns:
      (...) x_Sup = x_COM + xdot_COM sqrt(h/g) in m, same sign as phi, with
      x_COM = l sin(phi) (Eq. 7), xdot_COM = l cos(phi) phidot (Eq. 8) and phidot from the
      energy balance of Eq. 9.

    Eq. 10 gives phidot = sqrt(2 (g/l) (1 - cos phi)) without a sign; the sign of phi is kept so
    that a backward fall yields a backward step (the paper's Sec. 3.2 text: "the positive or
    negative value of x_Sup"). Algorithm 1 also has a typo, sqrt(2 g (1 - cos phi)) / l, which
    puts l outside the root; Eq. 10 is dimensionally right and used here.
    """
    # Identity: 2 (1 - cos phi) = 4 sin^2(phi/2), so
    #   sign(phi) sqrt(2 (g/l) (1 - cos phi)) = 2 sqrt(g/l) sin(phi/2)   exactly.
    # The right side is smooth at phi = 0 where the literal sqrt has an infinite derivative.
    # g/l and h/g are positive (validate()), so these square roots have finite gradients.
    phidot = energy_rate(phi, leg_length, g)
    return _lip_capture_point(phi, phidot, leg_length, com_height, g)


def energy_rate(phi: jax.Array, leg_length, g=9.81) -> jax.Array:
    """(...) the signed fall rate of Eq. 9-10, sign(phi) sqrt(2 (g/l)(1 - cos phi)), rad/s."""
    return 2.0 * jnp.sqrt(g / leg_length) * jnp.sin(0.5 * phi)


def _lip_capture_point(phi, phidot, leg_length, com_height, g):
    """Eq. 7-8 and 6: l sin(phi) + l cos(phi) phidot sqrt(h/g)."""
    x_com = leg_length * jnp.sin(phi)
    xdot_com = leg_length * jnp.cos(phi) * phidot
    return x_com + xdot_com * jnp.sqrt(com_height / g)


def capture_point_rate(phi: jax.Array, rate: jax.Array, params: ControllerParams) -> jax.Array:
    """Rate-aware capture point (m) of the angle phi (rad) and the measured rate (rad/s).

    x = l sin(phi) + l cos(phi) phidot sqrt(h/g) (Eq. 6-8, the instantaneous capture point of
    Pratt et al. 2006 / the DCM of Englsberger et al. 2011), with phidot the blend
    (1 - b) phidot_E + b rate of the energy-balance rate of Eq. 9-10 and the gyro's, b =
    params.cp_rate_blend, then predicted params.cp_lookahead_s ahead by the LIP:
    x exp(omega tau), omega = sqrt(g/h) (Koolen et al. 2012). With b = 0 and tau = 0 this is
    `capture_point(phi, ...)` exactly (the blend adds 0 * (finite), the factor is exp(0) = 1).
    """
    leg_len, h, g = params.leg_length, params.com_height, params.gravity
    phidot_e = energy_rate(phi, leg_len, g)
    phidot = phidot_e + params.cp_rate_blend * (rate - phidot_e)
    x = _lip_capture_point(phi, phidot, leg_len, h, g)
    return x * jnp.exp(params.cp_lookahead_s * jnp.sqrt(g / h))


def push_detected(phi: jax.Array, params: ControllerParams) -> jax.Array:
    """(...) bool: the hard test of Algorithm 1, phi > eps_forward or phi < -eps_backward.

    phi is the absolute inclination (rad), as in the paper's thresholds (-2 deg, 12 deg).
    """
    phi = jnp.asarray(phi)
    return (phi > params.eps_forward) | (phi < -params.eps_backward)


def push_gate(phi: jax.Array, params: ControllerParams) -> jax.Array:
    """(...) gate in [0, 1] (float) deciding whether a recovery step is taken.

    gate_temperature tau == 0: exactly the hard 0/1 of `push_detected`.
    tau > 0: sigmoid((phi - eps_1)/tau) + sigmoid((-eps_2 - phi)/tau), clipped to <= 1, a
    differentiable gate that tends to the hard one as tau -> 0 (except at the thresholds).
    The choice is a `where` on the tau value, so one compiled function serves both.
    """
    return band_gate(phi, -params.eps_backward, params.eps_forward, params.gate_temperature)


def band_gate(angle: jax.Array, lower, upper, temperature) -> jax.Array:
    """(...) in [0, 1]: 1 outside the band (lower, upper), 0 inside; sigmoid edges of width
    `temperature` when it is > 0, exactly the hard test when it is 0."""
    angle = jnp.asarray(angle, jnp.result_type(angle, float))
    dtype = angle.dtype
    tau = temperature
    soft_on = tau > 0
    # Divide by 1 where tau == 0: the unselected soft branch must stay finite or its zero
    # cotangent times inf/NaN would poison the gradient through `where`.
    tau_safe = jnp.where(soft_on, tau, 1.0)
    soft = jax.nn.sigmoid((angle - upper) / tau_safe) + jax.nn.sigmoid((lower - angle) / tau_safe)
    # The sum is <= 1 whenever lower <= upper; the clip guards rounding and odd settings.
    soft = jnp.minimum(soft, 1.0)
    hard = ((angle > upper) | (angle < lower)).astype(dtype)
    return jnp.where(soft_on, soft, hard).astype(dtype)


def push_recovery(phi: jax.Array, params: ControllerParams) -> jax.Array:
    """Algorithm 1: step length x_Sup (m) for the measured inclination phi (rad).

    Args:
      phi: (...) absolute pitch inclination (filtered), rad.
      params: thresholds, cp_angle_offset, cp_gain, gate_temperature, leg_length, com_height,
        gravity.
    Returns:
      (...) x_Sup in m: cp_gain * capture_point(phi - cp_angle_offset) times `push_gate`
      (with the hard gate: that value when a push is detected, else 0).
    """
    x_sup = params.cp_gain * capture_point(phi - params.cp_angle_offset, params.leg_length,
                                           params.com_height, params.gravity)
    return x_sup * push_gate(phi, params)
