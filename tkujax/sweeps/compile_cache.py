"""A fresh persistent compilation cache for a block: cold compile timings (`tkujax bench`, the
gradient benchmark of `tkujax.studies.tune.benchmark`); and a count of the compiles a block
read from the persistent cache (a "first call" that read it was not a cold compile)."""

from __future__ import annotations

import contextlib
import tempfile

import jax


@contextlib.contextmanager
def fresh_compilation_cache():
    """A persistent compilation cache in an empty temporary folder for the block, then the
    previous one again. JAX reads the cache folder once, at its first compile: the cache is
    reset on both sides, or the change would be ignored (and "cold" read the old cache)."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    old_dir = jax.config.jax_compilation_cache_dir
    old_min = jax.config.jax_persistent_cache_min_compile_time_secs
    try:
        with tempfile.TemporaryDirectory() as cache:
            jax.config.update("jax_compilation_cache_dir", cache)
            jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
            cc.reset_cache()
            yield cache
    finally:
        jax.config.update("jax_compilation_cache_dir", old_dir)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", old_min)
        cc.reset_cache()


_CACHE_HIT_EVENT = "/jax/compilation_cache/cache_hits"


@contextlib.contextmanager
def persistent_cache_hits():
    """Counts the compiles in the block that JAX read from the persistent cache: yields a dict
    whose "hits" grows as they happen (JAX's monitoring event for a cache hit)."""
    count = {"hits": 0}

    def listener(event: str, **_) -> None:
        if event == _CACHE_HIT_EVENT:
            count["hits"] += 1

    jax.monitoring.register_event_listener(listener)
    try:
        yield count
    finally:
        jax.monitoring.unregister_event_listener(listener)
