"""Process-wide settings of the command line, applied in `tkujax.cli.main`, never on import."""

from __future__ import annotations

import os
from pathlib import Path

from tkujax.cli.errors import interrupts_deferred


def configure_runtime() -> None:
    """Persistent XLA compilation cache and a headless GL default (EGL, where present)."""
    # mujoco reads MUJOCO_GL at import and fails to import at all when the chosen library is
    # missing: default to EGL only where libEGL exists (headless rendering), else leave it.
    import ctypes.util

    if "MUJOCO_GL" not in os.environ and ctypes.util.find_library("EGL"):
        os.environ["MUJOCO_GL"] = "egl"
    with interrupts_deferred():     # a Ctrl-C while JAX's extensions load: after they have
        import jax

    cache = os.environ.get("TKUJAX_CACHE_DIR", str(Path.home() / ".cache" / "tkujax" / "jax"))
    jax.config.update("jax_compilation_cache_dir", cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
