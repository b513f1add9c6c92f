"""Where a result came from: package versions and the git commit, recorded by sweeps (their
manifest) and by `tkujax bench`."""

from __future__ import annotations

import platform
import subprocess
from importlib import metadata
from pathlib import Path

PACKAGES = ("tkujax", "jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy")


def package_versions(packages=PACKAGES) -> dict[str, str | None]:
    """{package: installed version, or None where it is not installed}."""
    out = {}
    for pkg in packages:
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def versions(packages=PACKAGES) -> dict[str, str | None]:
    """The Python version and the packages' versions."""
    return {"python": platform.python_version(), **package_versions(packages)}


def git_commit() -> str | None:
    """The commit of the checkout tkujax runs from (None outside a git checkout)."""
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, timeout=5).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None
