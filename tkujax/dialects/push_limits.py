"""The limits of a sweep spec, checked once it is parsed (`check_limits`): no push that the
horizon cannot hold (an onset after it, or a pulse it cuts short), and no more records than
MAX_RECORDS (counted before any is made: `record_count`).
"""

from __future__ import annotations

import math

import numpy as np

from tkujax.sim.push import CONTROL_PERIOD_S, onset_from_phase
from tkujax.dialects.step_table import step_count
from tkujax.dialects.validation import SpecError
from tkujax.dialects.walk_table import GAIT_PHASE_KEY, onsets_at_phase

# name: (lo, hi, default, unit). Push fields in user units.
PUSH_FIELDS = {
    # Any humanoid's: 0.5-1.8 m, 3-50 kg (a sweep checks the heights against its robot:
    # tkujax.sweeps.sweep.check_robot_sweep, check_tkux_pushes).
    "impulse_ns": (0.0, 200.0, 0.5, "N·s"),
    "azimuth_deg": (-360.0, 360.0, 0.0, "deg"),
    "height_m": (0.05, 2.0, 0.36, "m"),
    "onset_s": (0.05, 20.0, 0.75, "s"),
    "duration_s": (0.002, 0.5, 0.02, "s"),
}
# The push's phase in the control period (see the module doc): its own key, not in PUSH_FIELDS
# (the tune specs share PUSH_FIELDS and have no phase).
PHASE_KEY = "onset_phase"
PHASE_UNIT = "(fraction of the 30 ms control period; 1 excluded)"
# Limits of a sweep: records (a larger sweep is several sweeps: its input columns, expanded
# before the first chunk, take about 0.25 GB per million records at peak, 2 s per 8 million;
# tests/test_hostile_spec.py), pushes per chunk, the seed (JAX's PRNGKey keeps 32 bits: a
# larger seed would give another sweep's noise).
MAX_RECORDS = 1 << 23
MAX_CHUNK_SIZE = 1 << 20
MAX_SEED = (1 << 32) - 1
# Slack of the horizon check: float sums of onsets and durations given to the microsecond.
HORIZON_SLACK_S = 1e-9


def record_count(spec) -> int:
    """The records `spec` (a SweepSpec) expands to, counted without making them."""
    n_grid = math.prod(len(v) for v in spec.push_grid.values()) if spec.push_grid else 0
    settings = len(spec.control) * math.prod(
        len(v) for v in (spec.controller_grid | spec.fpga_grid).values())
    walks = len(spec.walk.recovery) if getattr(spec, "walk", None) is not None else 1
    return ((n_grid + spec.n_random) * settings * walks
            * step_count(spec.step_grid, spec.step_reference))


def _latest_end(part: str, onset, phase, duration, walk=None,
                gait_phase=None) -> tuple[float, str]:
    """(the latest end of a push of [push.PART], which of its keys set it); with a gait phase
    (and the WalkSpec `walk`), the onset is its time in the walk."""
    onset, duration = float(np.max(onset)), float(np.max(duration))
    start = onset if phase is None else float(onset_from_phase(onset, float(np.max(phase))))
    via = f"push.{part}.onset_s" + ("" if phase is None else f" + push.{part}.{PHASE_KEY}")
    if gait_phase is not None:
        start = float(np.max(onsets_at_phase(walk, np.max(gait_phase))))
        via = f"push.{part}.{GAIT_PHASE_KEY} (in walk.push_cycle = {walk.push_cycle})"
    return start + duration, f"{via} + push.{part}.duration_s (latest onset {start:.6g} s, " \
        f"longest pulse {duration:.6g} s)"


def check_push_window(spec) -> None:
    """SpecError when a push of `spec` starts after its horizon (sweep.duration_s) or ends
    after it (the horizon would cut the pulse short): the outcome would be no push's."""
    parts = []
    if spec.push_grid:
        g = spec.push_grid
        default = {k: [v[2]] for k, v in PUSH_FIELDS.items()}
        parts.append(_latest_end("grid", g.get("onset_s", default["onset_s"]), g.get(PHASE_KEY),
                                 g.get("duration_s", default["duration_s"]), spec.walk,
                                 g.get(GAIT_PHASE_KEY)))
    if spec.n_random:
        r = spec.push_random
        parts.append(_latest_end("random", r.get("onset_s", (PUSH_FIELDS["onset_s"][2],)),
                                 r.get(PHASE_KEY),
                                 r.get("duration_s", (PUSH_FIELDS["duration_s"][2],)),
                                 spec.walk, r.get(GAIT_PHASE_KEY)))
    seq = getattr(spec, "sequence", None)
    if seq is not None and seq.pulses > 1:     # the last pulse of a sequence
        parts = [(end + seq.span_s, f"{via} + (push.sequence.pulses - 1) x "
                  f"push.sequence.interval_s (at most {seq.span_s:.6g} s)") for end, via in parts]
    for end, via in parts:
        check_push_end(via, end, "sweep.duration_s", spec.duration_s)


def check_push_end(via: str, end_s: float, horizon_key: str, horizon_s: float) -> None:
    """SpecError when a push ending at `end_s` (`via`: the keys that set it) ends after the
    horizon `horizon_key` = `horizon_s`: the outcome would be no push's. Sweeps, tunes and the
    robot tune's stages share it."""
    if end_s > horizon_s + HORIZON_SLACK_S:
        raise SpecError(f"{via}: a push would end at {end_s:.6g} s, after the horizon "
                        f"{horizon_key} = {horizon_s:g} s (the pulse would be cut short or "
                        f"never start); allowed: onset + push duration <= {horizon_s:g} s "
                        f"(onsets on the {CONTROL_PERIOD_S * 1e3:g} ms grid)")


def check_record_cap(key: str, n: int, what: str) -> None:
    """SpecError when `n` records (`what`, set by `key`) exceed MAX_RECORDS, counted before
    any is made."""
    if n > MAX_RECORDS:
        raise SpecError(f"{key}: {what} would be {n:,} records, above the limit of "
                        f"{MAX_RECORDS:,} (tkujax.dialects.push_limits.MAX_RECORDS); make it "
                        "smaller")


def check_limits(spec):
    """`spec` (a SweepSpec) after checking its record count and its pushes' window."""
    n = record_count(spec)
    if n > MAX_RECORDS:
        raise SpecError(f"[push]: the spec expands to {n:,} records (pushes x settings x steps), "
                        f"above the limit of {MAX_RECORDS:,} per sweep "
                        "(tkujax.dialects.sweep_spec.MAX_RECORDS); split it into several sweeps")
    check_push_window(spec)
    return spec
