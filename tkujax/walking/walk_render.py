"""`tkujax walk --gif F.gif --png F.png`: the walk as a video and as a picture.

The walk's qpos (recorded once per control period) drawn by MuJoCo's offscreen renderer
(`tkujax.render`, EGL or OSMesa), the camera following the base and sized to the robot (its CoM
height against TKU-X's): the GIF at about GIF_FPS frames per second of simulated time, the
picture STRIP_FRAMES frames side by side over the last gait cycle (two steps) before the end or
the fall.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from tkujax import render
from tkujax.control.controller_params import ControllerParams

GIF_FPS = 10.0
STRIP_FRAMES = 6
FRAME_WIDTH, FRAME_HEIGHT = 280, 240


def camera_scale(com_height_m: float) -> float:
    """The robot's size against TKU-X's, by CoM height (the camera's distance follows it)."""
    return float(com_height_m) / float(ControllerParams.paper().com_height)


def check_rendering() -> None:
    """Raise RuntimeError, with what to install, when no offscreen GL context can be made."""
    ok, why = render.rendering_available()
    if not ok:
        raise RuntimeError(f"rendering is not available here ({why}); on Linux install EGL "
                           "(libegl1, libgl1-mesa-dri) or OSMesa and set MUJOCO_GL")


def save_walk_figures(model, qpos: np.ndarray, period_s: float, last: int, cycle_s: float,
                      com_height_m: float, gif: str | Path | None = None,
                      png: str | Path | None = None) -> dict:
    """Write the GIF and/or the picture of one walk: qpos (n, nq) sampled every period_s, the
    walk ending at sample `last` (its end or its fall), cycle_s one gait cycle (2 T). Returns
    {"gif": path, "png": path} of what was written."""
    scale = camera_scale(com_height_m)
    out = {}
    if gif is not None:
        every = max(1, int(round(1.0 / (GIF_FPS * period_s))))
        frames = render.render_frames(model, qpos[:last + 1:every], FRAME_WIDTH, FRAME_HEIGHT,
                                      scale=scale)
        out["gif"] = str(render.save_gif(frames, gif, fps=1.0 / (every * period_s)))
    if png is not None:
        first = max(0, last - int(round(cycle_s / period_s)))
        picks = np.linspace(first, last, STRIP_FRAMES).round().astype(int)
        frames = render.render_frames(model, qpos[picks], FRAME_WIDTH, FRAME_HEIGHT, scale=scale)
        out["png"] = str(render.save_image(np.concatenate(frames, axis=1), png))
    return out
