"""Offscreen pictures and videos (MuJoCo's renderer; needs EGL or OSMesa on Linux): TKU-X, a
paper case (`render_case`) and a walk (`save_walk_figures`). The simulations stay in their
layers (studies.paper, walking); drawing happens here, at the top.

On a headless Linux machine: `apt-get install libegl1 libgl1-mesa-dri` and MUJOCO_GL=egl (the CLI
sets egl when MUJOCO_GL is unset), or `apt-get install libosmesa6` and MUJOCO_GL=osmesa.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import mujoco
import numpy as np


def rendering_available() -> tuple[bool, str]:
    """Whether an offscreen GL context can be made here, and why not."""
    # A context can appear to be made and still be unusable (GLFW without a display only
    # warns), so render one frame of an empty model; GLFW's warnings are not the user's business.
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with mujoco.Renderer(mujoco.MjModel.from_xml_string("<mujoco/>"), 16, 16) as r:
                r.render()
        return True, ""
    except Exception as err:  # noqa: BLE001 - any GL failure means "cannot render"
        return False, f"{type(err).__name__}: {err} (MUJOCO_GL={os.environ.get('MUJOCO_GL')})"


def _camera(azimuth_deg: float, scale: float = 1.0) -> mujoco.MjvCamera:
    """The camera on TKU-X (scale 1), or on a robot `scale` times its size."""
    cam = mujoco.MjvCamera()
    cam.lookat[:] = (0.0, 0.0, 0.27 * scale)
    cam.distance = 1.15 * scale
    cam.azimuth = azimuth_deg
    cam.elevation = -12.0
    return cam


def render_frames(model: mujoco.MjModel, qpos_seq: np.ndarray, width: int = 480,
                  height: int = 400, azimuth_deg: float = 215.0,
                  track_xy: bool = True, all_geom_groups: bool = False,
                  scale: float = 1.0) -> list[np.ndarray]:
    """RGB frames (height, width, 3) uint8 for each row of `qpos_seq` (n, nq).
    all_geom_groups: draw every geom group, the collision geoms (often hidden) included.
    scale: the robot's size against TKU-X's (the camera's distance and height follow it)."""
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not 16 <= v <= 4096:
            raise ValueError(f"{name} must be an integer in [16, 4096] pixels, got {v!r}")
    data = mujoco.MjData(model)
    if not 0.1 <= scale <= 20.0:
        raise ValueError(f"scale must be in [0.1, 20], got {scale!r}")
    cam = _camera(azimuth_deg, scale)
    scene_option = mujoco.MjvOption()
    scene_option.sitegroup[:] = 0   # hide sensor sites; show the bodies
    if all_geom_groups:
        scene_option.geomgroup[:] = 1
    frames = []
    with mujoco.Renderer(model, height, width) as renderer:
        for qpos in np.atleast_2d(qpos_seq):
            data.qpos[:] = qpos
            mujoco.mj_forward(model, data)
            if track_xy:
                cam.lookat[:2] = data.qpos[:2]
            renderer.update_scene(data, cam, scene_option)
            frames.append(renderer.render().copy())
    return frames


def save_image(frame: np.ndarray, out: str | Path) -> Path:
    from PIL import Image  # pillow ships with matplotlib

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(frame).save(out)
    return out


def save_gif(frames: list[np.ndarray], out: str | Path, fps: float) -> Path:
    from PIL import Image

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    images = [Image.fromarray(f) for f in frames]
    images[0].save(out, save_all=True, append_images=images[1:], loop=0,
                   duration=int(round(1000.0 / fps)), optimize=True)
    return out


def check_rendering() -> None:
    """Raise RuntimeError, with what to install, when no offscreen GL context can be made."""
    ok, why = rendering_available()
    if not ok:
        raise RuntimeError(f"rendering is not available here ({why}); on Linux install EGL "
                           "(libegl1, libgl1-mesa-dri) or OSMesa and set MUJOCO_GL")


def render_case(case: str, control_on: bool, out: str | Path, width: int = 480,
                height: int = 400, impulse_scale: float = 1.0) -> Path:
    """GIF of one paper case, e.g. case='volleyball-back' (`studies.paper.case_trajectory`)."""
    from tkujax.studies.paper import case_trajectory

    model, qpos, period_s = case_trajectory(case, control_on, impulse_scale)
    return save_gif(render_frames(model, qpos, width, height), out, fps=1.0 / period_s)


# A walk's figures (`tkujax walk --gif/--png`): the GIF at about WALK_GIF_FPS frames per second
# of simulated time, the picture WALK_STRIP_FRAMES frames side by side over the last gait cycle.
WALK_GIF_FPS = 10.0
WALK_STRIP_FRAMES = 6
WALK_FRAME_SIZE = (280, 240)          # width, height (pixels)


def save_walk_figures(model: mujoco.MjModel, qpos: np.ndarray, period_s: float, last: int,
                      cycle_s: float, scale: float, gif: str | Path | None = None,
                      png: str | Path | None = None) -> dict:
    """Write the GIF and/or the picture of one walk: qpos (n, nq) sampled every period_s, the
    walk ending at sample `last` (its end or its fall), cycle_s one gait cycle (2 T), scale the
    robot's size against TKU-X's (the camera follows the base). Returns {"gif": path, "png":
    path} of what was written."""
    width, height = WALK_FRAME_SIZE
    out = {}
    if gif is not None:
        every = max(1, int(round(1.0 / (WALK_GIF_FPS * period_s))))
        frames = render_frames(model, qpos[:last + 1:every], width, height, scale=scale)
        out["gif"] = str(save_gif(frames, gif, fps=1.0 / (every * period_s)))
    if png is not None:
        first = max(0, last - int(round(cycle_s / period_s)))
        picks = np.linspace(first, last, WALK_STRIP_FRAMES).round().astype(int)
        frames = render_frames(model, qpos[picks], width, height, scale=scale)
        out["png"] = str(save_image(np.concatenate(frames, axis=1), png))
    return out


def walk_figures(result: dict, series, who, command, gif: str | Path | None = None,
                 png: str | Path | None = None) -> dict:
    """`save_walk_figures` of what `tkujax.walking.walk.walk_once` returns (result, series, the
    Walker, the command): up to the walk's end or its fall, the camera sized to the robot by
    its CoM height against TKU-X's, a gait cycle of 2 T in the picture."""
    from tkujax.control.controller_params import ControllerParams

    t = np.asarray(series.t[0])
    period = float(t[1] - t[0])
    last = int(np.searchsorted(t, result["fall_s"])) if result["fell"] else len(t) - 1
    scale = float(who.gait_params.com_height) / float(ControllerParams.paper().com_height)
    return save_walk_figures(who.robot.host_model, np.asarray(series.qpos[0]), period,
                             min(last, len(t) - 1), 2.0 * float(command.step_period_s), scale,
                             gif, png)
