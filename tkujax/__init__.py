"""tkujax: a JAX-vectorised, differentiable simulator for humanoid push-recovery sweeps.

Submodules are imported lazily so that the CLI can set MUJOCO_GL and XLA options first.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"
__all__ = ["ModelParams", "load_model", "__version__"]


def __getattr__(name: str):
    if name in ("ModelParams", "load_model"):
        return getattr(importlib.import_module("tkujax.model"), name)
    raise AttributeError(f"module 'tkujax' has no attribute {name!r}")
