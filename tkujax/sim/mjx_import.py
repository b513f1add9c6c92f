"""`mjx`, imported without the noise of its optional Warp backend.

mujoco.mjx tries to import the optional `warp` / `mujoco_warp` packages and prints "Failed to
import ..." to stdout when they are absent; tkujax never uses that backend, so the message is
not the user's business. Every tkujax module imports mjx from here.
"""

from __future__ import annotations

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()):
    from mujoco import mjx  # noqa: F401
