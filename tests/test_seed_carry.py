"""The rollout's seeded scan carry (tkujax.sim.rollout_mjx.seed_carry): values bit for bit
unchanged (signed zeros, infinities and NaN included, whatever the inputs hold), but batched
under vmap and differentiated under jvp from the start, so that lax.scan's fixpoints end in
one pass. Pure JAX on tiny arrays: no MJX compile."""

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.sim.rollout_mjx import seed_carry

CARRY = (jnp.array([-0.0, 0.0, 1.5, -np.inf, np.inf, np.nan], jnp.float32),
         {"ticks": jnp.array(3, jnp.int32), "x": jnp.float32(-2.25)})


def _bits(tree):
    return [np.asarray(x).tobytes() for x in jax.tree.leaves(tree)]


def test_values_are_unchanged_bit_for_bit():
    for inputs in ((jnp.float32(-3.0), jnp.array([1.0, -7.0])),
                   (jnp.float32(np.inf), jnp.array([np.nan, -np.inf])),   # non-finite inputs
                   (None, 2, jnp.float32(0.0))):                          # no float leaves but one
        out = seed_carry(CARRY, inputs)
        assert _bits(out) == _bits(CARRY)
        assert [x.dtype for x in jax.tree.leaves(out)] == [x.dtype for x in jax.tree.leaves(CARRY)]


def test_carry_is_batched_under_vmap():
    """An unbatched carry comes out batched when the inputs are (one value per push)."""
    pushes = jnp.array([0.5, 1.0, 2.0])
    out = jax.vmap(lambda p: seed_carry(CARRY, (p,)))(pushes)
    assert out[0].shape == (3, 6) and out[1]["x"].shape == (3,)
    assert out[1]["ticks"].shape == (3,)          # integer leaves are broadcast, not tied
    assert _bits(out[0][1]) == _bits(CARRY[0])


def test_carry_has_a_tangent_under_jvp():
    """d(carry)/d(input) is an explicit zero: the tangent exists (no symbolic Zero), equals 0,
    and the values are unchanged."""
    def f(p):
        return seed_carry(CARRY, (p,))[1]["x"]

    primal, tangent = jax.jvp(f, (jnp.float32(1.3),), (jnp.float32(1.0),))
    assert float(primal) == -2.25 and float(tangent) == 0.0
    jaxpr = jax.make_jaxpr(lambda p, t: jax.jvp(f, (p,), (t,)))(1.3, 1.0)
    # the output tangent is computed from the input tangent, not a literal zero
    assert any(e.primitive.name == "mul" for e in jaxpr.eqns)
    assert float(jax.grad(f)(jnp.float32(1.3))) == 0.0
