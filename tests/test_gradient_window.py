"""ProgramOptions.gradient_window_ticks: truncated backpropagation (Brax APG's
truncation_length). Forward values unchanged bit for bit; no gradient crosses a window's
start; within one window the gradient is the finite difference's. Five 30 ms ticks with the
compact tree passes (the smaller gradient program), control off, no servo quantisation."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.sim.options import Episode, ProgramOptions, RolloutConfig
from tkujax.sim.push import Push
from tkujax.sim.rollout_mjx import rollout
from tkujax.sim.setup import init


@functools.cache
def _fn(window, loop="nested", grad=False):
    """jit of (impulse, onset) -> the Series (or value_and_grad of the last tick's CoM x
    with respect to the impulse)."""
    _, model, index, state = init()
    config = RolloutConfig(duration_s=0.15, quantise_targets=False, program=ProgramOptions(
        tree_passes="compact", loop=loop, gradient_window_ticks=window))

    def series(impulse, onset):
        push = Push(impulse, jnp.float32(0.0), jnp.float32(0.36), jnp.float32(0.02), onset)
        return rollout(model, state, Episode(push, jnp.float32(0.0), jax.random.PRNGKey(0)),
                       ControllerParams.paper(), config, index)

    if grad:
        return jax.jit(jax.value_and_grad(lambda i, o: series(i, o).com[-1, 0]))
    return jax.jit(series)


@pytest.mark.parametrize("loop", ["nested", "flat"])
def test_window_keeps_forward_values(loop):
    args = (jnp.float32(2.0), jnp.float32(0.03))
    plain, windowed = _fn(None, loop)(*args), _fn(2, loop)(*args)
    for name in plain.keys():
        if plain[name] is not None:
            np.testing.assert_array_equal(np.asarray(windowed[name]), np.asarray(plain[name]),
                                          err_msg=name)


@pytest.mark.slow
def test_window_of_one_tick_cuts_the_gradient_of_an_early_push():
    """The push acts in tick 0 only; the CoM at tick 4 depends on it, but with K = 1 no
    gradient reaches back past tick 4's start."""
    value, grad = _fn(1, grad=True)(jnp.float32(2.0), jnp.float32(0.0))
    assert np.isfinite(float(value)) and float(grad) == 0.0


@pytest.mark.slow
def test_gradient_within_one_window_matches_finite_differences():
    """K = 3: ticks 3-4 are one window; a push in tick 3 moves the CoM at tick 4, and the
    windowed gradient is the central finite difference of the forward values."""
    onset, impulse, h = jnp.float32(0.09), 2.0, 0.1
    _, grad = _fn(3, grad=True)(jnp.float32(impulse), onset)
    fwd = _fn(None)
    fd = (float(fwd(jnp.float32(impulse + h), onset).com[-1, 0])
          - float(fwd(jnp.float32(impulse - h), onset).com[-1, 0])) / (2 * h)
    assert abs(fd) > 1e-5
    assert float(grad) == pytest.approx(fd, rel=0.05)
