"""Step timing with a gradient (TimingGradientParams): the interpolated crossing time's gradient
against finite differences on a hand-made crossing, and forward values bit-identical to the
plain controller's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.controller import (Sensors, controller_init, controller_step,
                                       crossing_time_offset, with_timing_gradient)
from tkujax.control.controller_params import ControllerParams

G = 9.81


def _two_ticks(params, gyro_y, dtype):
    """Two periods: at rest, then a pitch rate gyro_y (rad/s) that crosses the trigger."""
    s = controller_init(params, dtype)
    rest = Sensors(jnp.zeros(3, dtype), jnp.array([0.0, 0.0, G], dtype))
    s1, _ = controller_step(s, rest, params)
    s2, out = controller_step(s1, Sensors(jnp.array([0.0, gyro_y, 0.0], dtype),
                                          jnp.array([0.0, 0.0, G], dtype)), params)
    return s1, s2, out


def test_crossing_time_gradient_matches_finite_differences():
    """d step_start / d cp_trigger_forward_m equals the central difference of the crossing time
    interpolated from the two ticks' detection values; the value is the hard start time."""
    with jax.enable_x64(True):
        base = ControllerParams.recommended()
        dtype = jnp.float64

        def start(theta):
            p = with_timing_gradient(base.__class__(**{**_fields(base),
                                                       "cp_trigger_forward_m": theta}))
            return _two_ticks(p, 2.0, dtype)[1].step_start_s

        def interpolated(theta):
            p = with_timing_gradient(base.__class__(**{**_fields(base),
                                                       "cp_trigger_forward_m": theta}))
            s1, s2, _ = _two_ticks(p, 2.0, dtype)
            e0, e1 = s1.detect_prev, s2.detect_prev
            assert e0 <= 0.0 < e1           # a crossing between the two ticks
            return s1.time_s - (1.0 - e0 / (e0 - e1)) * p.control_period

        theta0 = jnp.asarray(base.cp_trigger_forward_m, dtype)
        grad = float(jax.grad(start)(theta0))
        h = 1e-5
        fd = float((interpolated(theta0 + h) - interpolated(theta0 - h)) / (2 * h))
        assert abs(fd) > 1e-3               # the crossing moves with the threshold
        np.testing.assert_allclose(grad, fd, rtol=1e-5)
        # The value is the hard controller's: the tick at which the gate fired.
        assert float(start(theta0)) == float(_two_ticks(base, 2.0, dtype)[1].step_start_s)
        # The plain controller's start time has no gradient in the threshold.
        plain = lambda t: _two_ticks(base.__class__(**{**_fields(base),  # noqa: E731
                                                       "cp_trigger_forward_m": t}),
                                     2.0, dtype)[1].step_start_s
        assert float(jax.grad(plain)(theta0)) == 0.0


def _fields(p):
    import dataclasses
    return {f.name: getattr(p, f.name) for f in dataclasses.fields(ControllerParams)}


def test_option_gives_bit_identical_forward_values():
    """A synthetic push (a pitch-rate pulse) over 40 periods: every state field and output of
    the controller with the option equals the plain controller's bit for bit."""
    rng = np.random.default_rng(0)
    rates = np.concatenate([np.zeros(5), np.full(8, 2.5), 0.3 * rng.standard_normal(27)])
    tilt = np.clip(np.cumsum(rates) * 0.03, -0.6, 0.6)        # the pitch the gyro integrates
    seq = [Sensors(jnp.array([0.1 * r, r, 0.0], jnp.float32),
                   jnp.array([-G * np.sin(a), 0.0, G * np.cos(a)], jnp.float32))
           for r, a in zip(rates, tilt)]
    for base in (ControllerParams.recommended(), ControllerParams.paper()):
        states = {}
        for name, p in (("plain", base), ("option", with_timing_gradient(base))):
            s, rows = controller_init(p), []
            step = jax.jit(controller_step)
            for sens in seq:
                s, out = step(s, sens, p)
                rows.append((s.time_s, s.step_weight, s.step_start_s, s.x_sup_m, s.y_sup_m,
                             s.kalman.phi, s.steps.feet_to, *out))
            states[name] = rows
        assert any(float(r[1]) > 0.5 for r in states["plain"])     # the step was taken
        for a, b in zip(states["plain"], states["option"]):
            for x, y in zip(a, b):
                assert np.array_equal(np.asarray(x), np.asarray(y))


def test_crossing_offset_is_zero_in_value_and_guarded():
    """Zero value everywhere; a finite zero gradient where no crossing happened (e_prev = e_now:
    the interpolation's 0/0 is never evaluated on a selected branch)."""
    def f(e_prev, e_now, starts):
        return crossing_time_offset(starts, e_prev, e_now, jnp.float32(0.3), 0.03)

    for e_prev, e_now, starts in ((-0.01, 0.02, True), (0.0, 0.0, True), (-0.01, 0.02, False),
                                  (0.01, 0.02, True)):
        v = f(jnp.float32(e_prev), jnp.float32(e_now), jnp.asarray(starts))
        g = jax.grad(f, argnums=(0, 1))(jnp.float32(e_prev), jnp.float32(e_now),
                                         jnp.asarray(starts))
        assert float(v) == 0.0
        assert all(np.isfinite(float(x)) for x in g)
        crossed = starts and e_prev <= 0.0 < e_now
        if crossed:     # t_x = t - (1 - e0/(e0 - e1)) dt: d/de0 = dt * (-e1)/(e0 - e1)^2
            d = e_prev - e_now
            np.testing.assert_allclose(float(g[0]), 0.03 * (-e_now) / d ** 2, rtol=1e-5)
            np.testing.assert_allclose(float(g[1]), 0.03 * e_prev / d ** 2, rtol=1e-5)
        else:
            assert float(g[0]) == 0.0 and float(g[1]) == 0.0


def test_latent_moves_the_named_fields_and_carries_the_option():
    from tkujax.control.controller import TimingGradientParams
    from tkujax.studies.gradient_measure import Latent
    base = ControllerParams.recommended()
    lat = Latent(base, timing_gradient=True)
    z = np.zeros(len(lat.names))
    p = lat.apply(jnp.asarray(z))
    assert isinstance(p, TimingGradientParams)
    assert all(float(getattr(p, n)) == float(np.float32(getattr(base, n))) for n in lat.names)
    z[lat.names.index("cp_gain")] = 2.0
    moved = lat.concrete(z)
    assert type(moved) is ControllerParams
    assert moved.cp_gain == base.cp_gain + 2.0 * lat.scales[lat.names.index("cp_gain")]
