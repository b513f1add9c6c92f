"""Test-wide set-up: headless GL, persistent XLA cache (MJX compiles are slow on CPU)."""

import ctypes.util
import os
from pathlib import Path

# Headless rendering through EGL where libEGL exists; elsewhere rendering tests skip (setting
# MUJOCO_GL=egl without libEGL would make `import mujoco` itself fail).
if "MUJOCO_GL" not in os.environ and ctypes.util.find_library("EGL"):
    os.environ["MUJOCO_GL"] = "egl"

import jax

_cache = os.environ.get("TKUJAX_CACHE_DIR", str(Path.home() / ".cache" / "tkujax" / "jax"))
jax.config.update("jax_compilation_cache_dir", _cache)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
