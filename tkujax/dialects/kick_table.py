"""[push] kind = "velocity_kick": the pushes of MuJoCo Playground's locomotion tasks.

Playground kicks its robots rather than pushing them: at a control step, the floating base's
horizontal velocity (the free joint's qvel[0:2], world frame) jumps by a magnitude drawn
uniformly (e.g. 0.1-1.0 m/s for Booster T1) toward a direction drawn uniformly in [0, 2 pi),
again at a random interval (5-10 s). Here:

    [push]
    kind = "velocity_kick"          # default "impulse": the half-sine force pulse
    [push.grid]                     # or [push.random]
    kick_mps = [0.2, 0.5, 1.0]      # the velocity change, m/s, in [0, 5]: instead of impulse_ns
    azimuth_deg = [0, 90, 180, 270]
    onset_s = [1.5]
    [push.sequence]                 # Playground's repeated kicks
    pulses = 3
    interval_s = {uniform = [5.0, 10.0]}
    kick_mps = {uniform = [0.1, 1.0]}
    azimuth_deg = {uniform = [0, 360]}

A kick acts at the first controller tick at or after its onset (ticks every 30 ms, as
Playground's kicks act between control steps): the records' onsets are those ticks. The
records carry kick_mps (and pulse<i>_kick_mps) in place of impulse_ns; height_m and duration_s
do not apply (a kick's duration_s column is the control period, the most its onset moves).
Playground draws one interval per episode and repeats it; a sequence here draws each interval.
"""

from __future__ import annotations

import numpy as np

from tkujax.sim.push import CONTROL_PERIOD_S
from tkujax.dialects.validation import SpecError, choice, uniform, values

PUSH_KINDS = ("impulse", "velocity_kick")
KICK_KEY = "kick_mps"
KICK_RANGE = (0.0, 5.0, "m/s")
NOT_FOR_KICKS = ("impulse_ns", "height_m", "duration_s")


def push_kind(push: dict) -> str:
    """[push] kind: "impulse" (default) or "velocity_kick"."""
    return choice("push.kind", push.get("kind", PUSH_KINDS[0]), PUSH_KINDS)


def _kick_table(part: str, raw: dict, is_random: bool) -> dict:
    """A [push.PART] table of a kick sweep with kick_mps checked (its range) and put in the
    impulse_ns slot, the duration the control period; keys a kick has not are refused."""
    bad = sorted(set(raw) & set(NOT_FOR_KICKS))
    if bad:
        raise SpecError(f"push.{part}: {bad} do not apply to velocity kicks (push.kind = "
                        f"\"velocity_kick\"); give {KICK_KEY} ({KICK_RANGE[0]}-{KICK_RANGE[1]} "
                        "m/s)")
    out = {k: v for k, v in raw.items() if k != KICK_KEY}
    if KICK_KEY in raw:
        key = f"push.{part}.{KICK_KEY}"
        if isinstance(raw[KICK_KEY], dict) and "uniform" in raw[KICK_KEY]:
            uniform(key, raw[KICK_KEY], *KICK_RANGE)
        else:
            values(key, raw[KICK_KEY], *KICK_RANGE)
        out["impulse_ns"] = raw[KICK_KEY]
    if part == "sequence":
        return out
    if is_random:
        out["duration_s"] = {"uniform": [CONTROL_PERIOD_S, CONTROL_PERIOD_S]}
    else:
        out["duration_s"] = [CONTROL_PERIOD_S]
    return out


def kick_push_table(push: dict) -> dict:
    """The [push] table with a kick sweep's tables in the impulse spec's terms (`_kick_table`);
    an impulse sweep's unchanged (a kick_mps key in it refused)."""
    kind = push_kind(push)
    out = {k: v for k, v in push.items() if k != "kind"}
    if kind == "impulse":
        for part in ("grid", "random", "sequence"):
            if isinstance(out.get(part), dict) and KICK_KEY in out[part]:
                raise SpecError(f"push.{part}.{KICK_KEY}: a velocity kick needs push.kind = "
                                "\"velocity_kick\"")
        return out
    if "grid" in out and isinstance(out["grid"], dict):
        out["grid"] = _kick_table("grid", out["grid"], False)
    if "random" in out and isinstance(out["random"], dict):
        out["random"] = _kick_table("random", out["random"], True)
    if "sequence" in out and isinstance(out["sequence"], dict):
        out["sequence"] = _kick_table("sequence", out["sequence"], True)
    return out


def on_ticks(onset_s: np.ndarray, period_s: float = CONTROL_PERIOD_S) -> np.ndarray:
    """The first controller tick at or after each onset (s), to the microsecond."""
    return np.round(period_s * np.ceil(np.asarray(onset_s, float) / period_s - 1e-6), 6)


def kick_columns(recs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A kick sweep's records: the impulse_ns slots renamed kick_mps."""
    return {k.replace("impulse_ns", KICK_KEY): v for k, v in recs.items()}
