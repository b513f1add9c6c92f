"""[push.sequence] of a sweep spec: several pulses per rollout (multiple impacts).

    [push.sequence]
    pulses = 3                              # pulses per rollout, the record's push the first
    interval_s = {uniform = [0.6, 1.2]}     # onset to onset (a number, or drawn per pulse)
    impulse_ns = {uniform = [0.3, 0.8]}     # each later pulse's (default: the first's)
    azimuth_deg = {uniform = [0, 360]}      # each later pulse's (default: the first's)

The first pulse is the record's push (impulse_ns, azimuth_deg, onset_s, ... as without a
sequence); pulse i >= 2 has the columns pulse<i>_onset_s, pulse<i>_impulse_ns and
pulse<i>_azimuth_deg, drawn per push from the sweep's seed after every other column (which
therefore keep their values) and shared by the push's settings (control, controller grid,
walking recovery): comparisons stay paired. Every pulse has the first's height and duration;
an interval shorter than the duration (overlapping pulses) is refused, and so is a last pulse
that would end after the horizon (`sequence_span_s`). The outcomes count from the first onset.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from tkujax.dialects.validation import SpecError, integer, number, table, uniform

MAX_PULSES = 8
INTERVAL_RANGE_S = (0.002, 20.0)
# Per-pulse draws: (lo, hi, unit), the ranges of the first pulse's keys.
PULSE_KEYS = {"impulse_ns": (0.0, 200.0, "N·s"), "azimuth_deg": (-360.0, 360.0, "deg")}


@dataclasses.dataclass(frozen=True)
class SequenceSpec:
    """The validated [push.sequence]: pulses, and per later pulse (lo, hi) ranges (lo == hi:
    a fixed value; None: the first pulse's value) of interval_s, impulse_ns, azimuth_deg."""

    pulses: int
    interval_s: tuple[float, float]
    impulse_ns: tuple[float, float] | None = None
    azimuth_deg: tuple[float, float] | None = None

    @property
    def span_s(self) -> float:
        """The longest time from the first onset to the last pulse's onset."""
        return (self.pulses - 1) * self.interval_s[1]


def _range(key: str, value, lo: float, hi: float, unit: str) -> tuple[float, float]:
    if isinstance(value, dict):
        return uniform(key, value, lo, hi, unit)
    v = number(key, value, lo, hi, unit)
    return v, v


def parse_sequence(push: dict) -> SequenceSpec | None:
    """The [push.sequence] table of the [push] table (None without one)."""
    if "sequence" not in push:
        return None
    raw = table("push.sequence", push["sequence"], {"pulses", "interval_s"} | set(PULSE_KEYS))
    if "pulses" not in raw or "interval_s" not in raw:
        raise SpecError("[push.sequence]: give pulses (an integer in [1, 8]) and interval_s "
                        "(s, a number or {uniform = [lo, hi]})")
    pulses = integer("push.sequence.pulses", raw["pulses"], 1, MAX_PULSES)
    interval = _range("push.sequence.interval_s", raw["interval_s"], *INTERVAL_RANGE_S, "s")
    draws = {k: _range(f"push.sequence.{k}", raw[k], *PULSE_KEYS[k]) for k in PULSE_KEYS
             if k in raw}
    return SequenceSpec(pulses=pulses, interval_s=interval, **draws)


def check_sequence(seq: SequenceSpec | None, durations_s: np.ndarray) -> None:
    """Refuse pulses that overlap: an interval shorter than the longest pulse duration."""
    if seq is None:
        return
    longest = float(np.max(durations_s))
    if seq.interval_s[0] < longest:
        raise SpecError(f"push.sequence.interval_s: {seq.interval_s[0]:g} s is shorter than the "
                        f"pulse duration push.*.duration_s = {longest:g} s (pulses would "
                        f"overlap); allowed: interval_s in [{longest:g}, "
                        f"{INTERVAL_RANGE_S[1]:g}] s")


def pulse_columns(pulses: int) -> list[str]:
    """The record columns of pulses 2..pulses, in the order of the pulse fields."""
    return [f"pulse{i}_{k}" for i in range(2, pulses + 1)
            for k in ("onset_s", "impulse_ns", "azimuth_deg")]


def draw_sequence(seq: SequenceSpec | None, rng: np.random.Generator,
                  pushes: dict[str, np.ndarray], n_settings: int,
                  snap=None) -> dict[str, np.ndarray]:
    """The later pulses' columns of n pushes (their first pulses `pushes`: onset_s,
    impulse_ns, azimuth_deg (n,)), tiled over `n_settings` blocks (see the module doc).
    snap: a function moving each onset (velocity kicks: onto the controller's ticks)."""
    if seq is None:
        return {}
    n = len(pushes["onset_s"])
    onset = np.asarray(pushes["onset_s"], float)
    out = {}
    for i in range(2, seq.pulses + 1):
        onset = np.round(onset + rng.uniform(*seq.interval_s, n), 6)
        if snap is not None:
            onset = snap(onset)
        out[f"pulse{i}_onset_s"] = onset
        for k in ("impulse_ns", "azimuth_deg"):
            rng_k = getattr(seq, k)
            out[f"pulse{i}_{k}"] = (np.asarray(pushes[k], float) if rng_k is None
                                    else rng.uniform(*rng_k, n))
    return {k: np.tile(v, n_settings) for k, v in out.items()}


def pulse_count(rec: dict) -> int:
    """Pulses of the records `rec` (1: a single push): from their columns (static)."""
    return 1 + sum(1 for k in rec if k.startswith("pulse") and k.endswith("_azimuth_deg"))


def pulse_fields(rec: dict, xp=np) -> dict:
    """{impulse_ns or kick_mps (a velocity kick's records), azimuth_deg, onset_s}: the
    records' pulses stacked on a last axis (one pulse: the columns themselves). `xp`: numpy
    or jax.numpy (inside a program)."""
    k = pulse_count(rec)
    size = "kick_mps" if "kick_mps" in rec else "impulse_ns"
    fields = (size, "azimuth_deg", "onset_s")
    if k == 1:
        return {f: rec[f] for f in fields}
    return {f: xp.stack([rec[f]] + [rec[f"pulse{i}_{f}"] for i in range(2, k + 1)], -1)
            for f in fields}
