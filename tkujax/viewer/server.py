"""The replay viewer's page: viser scene nodes and GUI for a list of `PushScene`s (thin: what
is drawn at a time comes from `PushScene.frame`).

The page has a floor grid, each robot's geoms with its label (impulse, azimuth, outcome), the
push's arrow, the capture point (an orange ball on the floor) and the step's target (a green
disc), a time slider, a play/pause button and a speed control. A browser that moves the slider
calls `ReplayViewer.show`, which moves every node; playing advances the slider in real time
(times the speed) and loops.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time

import numpy as np

from tkujax.viewer.playback import PushScene

ARROW_RGB = (220, 40, 40)
CAPTURE_RGB = (255, 160, 0)
TARGET_RGB = (40, 170, 60)
HEMISPHERE_INTENSITY = 2.0
CAMERA_AZIMUTH_DEG = 45.0   # the first view: from the front-right (+x, -y), from above
CAMERA_ELEVATION_DEG = 30.0
CAMERA_FOV_DEG = 40.0       # vertical; viser's 75 deg default makes a row of robots recede


def rgb255(rgba) -> tuple[int, int, int]:
    return tuple(int(round(255 * float(c))) for c in rgba[:3])


class ReplayViewer:
    """A viser server showing `scenes` side by side. Attributes: server (viser.ViserServer),
    slider (time, s), play (button), speed (slider), geoms[k][j] (scene k's shape j's handle),
    capture[k], arrows[k], targets[k] (None without a step), labels[k]; time_s: the time shown
    (set once every node is posed for it)."""

    def __init__(self, scenes: list[PushScene], host: str = "127.0.0.1", port: int = 8080,
                 verbose: bool = False):
        import viser

        if not scenes:
            raise ValueError("no records to show")
        self.scenes = scenes
        self.t = scenes[0].t
        self._verbose = verbose
        with self._quiet():
            self.server = viser.ViserServer(host=host, port=port, verbose=verbose)
        self._lock = threading.Lock()          # one pose update at a time
        self._play_lock = threading.Lock()     # play/pause against a step of the player
        self._playing = threading.Event()
        self._closed = threading.Event()
        self.time_s = float(self.t[0])
        self._shown: dict[int, int] = {}
        self._add_scene_nodes()
        self._add_gui()
        self.show(self.time_s)
        self._thread = threading.Thread(target=self._play_loop, daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        """The page's address (localhost for a server on every interface)."""
        host = self.server.get_host()
        host = "localhost" if host in ("0.0.0.0", "::", "") else host
        return f"http://{host}:{self.server.get_port()}"

    def _quiet(self):
        """A context that keeps viser's own start and stop lines off stdout unless verbose."""
        return contextlib.nullcontext() if self._verbose else contextlib.redirect_stdout(
            io.StringIO())

    def _add_scene_nodes(self) -> None:
        scene = self.server.scene
        height = max(s.height_m for s in self.scenes)
        row = 2.0 * float(np.max(np.abs([s.offset for s in self.scenes])))
        span = row + 4.0 * height
        cell = max(0.05, round(height / 5.0, 2))
        scene.add_grid("/floor", width=span, height=span, cell_size=cell, section_size=5 * cell)
        # No image-based lighting (its start-up costs a software-rendered browser seconds): the
        # default lights plus a sky/ground hemisphere.
        scene.configure_environment_map(None)
        scene.add_light_hemisphere("/sky", sky_color=(255, 255, 255), ground_color=(120, 120, 130),
                                   intensity=HEMISPHERE_INTENSITY)
        dist = 0.8 * row + 2.8 * height
        az, el = np.radians(CAMERA_AZIMUTH_DEG), np.radians(CAMERA_ELEVATION_DEG)
        self.server.initial_camera.fov = np.radians(CAMERA_FOV_DEG)
        self.server.initial_camera.look_at = (0.0, 0.0, 0.4 * height)
        self.server.initial_camera.position = (
            dist * np.cos(el) * np.cos(az), -dist * np.cos(el) * np.sin(az),
            0.4 * height + dist * np.sin(el))
        self.geoms, self.capture, self.arrows, self.targets, self.labels = [], [], [], [], []
        for k, s in enumerate(self.scenes):
            root = f"/push{k}"
            self.geoms.append([
                scene.add_mesh_simple(f"{root}/geom{sh.geom}", sh.vertices, sh.faces,
                                      color=rgb255(sh.rgba),
                                      opacity=None if sh.rgba[3] >= 1.0 else float(sh.rgba[3]),
                                      flat_shading=sh.kind in ("box", "mesh"))
                for sh in s.shapes])
            self.labels.append(scene.add_label(f"{root}/label", s.label,
                                               position=s.offset + (0.0, 0.0, 1.2 * s.height_m)))
            r = 0.03 * s.height_m
            self.capture.append(scene.add_icosphere(f"{root}/capture_point", radius=r,
                                                    color=CAPTURE_RGB))
            self.arrows.append(scene.add_arrows(f"{root}/push", s.arrow[None], ARROW_RGB,
                                                shaft_radius=0.5 * r, head_radius=1.2 * r,
                                                head_length=2.5 * r))
            self.targets.append(None if s.step_target is None else scene.add_cylinder(
                f"{root}/step_target", radius=1.6 * r, height=0.1 * r, color=TARGET_RGB,
                position=s.step_target))

    def _add_gui(self) -> None:
        gui = self.server.gui
        dt = float(self.t[1] - self.t[0]) if len(self.t) > 1 else 0.03
        self.slider = gui.add_slider("time (s)", min=float(self.t[0]), max=float(self.t[-1]),
                                     step=dt, initial_value=float(self.t[0]))
        self.play = gui.add_button("Play")
        self.speed = gui.add_slider("speed", min=0.1, max=2.0, step=0.1, initial_value=1.0)
        self.slider.on_update(lambda _: self.show(self.slider.value))
        self.play.on_click(lambda _: self.toggle())

    def toggle(self) -> None:
        """Play when paused, pause when playing (the button's label says which comes next)."""
        with self._play_lock:
            if self._playing.is_set():
                self._playing.clear()
                self.play.label = "Play"
            else:
                self._playing.set()
                self.play.label = "Pause"

    def show(self, time_s: float) -> None:
        """Pose every node as at time_s."""
        with self._lock, self.server.atomic():
            for k, s in enumerate(self.scenes):
                f = s.frame(time_s)
                if self._shown.get(k) == f["k"]:
                    continue
                self._shown[k] = f["k"]
                for handle, p, q in zip(self.geoms[k], f["positions"], f["wxyz"]):
                    handle.position, handle.wxyz = p, q
                self.capture[k].position = f["capture"]
                self.arrows[k].visible = f["arrow_visible"]
                if self.targets[k] is not None:
                    self.targets[k].visible = f["target_visible"]
            self.time_s = float(time_s)

    def _play_loop(self) -> None:
        last = time.monotonic()
        while not self._closed.wait(0.02):
            now = time.monotonic()
            with self._play_lock:
                if self._playing.is_set():
                    self._advance(self.slider.value + (now - last) * float(self.speed.value))
            last = now

    def _advance(self, time_s: float) -> None:
        """Move the slider to time_s, wrapping past the end (the slider's update shows it)."""
        lo, hi = float(self.t[0]), float(self.t[-1])
        if time_s > hi + 1e-9:
            time_s = lo
        self.slider.value = float(np.clip(time_s, lo, hi))

    def stop(self) -> None:
        self._closed.set()
        self._thread.join(timeout=2.0)
        with self._quiet():
            self.server.stop()
