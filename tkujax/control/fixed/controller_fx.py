"""The fixed-point controller: a drop-in twin of `tkujax.control.controller.controller_step`.

Float sensors are quantised at the input (the ADC: gyro in rad/s -> `rate` words, accel in
m/s^2 -> `accel` words in g), the four modules run on integer words, and the 12 leg targets
leave as floats. Hard gates only (Algorithm 1); `gate_temperature` acts on the gradient path.
cp_excess and cp_update_window are implemented (mode bits and two coefficient registers);
options that are not (accel_gate, a soft gate, later ones) are refused at the edges by
`support.check_supported`.

Latency (sensor-to-servo, latency_ticks + latency_frac control periods):
  * whole ticks are a delay line of servo commands inside the state (pure state in / out);
  * the fraction is realised by the sim loop: each tick it applies `out.leg_targets_prev` for
    the first `servo_switch_substep(config, substeps)` physics substeps and `out.leg_targets`
    for the rest (`servo_command` does that choice). With latency 0 the loop is unchanged.

Gradients (config.straight_through): the state carries a float shadow of the float controller.
Each tick the float controller steps the shadow; every float the fixed controller emits (and
the shadow itself) is then `straight_through(float, fixed)`: exactly the fixed-point value, with
the float controller's derivative. Tuning thus optimises the fixed-point controller's values
with the float controller's gradients (evaluated along the fixed-point trajectory).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp

from tkujax.control.controller import (ControllerState, Sensors, StepsState, controller_init,
                                       controller_step)
from tkujax.control.fixed.capture_point_fx import band_gate_fx, step_length_fx
from tkujax.control.fixed.coefficients import coef_format, coefficients
from tkujax.control.fixed.config import FixedPointConfig
from tkujax.control.fixed.cpg_fx import cpg_feet_fx
from tkujax.control.fixed.ik_fx import solve_legs_fx
from tkujax.control.fixed.kalman_fx import accel_to_angle_fx, kalman_step_fx
from tkujax.control.fixed.qformat import neg, quantize, requant, straight_through, sub, to_float
from tkujax.control.kalman import KalmanState
from tkujax.control.controller_params import ControllerParams

STANDARD_GRAVITY = 9.80665      # m/s^2 per g: the accelerometer's output scale
NOT_STARTED_TICK = 1 << 30      # step start before any step: n = tick - start is very negative
_NOT_STARTED_S = 1.0e4          # the float controller's equivalent (controller.NOT_STARTED_S)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class FixedControllerState:
    """Registers (int32 words unless noted) and the float views the sim records.

    phi (2,) state words [pitch, roll]; p (2,) cov words; tick: control-period counter;
    step_start_tick; stepping (bool): the latched detection; x_sup, y_sup: length words;
    phi_at_detect: state word; delay (latency_ticks + 1, 12) angle words: the last commands,
    oldest first. Float views (exact values of the words): x_sup_m, y_sup_m, step_weight.
    shadow / delay_grad: the float gradient carriers (None without straight_through).
    """

    phi: jax.Array
    p: jax.Array
    tick: jax.Array
    step_start_tick: jax.Array
    stepping: jax.Array
    x_sup: jax.Array
    y_sup: jax.Array
    phi_at_detect: jax.Array
    delay: jax.Array
    x_sup_m: jax.Array
    y_sup_m: jax.Array
    step_weight: jax.Array
    shadow: ControllerState | None
    delay_grad: jax.Array | None


class FixedControllerOutput(NamedTuple):
    leg_targets: jax.Array        # (12,) rad: command after the latency (LEG_ACTUATORS order)
    phi: jax.Array                # filtered pitch, rad
    roll: jax.Array               # filtered roll, rad
    gate: jax.Array               # detection gate this period, 0 or 1
    reachable: jax.Array          # IK reached the CPG's targets
    leg_targets_prev: jax.Array   # (12,) rad: the command the servos hold for latency_frac


def _targets(n_ticks, x_sup, y_sup, coef, config):
    p_right, p_left = cpg_feet_fx(n_ticks, x_sup, y_sup, coef, config)
    return solve_legs_fx(p_right, p_left, coef, config)


def stand_leg_targets_fx(params: ControllerParams, config: FixedPointConfig) -> jax.Array:
    """(12,) angle words of the stand pose."""
    coef = coefficients(params, config)
    zero = jnp.int32(0)
    return _targets(jnp.int32(-1), zero, zero, coef, config)[0]


def controller_init_fx(params: ControllerParams, config: FixedPointConfig = FixedPointConfig(),
                       dtype=jnp.float32) -> FixedControllerState:
    """Robot standing in its `stand` keyframe: filter at the standing lean, stand commands."""
    coef = coefficients(params, config)
    zero, fzero = jnp.int32(0), jnp.zeros((), dtype)
    lean = requant(coef.standing_lean, config.angle, config.state, config.rounding)
    stand = stand_leg_targets_fx(params, config)
    n = config.latency_ticks + 1
    shadow = controller_init(params, dtype) if config.straight_through else None
    return FixedControllerState(
        phi=jnp.stack([lean, zero]), p=jnp.stack([coef.kalman_r, coef.kalman_r]), tick=zero,
        step_start_tick=jnp.int32(NOT_STARTED_TICK), stepping=jnp.asarray(False), x_sup=zero,
        y_sup=zero, phi_at_detect=zero, delay=jnp.broadcast_to(stand, (n, 12)),
        x_sup_m=fzero, y_sup_m=fzero, step_weight=fzero, shadow=shadow,
        delay_grad=(jnp.broadcast_to(to_float(stand, config.angle, dtype), (n, 12))
                    if config.straight_through else None))


def _float_view(s: FixedControllerState, params: ControllerParams, config: FixedPointConfig,
                dtype) -> ControllerState:
    """The float controller state whose values the fixed-point registers hold."""
    f = lambda w, fmt: to_float(w, fmt, dtype)            # noqa: E731
    dt = jax.lax.stop_gradient(jnp.asarray(params.control_period, dtype))
    return ControllerState(
        kalman=KalmanState(phi=f(s.phi, config.state), p=f(s.p, config.cov)),
        time_s=s.tick.astype(dtype) * dt, step_weight=s.stepping.astype(dtype),
        step_start_s=jnp.where(s.stepping, s.step_start_tick.astype(dtype) * dt,
                               jnp.asarray(_NOT_STARTED_S, dtype)),
        x_sup_m=f(s.x_sup, config.length), y_sup_m=f(s.y_sup, config.length),
        phi_at_detect=f(s.phi_at_detect, config.state), steps=StepsState.init(dtype))


def controller_step_fx(state: FixedControllerState, sensors: Sensors, params: ControllerParams,
                       enabled: jax.Array = 1.0, config: FixedPointConfig = FixedPointConfig()
                       ) -> tuple[FixedControllerState, FixedControllerOutput]:
    """One control period in fixed point; semantics of `controller_step` (hard gate)."""
    c, rnd = config, config.rounding
    dtype = state.x_sup_m.dtype
    coef = coefficients(params, c)
    gyro = jnp.asarray(sensors.gyro)
    rate = quantize(jnp.stack([gyro[..., 1], gyro[..., 0]], -1), c.rate, rnd)
    accel = quantize(jnp.asarray(sensors.accel) / STANDARD_GRAVITY, c.accel, rnd)
    phi, p = kalman_step_fx(state.phi, state.p, rate, accel_to_angle_fx(accel, c), coef, c)
    pitch, psi = phi[..., 0], neg(phi[..., 1], c.state)  # psi: lateral lean, + toward +y
    on = jnp.asarray(enabled) > 0.5
    gate_lat = coef.lateral & band_gate_fx(psi, neg(coef.eps_lateral, c.state), coef.eps_lateral)
    gate = on & (band_gate_fx(pitch, neg(coef.eps_backward, c.state), coef.eps_forward) | gate_lat)
    trigger = gate & ~state.stepping                      # only the first detection counts
    theta = sub(requant(pitch, c.state, c.angle, rnd), coef.cp_angle_offset, c.angle)
    # cp_excess: the excess over the threshold on pitch's side of cp_mid (controller.cp_angle).
    threshold = jnp.where(pitch >= coef.cp_mid, coef.eps_forward, neg(coef.eps_backward, c.state))
    excess = requant(sub(pitch, threshold, c.state), c.state, c.angle, rnd)
    theta = jnp.where(coef.cp_excess, excess, theta)
    steps = step_length_fx(jnp.stack([theta, requant(psi, c.state, c.angle, rnd)]), coef, c)
    x_sup = jnp.where(trigger, steps[0], state.x_sup)
    y_sup = jnp.where(trigger & coef.lateral, steps[1], state.y_sup)
    start = jnp.where(trigger, state.tick, state.step_start_tick)
    # cp_update_window: x_Sup follows the current angle while the step is younger than
    # update_ticks periods and the pitch still lies outside its band (controller_step's rule).
    age = jnp.left_shift(jnp.clip(state.tick - start, 0, (1 << 10) - 1),
                         coef_format("update_ticks", c).frac_bits)
    updating = (coef.cp_update & state.stepping & ~trigger & (age < coef.update_ticks)
                & band_gate_fx(pitch, neg(coef.eps_backward, c.state), coef.eps_forward))
    x_sup = jnp.where(updating, steps[0], x_sup)
    targets, reachable = _targets(state.tick - start, x_sup, y_sup, coef, c)
    # Delay line: [T_{k-N-1} .. T_{k-1}] + T_k; command T_{k-N}, previous command T_{k-N-1}.
    full = jnp.concatenate([state.delay, targets[None]], 0)
    n = c.latency_ticks
    new = FixedControllerState(
        phi=phi, p=p, tick=state.tick + 1, step_start_tick=start,
        stepping=state.stepping | gate, x_sup=x_sup, y_sup=y_sup,
        phi_at_detect=jnp.where(trigger, pitch, state.phi_at_detect), delay=full[1:],
        x_sup_m=state.x_sup_m, y_sup_m=state.y_sup_m, step_weight=state.step_weight,
        shadow=None, delay_grad=None)
    view = _float_view(new, params, c, dtype)
    legs = to_float(full[-(n + 1)], c.angle, dtype)
    legs_prev = to_float(full[0], c.angle, dtype)
    out_phi, out_roll = view.kalman.phi[..., 0], view.kalman.phi[..., 1]
    out_gate = gate.astype(dtype)
    delay_grad = None
    if c.straight_through:
        shadow, out_f = controller_step(state.shadow, sensors, params, enabled)
        view = jax.tree_util.tree_map(straight_through, shadow, view)
        full_g = jnp.concatenate([state.delay_grad, out_f.leg_targets[None].astype(dtype)], 0)
        delay_grad = full_g[1:]
        legs = straight_through(full_g[-(n + 1)], legs)
        legs_prev = straight_through(full_g[0], legs_prev)
        out_phi = straight_through(out_f.phi.astype(dtype), out_phi)
        out_roll = straight_through(out_f.roll.astype(dtype), out_roll)
        out_gate = straight_through(out_f.gate.astype(dtype), out_gate)
    new = dataclasses.replace(new, x_sup_m=view.x_sup_m, y_sup_m=view.y_sup_m,
                              step_weight=view.step_weight,
                              shadow=view if c.straight_through else None, delay_grad=delay_grad)
    return new, FixedControllerOutput(legs, out_phi, out_roll, out_gate, reachable, legs_prev)


def servo_command(out: FixedControllerOutput, substep: jax.Array, switch_substep: int) -> jax.Array:
    """Command of physics substep `substep` of a tick: the previous one before the switch."""
    return jnp.where(substep < switch_substep, out.leg_targets_prev, out.leg_targets)
