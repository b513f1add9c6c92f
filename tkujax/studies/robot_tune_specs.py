"""The specs `tkujax tune --robot` runs (tkujax.studies.robot_tune): the CMA-ES search's tune
spec of a recovery structure on the robot's pushes (`tune_spec`, its ranges `ranges_for`), the
held-out sweep spec of the verdict (`heldout_spec`), and `check_stages`, which parses every spec
the stages can run before anything is simulated.

`robot_file` None is the built-in TKU-X: the specs then name no [robot] file, as a TKU-X spec
does.
"""

from __future__ import annotations

import math

from tkujax.dialects.push_limits import check_push_end
from tkujax.dialects.sweep_spec import parse_spec
from tkujax.sweeps.sweep import check_robot_sweep, check_tkux_pushes
from tkujax.studies.robot_pushes import (PROBE_DURATION_S, PROBE_HORIZON_S, PROBE_ONSET_S,
                                         widest_pushes)
from tkujax.studies.robot_structure import STRUCTURES, structure_start
from tkujax.studies.tune.reparam import check_start
from tkujax.studies.tune.tune_spec import parse_tune_spec

TUNE_SEED, HELDOUT_SEED = 0, 11
TUNE_BATCH, POPSIZE = 256, 13
HELDOUT_HORIZON_S = 2.0
# The search watches each push as long as the verdict does: with 1.5 s, stance gains that only
# delay a fall past the search's horizon looked better than the start there and harmed 8
# cells from behind in the Berkeley Humanoid's verdict at 2.0 s (falls 0 -> 7 % at 4-7 N s;
# results/robots/berkeley_humanoid/README.md).
TUNE_HORIZON_S = HELDOUT_HORIZON_S
TUNE_HARM_WEIGHT = 2.0               # OP3's loss: a harmed push costs twice a saved one
RETRY_HARM_WEIGHT = 8.0              # the retry's (module doc, step 5)
RETRY_BATCH = 2 * TUNE_BATCH
DEGREE_KEYS = ("eps_forward", "eps_backward")
# A first search starts at least this share of each range's width inside it: a default clamped
# onto its allowed range's edge (Unitree H1's lift height, 0.1 m) is a range's edge too, where
# the search's bounded reparametrisation cannot move (tests/test_robot_tune.py).
START_MARGIN = 0.05


def robot_table(robot_file: str | None) -> dict:
    """A spec's [robot] table naming `robot_file`; none for the built-in TKU-X (None)."""
    return {} if robot_file is None else {"robot": {"file": robot_file}}


def ranges_for(robot, start: dict, tuned: tuple[str, ...]) -> dict:
    """Search ranges of the tuned fields scaled to the robot, each holding the start strictly
    inside (the stance gains keep the tune's default ranges)."""
    d = robot.defaults
    reach = float(d.thigh_length + d.calf_length)
    # The sideways step's gain keeps its sign: widening (step) or toward the capture point
    # (shift_step); tests/test_robot_tune.py checks every start lies inside its ranges.
    lateral = [-2.0, 0.5] if start.get("cp_gain_lateral", -1.0) < 0 else [0.25, 2.0]
    ranges = dict(cp_gain=[0.3, 4.0], cp_gain_lateral=lateral, accel_gate=[0.01, 1.0],
                  cp_trigger_forward_m=[0.0, round(min(0.5, 0.6 * reach), 4)],
                  cp_trigger_backward_m=[0.0, round(min(0.5, 0.6 * reach), 4)],
                  cp_trigger_lateral_m=[0.0, round(min(0.5, 0.6 * reach), 4)])
    if "step_period" in start:
        t, lift = start["step_period"], start["lift_height"]
        ranges |= dict(step_period=[round(0.5 * t, 4), round(min(2.0, 2.0 * t), 4)],
                       lift_height=[round(0.2 * lift, 4), round(min(0.1, 2.5 * lift), 4)])
    if "step_shift_m" in start:
        ranges["step_shift_m"] = [0.0, round(min(0.25, max(0.02, 2.0 * start["step_shift_m"])), 4)]
    return {k: v for k, v in ranges.items() if k in tuned}


def _uniform(pair) -> dict:
    return {"uniform": [float(pair[0]), float(pair[1])]}


def tune_spec(robot_file: str | None, robot, pushes: dict, structure: str, iterations: int,
              retry_from: dict | None = None) -> dict:
    """The tune spec (as its TOML dict) of the robot's controller in `structure` (module doc);
    `retry_from` (a tuned controller's parameter dict): the retry's spec (step 5), which starts
    there, within the first search's ranges."""
    start = structure_start(robot, structure)
    tuned = STRUCTURES[structure]["tuned"]
    ranges = ranges_for(robot, start, tuned)
    if retry_from is None:
        start = {k: inside(v, ranges.get(k), START_MARGIN) for k, v in start.items()}
    else:
        start = {k: inside(retry_from[k], ranges.get(k)) for k in start}
    # The spec dialect gives the lean thresholds in degrees.
    controller = {(f"{k}_deg" if k in DEGREE_KEYS else k): (math.degrees(v) if k in DEGREE_KEYS
                                                            else v)
                  for k, v in start.items()}
    retry = retry_from is not None
    return robot_table(robot_file) | {
        "tune": {"name": f"{robot.name}_controller" + ("_retry" if retry else ""),
                 "seed": TUNE_SEED, "method": "cma", "popsize": POPSIZE,
                 "iterations": iterations, "batch": RETRY_BATCH if retry else TUNE_BATCH,
                 "duration_s": TUNE_HORIZON_S, "params": list(tuned), "float64": False,
                 "remat": True, "ranges": ranges,
                 "loss": dict(w_fall=1.0, w_recovery=1.0, w_step=0.1,
                              w_harm=RETRY_HARM_WEIGHT if retry else TUNE_HARM_WEIGHT)},
        "controller": controller,
        "push": {"impulse_ns": _uniform(pushes["impulse_ns"]), "azimuth_deg": _uniform((0, 360)),
                 "height_m": _uniform(pushes["height_m"]), "onset_s": _uniform((0.25, 0.4)),
                 "duration_s": _uniform(pushes["duration_s"])},
        "baseline": {"sigma": 0.5},
        # The tune's grid evaluation over the robot's impulses (its default grid is TKU-X's).
        "evaluate": {"impulse_ns": {"start": float(pushes["impulse_ns"][0]),
                                    "stop": float(pushes["impulse_ns"][1]), "num": 12}},
    }


def inside(value: float, bounds, margin_frac: float = 1e-6) -> float:
    """`value` nudged strictly inside `bounds`, at least `margin_frac` of their width from each
    edge (a tuned value can round onto its range's edge, and a start must lie strictly inside,
    tkujax.studies.tune.reparam); as it is without."""
    if bounds is None:
        return float(value)
    lo, hi = bounds
    margin = margin_frac * (hi - lo)
    return float(min(max(value, lo + margin), hi - margin))


def heldout_spec(robot_file: str | None, robot, pushes: dict, n: int) -> dict:
    """The held-out sweep spec (as its TOML dict): other seed, onsets and horizon."""
    sweep = {"name": f"{robot.name}_heldout", "seed": HELDOUT_SEED, "chunk_size": min(n, 8192),
             "duration_s": HELDOUT_HORIZON_S, "control": ["off", "on"]}
    random = {"n": n, "impulse_ns": _uniform(pushes["impulse_ns"]),
              "azimuth_deg": _uniform((0, 360)), "height_m": _uniform(pushes["height_m"]),
              "onset_s": _uniform((0.3, 0.6)), "duration_s": _uniform(pushes["duration_s"])}
    return robot_table(robot_file) | {"sweep": sweep, "push": {"random": random}}


def check_stages(robot_file: str | None, robot, heldout_n: int) -> None:
    """The stages' pushes checked before anything is simulated, by the checks of sweeps and
    tunes (`tkujax.dialects.push_limits`, `tkujax.studies.tune.limits`): the probe's pushes
    within its horizon, and the tune and held-out specs of every structure, built with the
    widest pushes the probe can give, parsed, each start strictly inside its ranges (SpecError
    names the stage's key)."""
    check_push_end("the probe's onset + pulse (tkujax.studies.robot_pushes.PROBE_ONSET_S + "
                   "PROBE_DURATION_S)", PROBE_ONSET_S + PROBE_DURATION_S,
                   "PROBE_HORIZON_S", PROBE_HORIZON_S)
    widest = widest_pushes(robot).as_dict()
    for structure in STRUCTURES:
        for retry_from in (None, structure_start(robot, structure)):
            check_start(parse_tune_spec(tune_spec(robot_file, robot, widest, structure,
                                                  iterations=10_000, retry_from=retry_from)))
    held = parse_spec(heldout_spec(robot_file, robot, widest, heldout_n))
    # The sweep's own check of its pushes on the robot (a height off TKU-X's trunk, or
    # outside a robot file's band), here before the search rather than after it.
    if robot.builtin:
        check_tkux_pushes(held)
    else:
        check_robot_sweep(held, robot)
