"""The persistent-cache helpers of `tkujax.sweeps.compile_cache`: a fresh cache compiles cold,
and `persistent_cache_hits` sees the compile that the cache then serves."""

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.sweeps.compile_cache import fresh_compilation_cache, persistent_cache_hits


def _compile_and_run():
    # A new function object each time: only the persistent cache can serve the second compile
    # once the in-memory caches are cleared.
    # A numpy input: no other program (jnp.ones is one) is compiled in the block.
    return jax.jit(lambda x: jnp.sin(x) * 3.0 + 1.0)(np.ones(3, np.float32)).block_until_ready()


def test_cache_hits_counted_only_when_read_from_the_cache():
    with fresh_compilation_cache():
        with persistent_cache_hits() as cold:
            first = _compile_and_run()
        jax.clear_caches()
        with persistent_cache_hits() as warm:
            second = _compile_and_run()
    assert cold["hits"] == 0
    assert warm["hits"] == 1
    assert jnp.array_equal(first, second)
    with persistent_cache_hits() as after:      # the listener is gone with its block
        pass
    assert after["hits"] == 0
