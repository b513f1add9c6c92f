"""Stepping trajectories from sinusoidal oscillators (Sec. 3.3, Eq. 11-18, Table 2).

Positions are of the ankle centres relative to the waist P_W, in a level frame (x forward,
y left, z up), in metres. The right foot supports and slides by -x_Sup/2 (the body moves over
it), the left foot lifts by H_Sup and swings to +x_Sup/2, so the feet end x_Sup apart.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.control.controller_params import ControllerParams


def cpg_feet(t: jax.Array, x_sup: jax.Array,
             params: ControllerParams) -> tuple[jax.Array, jax.Array]:
    """Ankle targets of the recovery step at time t.

    Args:
      t: (...) time since the start of the recovery step, s. For t < gamma T / 2 (including
        t < 0) the feet are at the stand positions (0, -/+d_y, -d_z); for t >= T - gamma T / 2
        (including t >= T) the x offsets hold at -/+x_Sup/2 and y, z are back to the stand.
      x_sup: (...) step length x_Sup from `push_recovery`, m; broadcast against t.
      params: step_period T (s), double_support_ratio gamma, lift_height H_Sup (m),
        hip_offset_y d_y (m), hip_to_ankle_z d_z (m).
    Returns:
      (p_right, p_left), each (..., 3) in m: Eq. 11-12, with the oscillators of Eq. 13-18 and
      Table 2: rho_RA = (-x_Sup/2, 0, 0), rho_LA = (x_Sup/2, 0, H_Sup),
      omega = (pi / (2 T'), 2 pi / T', pi / T') with T' = T (1 - gamma), phases 0.
    """
    dtype = jnp.result_type(t, x_sup, float)
    t, x_sup = jnp.broadcast_arrays(jnp.asarray(t, dtype), jnp.asarray(x_sup, dtype))
    unit_x, unit_y, unit_z = unit_oscillators(t, params)
    zero = jnp.zeros_like(x_sup)
    rho_r = (-0.5 * x_sup, zero, zero)
    rho_l = (0.5 * x_sup, zero, params.lift_height + zero)
    units = (unit_x, unit_y, unit_z)
    d_y, d_z = params.hip_offset_y, params.hip_to_ankle_z
    p0_r = (0.0, -d_y, -d_z)
    p0_l = (0.0, d_y, -d_z)
    p_right = jnp.stack([rho * u + o for rho, u, o in zip(rho_r, units, p0_r)], axis=-1)
    p_left = jnp.stack([rho * u + o for rho, u, o in zip(rho_l, units, p0_l)], axis=-1)
    return p_right.astype(dtype), p_left.astype(dtype)


def unit_oscillators(t: jax.Array, params: ControllerParams):
    """Eq. 13-18 with unit amplitudes: (x, y, z) profiles at time t since the step started."""
    T = params.step_period
    gamma = params.double_support_ratio
    t_lift = 0.5 * gamma * T          # end of the first double-support phase
    t_land = T - 0.5 * gamma * T      # end of the single-support (swing) phase
    swing = T * (1.0 - gamma)         # > 0 since gamma < 0.9 (validate())

    omega = (jnp.pi / (2.0 * swing), 2.0 * jnp.pi / swing, jnp.pi / swing)
    s = t - t_lift
    in_swing = (t >= t_lift) & (t < t_land)
    landed = t >= t_land
    # x: 0, a quarter sine up to the amplitude (sin(omega_x T') = 1, so it is continuous), hold.
    unit_x = jnp.where(in_swing, jnp.sin(omega[0] * s), jnp.where(landed, 1.0, 0.0))
    # y, z: 0 outside the swing. y is a full sine period with zero amplitude (Table 2); z a half
    # sine peaking at H_Sup at mid-step, continuous at both ends.
    unit_y = jnp.where(in_swing, jnp.sin(omega[1] * s), 0.0)
    unit_z = jnp.where(in_swing, jnp.sin(omega[2] * s), 0.0)
    return unit_x, unit_y, unit_z


def support_shift(t: jax.Array, params: ControllerParams) -> jax.Array:
    """(...) the waist's shift toward the support foot at time t of a step (m): 0 before it,
    a half-cosine ramp to params.step_shift_m over the first double support (gamma T / 2), held
    through the swing, back to 0 over the last double support, 0 from T on."""
    T = params.step_period
    ds = jnp.maximum(0.5 * params.double_support_ratio * T, 1e-6)   # gamma = 0: a jump
    up = jnp.clip(t / ds, 0.0, 1.0)
    down = jnp.clip((T - t) / ds, 0.0, 1.0)
    ramp = jnp.where(t < T - ds, up, down)
    return jnp.where(t < 0.0, 0.0, params.step_shift_m * 0.5 * (1.0 - jnp.cos(jnp.pi * ramp)))


def cpg_feet_lateral(t: jax.Array, x_sup: jax.Array, y_sup: jax.Array,
                     params: ControllerParams, swing_left=None) -> tuple[jax.Array, jax.Array]:
    """The recovery step extended with a sideways component (a tkujax extension).

    The swing foot is the left one when y_sup >= 0 (falling toward +y) and the right one
    otherwise, so the legs never cross. The swing foot moves by (+x_sup/2, +y_sup/2) relative to
    the waist and lifts by H_Sup, the support foot by (-x_sup/2, -y_sup/2); y follows the same
    quarter-sine-then-hold profile as x (Eq. 13/16 with rho^y = +-y_sup/2 instead of the paper's
    zero-amplitude Eq. 14/17). With y_sup = 0 and step_shift_m = 0 this equals `cpg_feet`
    exactly; step_shift_m moves the waist toward the support foot (`support_shift`). swing_left
    (optional, bool array or scalar): choose the swing foot explicitly (a commanded second step
    swings the other foot, `tkujax.control.StepOverride`); None: by the sign of y_sup.
    """
    dtype = jnp.result_type(t, x_sup, y_sup, float)
    t, x_sup, y_sup = jnp.broadcast_arrays(*(jnp.asarray(a, dtype) for a in (t, x_sup, y_sup)))
    unit_x, _, unit_z = unit_oscillators(t, params)
    swing_left = (y_sup >= 0.0 if swing_left is None
                  else jnp.broadcast_to(jnp.asarray(swing_left, bool), t.shape))
    lift = params.lift_height * unit_z
    d_y, d_z = params.hip_offset_y, params.hip_to_ankle_z
    half_x, half_y = 0.5 * x_sup * unit_x, 0.5 * y_sup * unit_x
    swing_sign_l = jnp.where(swing_left, 1.0, -1.0)
    # The waist toward the support foot is both feet away from it (0 with step_shift_m = 0).
    shift = swing_sign_l * support_shift(t, params)
    p_left = jnp.stack([swing_sign_l * half_x, d_y + swing_sign_l * half_y + shift,
                        -d_z + jnp.where(swing_left, lift, 0.0)], -1)
    p_right = jnp.stack([-swing_sign_l * half_x, -d_y - swing_sign_l * half_y + shift,
                         -d_z + jnp.where(swing_left, 0.0, lift)], -1)
    return p_right.astype(dtype), p_left.astype(dtype)
