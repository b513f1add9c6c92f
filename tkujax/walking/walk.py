"""`tkujax walk`: the robot walks from its controller's CPG (`tkujax.control.gait`); what was
measured.

`run_walk` simulates a batch of walks (one `WalkCommand` each) on MuJoCo C or MJX; `walk_metrics`
reads one walk's Series (recorded with the qpos) into the measurements `tkujax walk` prints:

  fell, fall_s        a fall (`tkujax.sim.metrics.fall_indicator`) and when;
  distance_m          the CoM's horizontal displacement from the first step to the end (or the
                      fall), and forward_m / lateral_m, the same in the start heading's frame;
  mean_speed_mps      |displacement| / time over the steady walk (after the ramp), and
                      mean_forward_mps / mean_lateral_mps in the start heading's frame;
  heading_drift_deg   the base's yaw at the end (or the fall) minus at the first step;
  step_period_s       the mean time between successive touchdowns (either foot) in the steady
                      walk; step_length_m / step_lateral_m: half of each foot's stride (its
                      footprint from one touchdown to its next), forward and sideways in the
                      heading at that time, averaged.

A touchdown is a sample where an ankle comes back below its stand height + TOUCHDOWN_FRAC of
the lift, after being above it (the series is sampled once per control period, 30 ms).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from tkujax.control.gait import WalkCommand
from tkujax.control.controller_params import ControllerParams
from tkujax.robot import Robot, builtin_robot, robot_from_file
from tkujax.sim.metrics import fall_indicator
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import Push, make_push, stack_pushes

ENGINES = ("mujoco", "mjx")
TOUCHDOWN_FRAC = 0.25
MIN_TOUCHDOWN_M = 0.002


@dataclasses.dataclass(frozen=True)
class Walker:
    """A robot ready to walk: its Robot (TKU-X's default model or a robot file's), the
    controller it runs and the gait's defaults (`WalkCommand.for_params`)."""

    robot: Robot
    params: ControllerParams
    gait_params: ControllerParams
    name: str

    @property
    def gait(self) -> dict:
        """The robot file's [walk] table: WalkCommand fields over `gait_params`' defaults."""
        return dict(self.robot.gait)


def walker(robot_file: str | None = None) -> Walker:
    """TKU-X (None) or a robot file's robot: the controller the file names for walking
    (`Robot.walking_params`; its scaled defaults otherwise), the gait from the scaled defaults
    (`Robot.defaults`)."""
    robot = builtin_robot() if robot_file is None else robot_from_file(robot_file)
    return Walker(robot=robot, params=robot.walking_params,
                  gait_params=robot.defaults or robot.params,
                  name="tkux" if robot.builtin else robot.name)


def stack_commands(commands: list[WalkCommand]) -> WalkCommand:
    """Commands stacked along a leading axis (float32), for one batch."""
    return WalkCommand(**{f.name: np.array([float(getattr(c, f.name)) for c in commands],
                                           np.float32)
                          for f in dataclasses.fields(WalkCommand)})


def run_walk(who: Walker, commands: list[WalkCommand], seconds: float, engine: str = "mujoco",
             enabled: float = 1.0, pushes: Push | None = None):
    """Simulate one walk per command (a batch) for `seconds`: (series, outcomes) as numpy, the
    qpos recorded. pushes: stacked Push (default: none)."""
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    for c in commands:
        c.validate()
    n = len(commands)
    if pushes is None:
        pushes = stack_pushes([make_push(0.0)] * n)
    config = RolloutConfig(duration_s=float(seconds), record_qpos=True)
    enabled = np.full(n, float(enabled), np.float32)
    walk = stack_commands(commands)
    if engine == "mujoco":
        from tkujax.sim.rollout_mujoco import simulate_mujoco

        return simulate_mujoco(pushes, enabled, who.params, config=config, robot=who.robot,
                               walk=walk)
    from tkujax.sim.rollout_mjx import simulate

    return simulate(pushes, enabled, who.params, config=config, robot=who.robot, walk=walk)


def base_yaw(qpos: np.ndarray) -> np.ndarray:
    """(n,) the floating base's yaw (rad, unwrapped) from qpos (n, nq): the heading of its x axis
    projected on the floor."""
    w, x, y, z = (qpos[:, 3 + i] for i in range(4))
    heading_x = 1.0 - 2.0 * (y * y + z * z)
    heading_y = 2.0 * (x * y + w * z)
    return np.unwrap(np.arctan2(heading_y, heading_x))


def touchdowns(ankle_z: np.ndarray, lift_m: float) -> np.ndarray:
    """Indices of the samples at which a foot is back down after being lifted (see the module
    docstring for the threshold)."""
    threshold = ankle_z[0] + max(MIN_TOUCHDOWN_M, TOUCHDOWN_FRAC * lift_m)
    up = ankle_z > threshold
    return np.flatnonzero(up[:-1] & ~up[1:]) + 1


def _rotate(v: np.ndarray, yaw) -> np.ndarray:
    """World (x, y) vectors into the frame of heading `yaw` (rad): (forward, left)."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1]], -1)


def _steps(series, i: int, lift_m: float, yaw: np.ndarray, after: int, end: int) -> dict:
    """Step period, length and lateral step from the touchdowns in [after, end)."""
    events = []
    for foot in ("r_ankle", "l_ankle"):
        pos = getattr(series, foot)[i]
        for k in touchdowns(pos[:, 2], lift_m):
            if after <= k < end:
                events.append((k, foot, pos[min(k + 1, end - 1), :2]))
    events.sort(key=lambda e: e[0])
    t = series.t[i]
    out = dict(step_period_s=math.nan, step_length_m=math.nan, step_lateral_m=math.nan,
               steps=len(events))
    if len(events) >= 2:
        out["step_period_s"] = float((t[events[-1][0]] - t[events[0][0]]) / (len(events) - 1))
    strides = [_rotate(b[2] - a[2], yaw[b[0]]) / 2.0
               for a, b in zip(events, events[2:]) if a[1] == b[1]]
    if strides:
        mean = np.mean(strides, 0)
        out["step_length_m"], out["step_lateral_m"] = float(mean[0]), float(mean[1])
    return out


def walk_metrics(series, i: int, command: WalkCommand) -> dict:
    """The measurements of walk i of a batch's Series (module docstring)."""
    t = np.asarray(series.t[i])
    dt = float(t[1] - t[0])
    fell_at = np.asarray(fall_indicator(_one(series, i)))
    fell = bool(fell_at.any())
    end = int(np.argmax(fell_at)) if fell else len(t)
    start = min(int(round(float(command.start_s) / dt)), end - 1)
    steady = min(int(round((float(command.start_s) + (float(command.ramp_steps) + 1.0)
                            * float(command.step_period_s)) / dt)), end - 1)
    com = np.asarray(series.com[i])[:, :2]
    yaw = base_yaw(np.asarray(series.qpos[i]))
    last = end - 1
    disp = _rotate(com[last] - com[start], yaw[start])
    span = t[last] - t[steady]
    vel = (_rotate(com[last] - com[steady], yaw[start]) / span if span > 0
           else np.full(2, math.nan))
    out = dict(fell=fell, fall_s=float(t[end]) if fell else None,
               distance_m=float(np.hypot(*disp)), forward_m=float(disp[0]),
               lateral_m=float(disp[1]), mean_speed_mps=float(np.hypot(*vel)),
               mean_forward_mps=float(vel[0]), mean_lateral_mps=float(vel[1]),
               heading_drift_deg=float(np.degrees(yaw[last] - yaw[start])))
    out.update(_steps(series, i, float(command.lift_m), yaw, steady, end))
    return out


def _one(series, i: int):
    """Walk i of a batch's Series (the fields fall_indicator reads)."""
    return {"pelvis_z": np.asarray(series.pelvis_z[i]),
            "lowest_body_z": np.asarray(series.lowest_body_z[i])}


def simulate_walk(robot_file: str | None = None, speed_mps: float = 0.0,
                  lateral_mps: float = 0.0, seconds: float = 20.0, engine: str = "mujoco",
                  step_period_s: float | None = None, enabled: bool = True,
                  lift_m: float | None = None, sway_m: float | None = None) -> dict:
    """`tkujax walk`: one walk of TKU-X (None) or a robot file's robot at the commanded speeds;
    the commanded gait and `walk_metrics`, with the wall time. step_period_s, lift_m, sway_m:
    None takes the robot file's [walk] table, else the robot's scaled defaults."""
    return walk_once(robot_file, speed_mps, lateral_mps, seconds, engine, step_period_s,
                     enabled, lift_m, sway_m)[0]


def walk_once(robot_file: str | None = None, speed_mps: float = 0.0, lateral_mps: float = 0.0,
              seconds: float = 20.0, engine: str = "mujoco", step_period_s: float | None = None,
              enabled: bool = True, lift_m: float | None = None, sway_m: float | None = None
              ) -> tuple[dict, object, Walker, WalkCommand]:
    """`simulate_walk`, also returning what drawing the walk needs: (result, the Series with
    the qpos, the Walker, the command)."""
    if not 0.0 < seconds <= 600.0:
        raise ValueError(f"seconds must be in (0, 600], got {seconds!r}")
    who = walker(robot_file)
    given = dict(step_period_s=step_period_s, lift_m=lift_m, sway_m=sway_m)
    fields = who.gait | {k: float(v) for k, v in given.items() if v is not None}
    command = WalkCommand.for_params(who.gait_params, speed_mps, lateral_mps, **fields).validate()
    t0 = time.perf_counter()
    series, _ = run_walk(who, [command], seconds, engine, float(enabled))
    wall = time.perf_counter() - t0
    step = np.array([command.speed_mps, command.lateral_mps]) * float(command.step_period_s)
    result = dict(robot=who.name, engine=engine, seconds=float(seconds),
                  command=dict(speed_mps=float(speed_mps), lateral_mps=float(lateral_mps),
                               step_period_s=float(command.step_period_s),
                               step_length_m=float(step[0]), step_lateral_m=float(step[1]),
                               lift_m=float(command.lift_m), sway_m=float(command.sway_m),
                               com_shift_m=float(command.com_shift_m),
                               ramp_steps=float(command.ramp_steps),
                               balance_control=bool(enabled)))
    result.update(walk_metrics(series, 0, command))
    result["wall_s"] = round(wall, 2)
    return result, series, who, command
