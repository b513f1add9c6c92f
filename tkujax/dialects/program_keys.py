"""The [sweep] keys that choose how a sweep's program runs its pushes: the passes over the body
tree, and the decisions (the full horizon, or early decisions with lane refill).

    [sweep]
    tree_passes = "compact"    # or "mjx" (SWEEP_TREE_PASSES)
    decisions = "early"        # or "full" (DECISIONS; default "full")
    lanes = 4096               # early: pushes in flight at once (the batch of lanes)
    segment_ticks = 4          # early: control ticks between refills

Early decisions (`tkujax.sweeps.early`, `tkujax.sim.lanes`): a lane whose push is decided
(fallen, or settled by the criterion stated in `tkujax.sim.lanes`) leaves the batch and the
next push takes the lane. "full" runs every push to duration_s, as sweeps always did.
"""

from __future__ import annotations

import dataclasses

from tkujax.dialects.validation import SpecError

# The sweeps' passes over the body tree (ProgramOptions.tree_passes): "compact" sums the tree
# in a fixed order, so a GPU gives the same records from run to run (results/scale/README.md:
# MJX's own passes sum subtrees with scatter-adds, which a GPU runs with atomics), with the
# same outcomes (tests/test_perf_equivalence.py, test_compact_sweep_chunk_keeps_the_outcomes).
SWEEP_TREE_PASSES = ("compact", "mjx")
# How pushes are decided: "full" (every push runs the whole horizon: the default, and what
# every sweep before the key ran) or "early".
DECISIONS = ("full", "early")
DECISION_KEYS = ("decisions", "lanes", "segment_ticks")
LANES_RANGE = (1, 1_048_576)
SEGMENT_TICKS_RANGE = (1, 1000)
DEFAULT_LANES = 4096
DEFAULT_SEGMENT_TICKS = 4


@dataclasses.dataclass(frozen=True)
class Decisions:
    """[sweep] decisions, lanes, segment_ticks (see the module docstring). lanes: pushes in
    flight (at most the chunk size: a chunk's pushes share its lanes); segment_ticks: control
    ticks a segment advances every lane before decided lanes are refilled."""

    mode: str = DECISIONS[0]
    lanes: int = DEFAULT_LANES
    segment_ticks: int = DEFAULT_SEGMENT_TICKS

    @property
    def early(self) -> bool:
        return self.mode == "early"

    def describe(self) -> dict:
        """The manifest's record of the decisions (lanes and segments only when early)."""
        if not self.early:
            return {"decisions": self.mode}
        return {"decisions": self.mode, "lanes": self.lanes, "segment_ticks": self.segment_ticks}


def tree_passes_of(sweep: dict) -> str:
    value = sweep.get("tree_passes", SWEEP_TREE_PASSES[0])
    if value not in SWEEP_TREE_PASSES:
        raise SpecError(f"sweep.tree_passes: expected one of {list(SWEEP_TREE_PASSES)}, "
                        f"got {value!r}")
    return value


def _integer(key: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise SpecError(f"sweep.{key}: expected an integer in [{lo}, {hi}], got {value!r}")
    return value


def decisions_of(sweep: dict, chunk_size: int, mode: str | None = None) -> Decisions:
    """The [sweep] table's Decisions; `mode` (the command line's --decisions) overrides the
    spec's. lanes default to min(DEFAULT_LANES, chunk_size) and may not exceed chunk_size."""
    mode = sweep.get("decisions", DECISIONS[0]) if mode is None else mode
    if mode not in DECISIONS:
        raise SpecError(f"sweep.decisions: expected one of {list(DECISIONS)}, got {mode!r}")
    lanes = _integer("lanes", sweep.get("lanes", min(DEFAULT_LANES, chunk_size)), *LANES_RANGE)
    if lanes > chunk_size:
        raise SpecError(f"sweep.lanes: {lanes} exceeds sweep.chunk_size {chunk_size} (a chunk's "
                        f"pushes share its lanes: give lanes in [1, {chunk_size}])")
    segment = _integer("segment_ticks", sweep.get("segment_ticks", DEFAULT_SEGMENT_TICKS),
                       *SEGMENT_TICKS_RANGE)
    return Decisions(mode=mode, lanes=lanes, segment_ticks=segment)


def with_decisions(spec, mode: str | None):
    """`spec` (a SweepSpec) with its decisions' mode set to `mode` (None: unchanged); the
    command line's --decisions. SpecError names the key and the allowed values."""
    if mode is None:
        return spec
    sweep = dict(spec.raw.get("sweep", {}))
    return dataclasses.replace(spec, decisions=decisions_of(sweep, spec.chunk_size, mode))


def hashed_raw(raw: dict) -> dict:
    """The spec as the spec hash reads it: without the decision keys (the hash states the
    decisions apart, and only when they are early, so that a spec saying decisions = "full"
    keeps the hash of one that does not)."""
    sweep = {k: v for k, v in raw.get("sweep", {}).items() if k not in DECISION_KEYS}
    return raw | ({"sweep": sweep} if "sweep" in raw else {})
