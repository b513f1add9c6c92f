"""A loop whose reverse-mode derivative is a hand-built adjoint, not JAX's autodiff of a scan.

`iterate(f, init, length)` is `lax.scan(lambda c, _: (f(c), None), init, None, length)[0]`:
`length` applications of `f` to a carry. Its VJP is written out (`jax.custom_vjp`):
- forward: one scan that also stores the carry before each step, only the leaves `f` reads
  (found from its jaxpr: MJX's state has many fields a step overwrites without reading);
- backward: a reverse scan whose body is `jax.vjp` of one step at its stored carry.
The same arithmetic as `jax.grad` of a scan with `jax.checkpoint` on each step (the step is
recomputed in the backward pass either way), to float rounding. Why: on one H200 XLA
compiles this program for a 750-step MJX rollout's gradient in 40 s against 63 s for the
checkpointed scan's, with the same run time (results/bench/README.md, session 14).

The traced values `f` closes over (the model's per-push fields, the push) are hoisted into
explicit arguments, so their derivatives flow and vmap sees them (`jax.closure_convert` would
hoist only the ones being differentiated, leaving vmap's closed over). Integer leaves of the
carry and integer closed-over values are carried, never differentiated.
"""

from __future__ import annotations

import functools

import jax
import jax.extend as jex
import jax.numpy as jnp
import numpy as np


def _is_float(x) -> bool:
    return jnp.issubdtype(jnp.result_type(x), jnp.inexact)


def iterate(f, init, length: int, unroll: int = 1):
    """`length` applications of `f` (carry -> carry, the same structure) to `init`, with
    the hand-built adjoint above. `unroll`: lax.scan unrolling of both passes."""
    if length < 1:
        return init
    leaves, tree = jax.tree.flatten(init)

    def f_leaves(*xs):
        return tuple(jax.tree.leaves(f(jax.tree.unflatten(tree, list(xs)))))

    closed = jax.make_jaxpr(f_leaves)(*leaves)
    hoist = tuple(isinstance(c, jax.core.Tracer) for c in closed.consts)
    kept = tuple(None if h else c for c, h in zip(closed.consts, hoist))
    jaxpr = closed.jaxpr

    def step(*xs_and_hoisted):
        xs, it = xs_and_hoisted[:len(leaves)], iter(xs_and_hoisted[len(leaves):])
        consts = [next(it) if h else c for c, h in zip(kept, hoist)]
        return tuple(jex.core.jaxpr_as_fun(jex.core.ClosedJaxpr(jaxpr, consts))(*xs))

    used = {id(v) for eqn in jaxpr.eqns for v in eqn.invars} | {id(v) for v in jaxpr.outvars}
    read = tuple(id(v) in used for v in jaxpr.invars)       # the leaves a step reads
    consts = tuple(c for c, h in zip(closed.consts, hoist) if h)
    # Differentiated: the float carry leaves, and the closed-over values that carry a tangent
    # (those jax.closure_convert hoists). The others (vmap's per-push model fields, the push)
    # get no cotangent: the backward pass would compute it for nothing.
    perturbed = {id(c) for c in jax.closure_convert(f_leaves, *leaves)[1]}
    diff = (tuple(_is_float(x) for x in leaves)
            + tuple(_is_float(c) and id(c) in perturbed for c in consts))
    out = _iterate(step, length, unroll, diff, read, tuple(leaves), consts)
    return jax.tree.unflatten(tree, list(out))


@functools.partial(jax.custom_vjp, nondiff_argnums=(0, 1, 2, 3, 4))
def _iterate(fn, length, unroll, diff, read, leaves, consts):
    def body(c, _):
        return tuple(fn(*c, *consts)), None
    return jax.lax.scan(body, leaves, None, length=length, unroll=unroll)[0]


def _iterate_fwd(fn, length, unroll, diff, read, leaves, consts):
    def body(c, _):
        return tuple(fn(*c, *consts)), tuple(x for x, r in zip(c, read) if r)
    final, stored = jax.lax.scan(body, leaves, None, length=length, unroll=unroll)
    # A leaf no step reads is any value in the backward pass: the initial one, kept once.
    unread = tuple(x for x, r in zip(leaves, read) if not r)
    return final, (stored, unread, consts)


def _iterate_bwd(fn, length, unroll, diff, read, residuals, cotangent):
    stored, unread, consts = residuals
    n = len(cotangent)
    diff_x, diff_c = diff[:n], diff[n:]

    def carry_at(step_stored):
        """The carry before a step: its stored leaves and the unread ones."""
        it_stored, it_unread = iter(step_stored), iter(unread)
        return tuple(next(it_stored) if r else next(it_unread) for r in read)

    def body(acc, step_stored):
        lam, g_consts = acc
        c = carry_at(step_stored)

        def step(float_leaves, float_consts):
            it, ic = iter(float_leaves), iter(float_consts)
            out = fn(*(next(it) if d else x for x, d in zip(c, diff_x)),
                     *(next(ic) if d else x for x, d in zip(consts, diff_c)))
            return tuple(y for y, d in zip(out, diff_x) if d)

        _, pullback = jax.vjp(step, _floats(c, diff_x), _floats(consts, diff_c))
        lam, g = pullback(lam)
        return (lam, jax.tree.map(jnp.add, g_consts, g)), None

    lam = _floats(cotangent, diff_x)
    g0 = tuple(jnp.zeros_like(x) for x in _floats(consts, diff_c))
    (lam, g_consts), _ = jax.lax.scan(body, (lam, g0), stored, length=length, reverse=True,
                                      unroll=unroll)
    # Integer leaves: their incoming cotangent (float0 zeros) goes back as it came; the
    # closed-over values not differentiated get zeros (float0 for integers).
    it, ic = iter(lam), iter(g_consts)
    return (tuple(next(it) if d else ct for ct, d in zip(cotangent, diff_x)),
            tuple(next(ic) if d else _zero_cotangent(x) for x, d in zip(consts, diff_c)))


def _zero_cotangent(x):
    return (jnp.zeros_like(x) if _is_float(x) else np.zeros(np.shape(x), jax.dtypes.float0))


def _floats(xs, diff):
    return tuple(x for x, d in zip(xs, diff) if d)


_iterate.defvjp(_iterate_fwd, _iterate_bwd)
