"""Test-wide set-up: headless GL, persistent XLA cache (MJX compiles are slow on CPU)."""

import os
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import jax  # noqa: E402

_cache = os.environ.get("TKUJAX_CACHE_DIR", str(Path.home() / ".cache" / "tkujax" / "jax"))
jax.config.update("jax_compilation_cache_dir", _cache)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
