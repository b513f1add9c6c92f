"""Which recovery structure a robot's controller is tuned in, chosen on the robot itself.

Three structures (`STRUCTURES`), each a start on the robot's scaled defaults:

- "step": the structure the OP3 evidence chose (docs/robots.md): the accelerometer gate, the
  capture-point triggers at 15 % of the leg's reach, one step, the widening sideways step,
  stance feedback. Its step is the paper's CPG step, which shifts no weight onto the support
  foot before lifting the other: a light robot with a short step period gets its foot down
  before it tips sideways; a heavy, wide-hipped one may not (Booster T1 pushed from the front
  lifts its left foot, rolls over it and falls: 54 % of 3.8-12 N s front pushes that standing
  still survives).
- "shift_step": the same step with the waist shifted toward the support foot before the
  other lifts (`step_shift_m`, starting at the hip's half-width d_y, over a double support
  of 0.3 T): on T1 a commanded step then stands where without it every one fell
  (tests/test_weight_shift.py).
- "stance": no step, stance feedback (ankle and hip on pitch, ankle on roll) and the
  accelerometer gate, as the conservative default.

`choose_structure` runs every start and control off on `PROBE_N` pushes of the robot's tuning
distribution (MuJoCo C, another seed than the tune's) and keeps the one with the lower
harm-weighted loss: falls + HARM_WEIGHT x pushes that fall only with the controller (the
tune's own weight). The choice and its counts go into the record.
"""

from __future__ import annotations

import numpy as np

from tkujax.control.params_files import controller_params_from
from tkujax.robot.own_controller import NO_STEP_THRESHOLD_RAD, STANCE_GAINS, conservative_stance
from tkujax.sim.options import RolloutConfig
from tkujax.sim.push import make_push, stack_pushes
from tkujax.sim.rollout_mujoco import simulate_mujoco

PROBE_N, PROBE_SEED, PROBE_HORIZON_S = 192, 5, 1.5
HARM_WEIGHT = 2.0
SHIFT_MAX_M = 0.2           # the shift step's start: d_y, at most this (ControllerParams: 0.25)
STEP_FIELDS = ("step_period", "double_support_ratio", "lift_height", "cp_gain",
               "cp_trigger_forward_m", "cp_trigger_backward_m", "cp_trigger_lateral_m",
               "cp_gain_lateral")
STEP_FIXED = dict(cp_trigger=1.0, max_steps=1.0, lateral_steps=1.0, cp_rate_blend=1.0,
                  cp_gain_lateral=-1.0, double_support_ratio=0.05, cp_gain=1.5)
STRUCTURES = {
    "step": dict(fixed=STEP_FIXED, tuned=STEP_FIELDS + ("accel_gate",) + STANCE_GAINS),
    # The step toward the capture point (its support foot is away from the fall, where the
    # shift moves the waist), with a double support long enough to shift in.
    "shift_step": dict(fixed=STEP_FIXED | dict(cp_gain_lateral=1.0, double_support_ratio=0.3),
                       tuned=STEP_FIELDS + ("step_shift_m", "accel_gate") + STANCE_GAINS),
    "stance": dict(fixed=dict(cp_trigger=0.0, max_steps=1.0, lateral_steps=0.0,
                              eps_forward=NO_STEP_THRESHOLD_RAD,
                              eps_backward=NO_STEP_THRESHOLD_RAD),
                   tuned=("accel_gate",) + STANCE_GAINS),
}


def structure_start(robot, name: str) -> dict:
    """The start of structure `name` on `robot` (module doc), as controller field values."""
    d = robot.defaults
    reach = float(d.thigh_length + d.calf_length)
    start = dict(STRUCTURES[name]["fixed"]) | conservative_stance()
    if name in ("step", "shift_step"):
        start |= dict(step_period=float(d.step_period), lift_height=float(d.lift_height))
        start |= {k: round(0.15 * reach, 4) for k in ("cp_trigger_forward_m",
                                                       "cp_trigger_backward_m",
                                                       "cp_trigger_lateral_m")}
    if name == "shift_step":
        start["step_shift_m"] = round(min(SHIFT_MAX_M, float(d.hip_offset_y)), 4)
    return start


def _probe_pushes(pushes: dict):
    rng = np.random.default_rng(PROBE_SEED)

    def draw(key):
        lo, hi = pushes[key]
        return rng.uniform(lo, hi, PROBE_N)

    impulse, height, duration = draw("impulse_ns"), draw("height_m"), draw("duration_s")
    azimuth, onset = rng.uniform(0, 360, PROBE_N), rng.uniform(0.25, 0.4, PROBE_N)
    return stack_pushes([make_push(float(j), azimuth_deg=float(a), height_m=float(h),
                                   duration_s=float(d), onset_s=float(o))
                         for j, a, h, d, o in zip(impulse, azimuth, height, duration, onset)])


def choose_structure(robot, pushes: dict) -> dict:
    """The record of the choice (module doc): each structure's falls, harmed and saved pushes,
    its loss, and `chosen`."""
    batch = _probe_pushes(pushes)
    config = RolloutConfig(duration_s=PROBE_HORIZON_S)
    _, off = simulate_mujoco(batch, np.zeros(PROBE_N), robot.defaults, robot=robot,
                             config=config)
    off_fell = np.asarray(off.fell, bool)
    record = dict(n_pushes=PROBE_N, control_off_falls=int(off_fell.sum()), structures={})
    for name in STRUCTURES:
        params = controller_params_from(robot.defaults, structure_start(robot, name))
        _, on = simulate_mujoco(batch, np.ones(PROBE_N), params, robot=robot, config=config)
        fell = np.asarray(on.fell, bool)
        harmed, saved = int((fell & ~off_fell).sum()), int((off_fell & ~fell).sum())
        record["structures"][name] = dict(falls=int(fell.sum()), harmed=harmed, saved=saved,
                                          loss=int(fell.sum()) + HARM_WEIGHT * harmed)
    record["chosen"] = min(record["structures"], key=lambda k: record["structures"][k]["loss"])
    record["why"] = (f"{record['chosen']}: the lower harm-weighted loss on {PROBE_N} pushes "
                     f"(falls + {HARM_WEIGHT:g} x harmed; "
                     + ", ".join(f"{k} {v['falls']} falls, {v['harmed']} harmed"
                                 for k, v in record["structures"].items())
                     + f"; control off {record['control_off_falls']} falls)")
    return record
