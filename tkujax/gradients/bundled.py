"""Bundled (randomised-smoothing) gradients: each push sees its own perturbed parameters,
z_i = z + sigma eps_i, eps_i ~ N(0, I), and the batch gradient is the mean of the per-push
gradients at z_i (Suh, Pang and Tedrake, RA-L 2022): an estimate of the gradient of the loss
smoothed by a Gaussian of width sigma, which averages over the contact switches that make the
plain gradient jump."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Bundled:
    """loss, grad: batch means; losses (n,), grads (n, d): per push; noise (n, d): eps_i."""

    loss: jax.Array
    grad: jax.Array
    losses: jax.Array
    grads: jax.Array
    noise: jax.Array


def bundled_value_and_grad(per_push: Callable, z: jax.Array, pushes, key: jax.Array,
                           sigma, antithetic: bool = False) -> Bundled:
    """per_push(z, push) -> (loss, grad) of one push at flat parameters z (d,); pushes: a
    pytree with a leading batch axis n. antithetic: eps_{i + n/2} = -eps_i (n even), so the
    noise's mean is exactly 0 (its first-order bias cancels between pairs of pushes)."""
    n = jax.tree_util.tree_leaves(pushes)[0].shape[0]
    if antithetic:
        if n % 2:
            raise ValueError("antithetic noise needs an even number of pushes")
        half = jax.random.normal(key, (n // 2,) + z.shape, z.dtype)
        eps = jnp.concatenate([half, -half], 0)
    else:
        eps = jax.random.normal(key, (n,) + z.shape, z.dtype)
    losses, grads = jax.vmap(per_push)(z + sigma * eps, pushes)
    return Bundled(loss=jnp.mean(losses), grad=jnp.mean(grads, 0), losses=losses, grads=grads,
                   noise=eps)


def bundle_noise(rng, n: int, d: int, antithetic: bool = False):
    """(n, d) standard normal noise eps_i from a numpy Generator (the tuner's bundled
    gradients, TuneProblem.grouped_value_and_grad): antithetic, eps_{i + n/2} = -eps_i (n
    even), as in `bundled_value_and_grad`."""
    if not antithetic:
        return rng.standard_normal((n, d))
    if n % 2:
        raise ValueError("antithetic noise needs an even number of pushes")
    half = rng.standard_normal((n // 2, d))
    return np.concatenate([half, -half], 0)
