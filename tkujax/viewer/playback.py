"""What the replay viewer shows, as data: which records, and each one's frames (pure functions
apart from `replay_scene`, which re-simulates a record).

A `Selection` picks records from a sweep's columns (`select_records`). Each picked record is
re-simulated on MuJoCo C by `tkujax.sweeps.replay.replay` (the sweep's robot, push, controller
and model variation) and turned into a `PushScene`: the robot's geom meshes and their pose at
every control period, the push's arrow, the capture point per frame and, when the controller
stepped, the step's target, all shifted sideways by the robot's place in the row.

Capture point: the recorded one when the replay carries it (`capture_point_xy`, (T, 2)), else
the linear inverted pendulum's xi = c + c_dot / omega, omega = sqrt(g / c_z), from the whole-body
CoM c of MuJoCo's kinematics and its central-difference velocity.
Step target: the controller latches a step of (x_sup, y_sup) (the record's capture_point_m and
capture_point_y_m, both 0 when it never stepped); the swing foot (the left one unless y_sup < 0)
moves that far from where it stood at the push's onset, in the robot's heading.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from tkujax.sim.robot import as_robot
from tkujax.viewer.scene_meshes import (VISIBLE_GROUPS, GeomShape, com_positions, geom_poses,
                                        geom_shapes, site_positions)

ARROW_SHOW_S = 0.25         # the push's arrow stays this long after its onset
ARROW_FRACTION = 0.5        # the largest shown impulse's arrow is this fraction of the robot


@dataclasses.dataclass(frozen=True)
class Selection:
    """Which records to show: fell (True: fell, False: survived, None: both; diverged records
    only by index), an azimuth band (lo, hi) deg (wrapping past 360: (315, 45) is the back),
    an impulse band (lo, hi) N s, control (True / False / None: both), explicit push ids, and
    at most max_pushes of what matches."""

    fell: bool | None = None
    direction: tuple[float, float] | None = None
    impulse: tuple[float, float] | None = None
    control: bool | None = None
    indices: tuple[int, ...] = ()
    max_pushes: int = 4


def parse_band(text: str, name: str) -> tuple[float, float]:
    """'LO,HI' -> (lo, hi); ValueError naming the option otherwise."""
    parts = str(text).split(",")
    try:
        lo, hi = (float(p) for p in parts)
    except ValueError:
        raise ValueError(f"{name} must be LO,HI (two numbers), got {text!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"{name} must be two finite numbers, got {text!r}")
    return lo, hi


def in_azimuth_band(azimuth_deg, lo: float, hi: float) -> np.ndarray:
    """Whether each azimuth lies in [lo, hi] deg, angles modulo 360 (lo > hi wraps through 0;
    a band of 360 deg or more holds every azimuth)."""
    if hi - lo >= 360.0:
        return np.ones(np.shape(azimuth_deg), bool)
    a, lo, hi = np.mod(azimuth_deg, 360.0), lo % 360.0, hi % 360.0
    eps = 1e-9
    return ((a >= lo - eps) & (a <= hi + eps)) if lo <= hi else ((a >= lo - eps) | (a <= hi + eps))


def select_records(records: dict, sel: Selection) -> list[int]:
    """The push ids to show: the given indices (in their order) or every record, narrowed by
    the filters; when more than max_pushes match, an evenly spaced sample of them (the first
    and the last included)."""
    ids = np.asarray(records["push_id"])
    row = {int(p): i for i, p in enumerate(ids)}
    missing = [i for i in sel.indices if i not in row]
    if missing:
        raise ValueError(f"--index {missing[0]}: no such record (push ids 0-{ids.max()})")
    rows = np.array([row[i] for i in sel.indices] if sel.indices else np.argsort(ids), int)
    keep = np.ones(len(rows), bool)
    fell, diverged = np.asarray(records["fell"], bool), np.asarray(records["diverged"], bool)
    if sel.fell is not None:
        keep &= (fell[rows] == sel.fell) & ~diverged[rows]
    if sel.direction is not None:
        keep &= in_azimuth_band(np.asarray(records["azimuth_deg"])[rows], *sel.direction)
    if sel.impulse is not None:
        j = np.asarray(records["impulse_ns"])[rows]
        keep &= (j >= sel.impulse[0] - 1e-9) & (j <= sel.impulse[1] + 1e-9)
    if sel.control is not None:
        keep &= np.asarray(records["control"], bool)[rows] == sel.control
    rows = rows[keep]
    if len(rows) > sel.max_pushes:
        rows = rows[np.round(np.linspace(0, len(rows) - 1, sel.max_pushes)).astype(int)]
    return [int(ids[r]) for r in rows]


def capture_points(com: np.ndarray, t: np.ndarray, gravity: float,
                   recorded: np.ndarray | None = None) -> np.ndarray:
    """(T, 3) capture point on the floor per frame: `recorded` (T, 2) when given, else the
    LIP's c + c_dot / omega from the CoM track com (T, 3) sampled at times t (T,)."""
    if recorded is not None:
        xy = np.asarray(recorded, np.float64)
    else:
        vel = np.gradient(com, t, axis=0) if len(t) > 1 else np.zeros_like(com)
        omega = np.sqrt(gravity / np.maximum(com[:, 2], 1e-3))
        xy = com[:, :2] + vel[:, :2] / omega[:, None]
    return np.concatenate([xy, np.zeros((len(xy), 1))], 1)


def push_arrow(azimuth_deg: float, target: np.ndarray, length_m: float) -> np.ndarray:
    """(2, 3) start and tip of the push's arrow: along the force (azimuth 0 = toward +x, 90 =
    toward +y), its tip at the contact point `target`, `length_m` long."""
    a = np.radians(azimuth_deg)
    d = np.array([np.cos(a), np.sin(a), 0.0])
    target = np.asarray(target, np.float64)
    return np.stack([target - max(length_m, 1e-3) * d, target])


def yaw_of(wxyz: np.ndarray) -> float:
    """Heading (rad) of a quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(wxyz, np.float64)
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def step_target(x_sup: float, y_sup: float, ankles: np.ndarray, yaw: float) -> np.ndarray | None:
    """Where the step lands (3,) on the floor: the swing ankle (ankles (2, 3): right, left, at
    the onset) moved by (x_sup, y_sup) in the heading yaw; None when no step was latched."""
    if x_sup == 0.0 and y_sup == 0.0:
        return None
    c, s = np.cos(yaw), np.sin(yaw)
    swing = np.asarray(ankles, np.float64)[0 if y_sup < 0.0 else 1]
    return np.array([swing[0] + c * x_sup - s * y_sup, swing[1] + s * x_sup + c * y_sup, 0.0])


def outcome_word(fell: bool, diverged: bool) -> str:
    return "diverged" if diverged else "fell" if fell else "survived"


def push_label(index: int, stored: dict, replayed: dict | None = None) -> str:
    """'#3 1.20 N·s @ 90°' over 'control on: fell' (and the replay's outcome when it differs)."""
    word = outcome_word(bool(stored["fell"]), bool(stored["diverged"]))
    text = (f"#{index} {float(stored['impulse_ns']):.2f} N·s @ "
            f"{float(stored['azimuth_deg']) % 360:.0f}°\ncontrol "
            f"{'on' if stored.get('control', True) else 'off'}: {word}")
    if replayed is not None and {"fell", "diverged"} <= set(replayed):
        again = outcome_word(bool(replayed["fell"]), bool(replayed["diverged"]))
        if again != word:
            text += f" (replayed: {again})"
    return text


def frame_index(t: np.ndarray, time_s: float) -> int:
    """The last frame at or before time_s (the first one before it starts)."""
    return int(np.clip(np.searchsorted(t, time_s + 1e-9, side="right") - 1, 0, len(t) - 1))


def row_offsets(n: int, spacing_m: float) -> np.ndarray:
    """(n, 3) sideways (y) offsets of n robots in a row, centred on y = 0, first at +y."""
    return np.array([[0.0, ((n - 1) / 2.0 - k) * spacing_m, 0.0] for k in range(n)])


@dataclasses.dataclass(frozen=True)
class PushScene:
    """One re-simulated record, ready to draw: frames at times t (T,) s (the end of each control
    period); each shape's world position (T, G, 3) and quaternion (T, G, 4); the capture point
    (T, 3); the push's arrow (2, 3), shown from its onset for ARROW_SHOW_S; the step's target
    (3,) or None, shown from the onset; the robot's standing height (m) and its row offset."""

    index: int
    label: str
    t: np.ndarray
    shapes: tuple[GeomShape, ...]
    positions: np.ndarray
    wxyz: np.ndarray
    capture: np.ndarray
    arrow: np.ndarray
    impulse_ns: float
    onset_s: float
    step_target: np.ndarray | None
    height_m: float
    offset: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(3))

    def frame(self, time_s: float) -> dict:
        """What to draw at time_s: positions, wxyz, capture (3,), arrow_visible, target_visible."""
        k = frame_index(self.t, time_s)
        shown = self.t[k] >= self.onset_s - 1e-9
        return dict(k=k, positions=self.positions[k], wxyz=self.wxyz[k],
                    capture=self.capture[k],
                    arrow_visible=bool(shown and self.t[k] <= self.onset_s + ARROW_SHOW_S),
                    target_visible=bool(shown and self.step_target is not None))

    def with_arrow_scale(self, m_per_ns: float) -> PushScene:
        """The same scene with the arrow m_per_ns long per N s of impulse (tip kept)."""
        tip, start = self.arrow[1], self.arrow[0]
        d = (tip - start) / max(float(np.linalg.norm(tip - start)), 1e-12)
        length = max(m_per_ns * self.impulse_ns, 1e-3)
        return dataclasses.replace(self, arrow=np.stack([tip - length * d, tip]))

    def shifted(self, offset) -> PushScene:
        """The same scene moved by offset (3,) (from where it is now)."""
        d = np.asarray(offset, np.float64)
        return dataclasses.replace(
            self, positions=self.positions + d, capture=self.capture + d, arrow=self.arrow + d,
            step_target=None if self.step_target is None else self.step_target + d,
            offset=self.offset + d)


def standing_height(shapes, positions: np.ndarray, wxyz: np.ndarray) -> float:
    """Top of the robot's geoms (m) in one frame (positions (G, 3), wxyz (G, 4))."""
    import mujoco

    top = 0.0
    for s, p, q in zip(shapes, positions, wxyz):
        mat = np.empty(9)
        mujoco.mju_quat2Mat(mat, np.asarray(q, np.float64))
        top = max(top, float(np.max(p[2] + s.vertices @ mat.reshape(3, 3)[2])))
    return top


def scene_from_replay(result: dict, model, ankle_sites, groups=VISIBLE_GROUPS) -> PushScene:
    """The PushScene of one `tkujax.sweeps.replay.replay` result on the MuJoCo model it ran
    (ankle_sites: the right and left ankle site ids; groups: the geom groups drawn); its arrow
    is ARROW_FRACTION of the robot's height long (`PushScene.with_arrow_scale` sets a scale
    shared by several pushes)."""
    qpos, stored = np.asarray(result["qpos"], np.float64), result["stored"]
    t = (np.arange(len(qpos)) + 1.0) * float(result["control_period_s"])
    shapes = tuple(geom_shapes(model, groups))
    if not shapes:
        raise ValueError(f"the robot has no geom to draw in geom groups {list(groups)}")
    positions, wxyz = geom_poses(model, qpos, [s.geom for s in shapes])
    com = com_positions(model, qpos)
    gravity = float(np.linalg.norm(model.opt.gravity))
    capture = capture_points(com, t, gravity, result.get("capture_point_xy"))
    onset = float(stored["onset_s"])
    k = frame_index(t, onset)
    height = standing_height(shapes, positions[0], wxyz[0])
    impulse = float(stored["impulse_ns"])
    contact = np.array([com[k, 0], com[k, 1], float(stored.get("height_m", com[k, 2]))])
    target = None
    if bool(stored.get("control", True)):
        ankles = site_positions(model, qpos[k], ankle_sites)[0]
        target = step_target(float(stored.get("capture_point_m", 0.0)),
                             float(stored.get("capture_point_y_m", 0.0)), ankles,
                             yaw_of(qpos[k, 3:7]))
    return PushScene(index=int(result["index"]), label=push_label(result["index"], stored,
                                                                  result.get("replayed")),
                     t=t, shapes=shapes, positions=positions, wxyz=wxyz, capture=capture,
                     arrow=push_arrow(float(stored["azimuth_deg"]), contact,
                                      ARROW_FRACTION * height),
                     impulse_ns=impulse, onset_s=onset, step_target=target, height_m=height)


def host_model_of(model_params):
    """The MuJoCo model a replay ran on: a robot file's, or the TKU-X model of its parameters."""
    return as_robot(model_params).host_model


def replay_scenes(run_dir: str | Path, indices, robot=None, progress=None,
                  groups=VISIBLE_GROUPS) -> list[PushScene]:
    """Re-simulate each record (push id) of the sweep in run_dir on MuJoCo C and lay the
    scenes out in a row, sideways, 1.5 robot heights apart; the arrows share one scale (the
    largest impulse's is ARROW_FRACTION of the robot's height). progress(i, n, index) is
    called before each replay; groups: the geom groups drawn."""
    from tkujax.sweeps.replay import replay

    results = []
    for i, index in enumerate(indices):
        if progress is not None:
            progress(i, len(indices), index)
        results.append(replay(run_dir, int(index), robot=robot, backend="mujoco"))
    if not results:
        return []
    scenes = [scene_from_replay(r, host_model_of(r["model_params"]),
                                as_robot(r["model_params"]).index.ankle_sites, groups)
              for r in results]
    height = max(s.height_m for s in scenes)
    per_ns = ARROW_FRACTION * height / (max(s.impulse_ns for s in scenes) or 1.0)
    return [s.with_arrow_scale(per_ns).shifted(o)
            for s, o in zip(scenes, row_offsets(len(scenes), 1.5 * height))]
