"""Gradient-safe elementary functions shared by the controller's math (Kalman, IK).

`jnp.where(c, f(x), 0)` alone does not protect a gradient: reverse mode still evaluates the
derivative of the unselected branch and multiplies it by a zero cotangent, and 0 * inf = NaN.
The "double where" below therefore also replaces the *input* of the dangerous branch by a
harmless value wherever that branch is not selected, so both branches and their derivatives
are finite everywhere.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["safe_atan2", "safe_norm", "safe_sqrt"]


def safe_atan2(y: jax.Array, x: jax.Array) -> jax.Array:
    """atan2(y, x) whose value and gradient are 0 (not NaN) at y = x = 0.

    d atan2 = (x dy - y dx) / (x^2 + y^2) is 0/0 at the origin; the double `where` feeds the
    origin a harmless (0, 1) so neither branch's gradient is NaN. Elsewhere it equals
    `jnp.arctan2` in value and gradient.
    """
    zero = (x * x + y * y) == 0
    return jnp.where(zero, 0.0, jnp.arctan2(jnp.where(zero, 0.0, y), jnp.where(zero, 1.0, x)))


def safe_sqrt(x: jax.Array) -> jax.Array:
    """sqrt(x) with value 0 and a finite (zero) gradient for x <= tiny.

    d sqrt = 1 / (2 sqrt x) is infinite at 0 (and NaN below); inputs at or below the smallest
    normal float of x's dtype are mapped to 0 with zero gradient, so the gradient is bounded by
    1 / (2 sqrt(tiny)) everywhere. Above that it equals `jnp.sqrt` in value and gradient.
    """
    tiny = jnp.finfo(jnp.result_type(x, float)).tiny
    pos = x > tiny
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, x, 1.0)), 0.0)


def safe_norm(*xs: jax.Array) -> jax.Array:
    """Euclidean norm sqrt(sum x_i^2) of the given components, elementwise.

    Value 0 and a finite (zero) gradient at the origin, where the gradient x / |x| of the plain
    norm is 0/0 (see `safe_sqrt`).
    """
    return safe_sqrt(sum(x * x for x in xs))
