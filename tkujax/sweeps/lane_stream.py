"""Early decisions across chunk boundaries: the pushes of several chunks streamed through one
batch of lanes (docs/sweeps.md, "Early decisions").

`run_lanes` (`tkujax.sweeps.early`) streams one chunk's pushes through its lanes; at the end
of the chunk the lanes drain, and the slowest push of the chunk holds the whole batch. A
`LaneStream` takes `Part`s (the pushes of one chunk, or of one fixed-point group of a chunk)
one after another: while a part drains, its free lanes take the pushes of the next part, which
`run`'s `more` callback supplies (the sweep claims the next chunk there), and `finished` is
called with a part as soon as all its pushes are decided (the sweep writes the chunk then).

Every push runs the same per-lane program as in `run_lanes` (a vmap: a lane's computation does
not depend on the other lanes), from the same start (the stand, or its own part's pre-push
snapshot) with its own noise key, so its record does not depend on which lane it ran in or
beside which part's pushes: the records are those of `run_lanes`, bit for bit
(tests/test_early.py). Parts with another compiled program (another fixed-point config) wait
until the lanes are empty.

`stats` counts lane-segments: `lane_segments` (lanes x segments run) and `idle_lane_segments`
(of them, lanes holding no push: the drain, and lanes a part never filled).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.sweeps.early import LaneFns, pre_push_snapshot, snapshot_groups


@dataclasses.dataclass
class Part:
    """Pushes streamed together: `label` (the caller's), their program, input columns (float32)
    and noise keys; `out`: their outcome columns as they are decided."""

    label: object
    fns: LaneFns
    recs: dict[str, np.ndarray]
    keys: np.ndarray
    snap: tuple | None = None          # (snapshot lanes, group per record)
    next_push: int = 0
    left: int = 0
    pid: int = -1
    out: dict = dataclasses.field(default_factory=dict)

    @property
    def n(self) -> int:
        return len(self.recs["onset_s"])


@jax.jit
def _pick(mask, a, b):
    """Per lane: a where mask, else b."""
    return jax.tree.map(lambda x, y: jnp.where(mask.reshape(mask.shape + (1,) * (x.ndim - 1)),
                                               x, y), a, b)


class LaneStream:
    """A batch of `n_lanes` lanes taking the pushes of parts in order (module docstring)."""

    def __init__(self, n_lanes: int, params, schedule, sharding=None, snapshot: bool = True,
                 steps: bool = False, cross: bool = True):
        self.n_lanes, self.params, self.schedule = n_lanes, params, schedule
        self.sharding, self.snapshot, self.steps, self.cross = sharding, snapshot, steps, cross
        self.lane_part = np.full(n_lanes, -1)      # the part id each lane holds (-1: idle)
        self.lane_row = np.zeros(n_lanes, np.int64)
        self.parts: dict[int, Part] = {}            # parts with pushes in the lanes, by id
        self.n_parts = 0
        self.queue: list[Part] = []
        self.fns: LaneFns | None = None
        self.lanes = None
        self.lane_recs: dict[str, np.ndarray] | None = None
        self.lane_keys: np.ndarray | None = None
        self.stats = dict(segments=0, lane_segments=0, idle_lane_segments=0)

    def put(self, x):
        return jax.device_put(x, self.sharding) if self.sharding is not None else jnp.asarray(x)

    def part(self, label, fns: LaneFns, recs: dict, keys) -> Part:
        """A part of these records (input columns) and noise keys, with its pre-push snapshot
        where `run_lanes` takes one."""
        part = Part(label, fns, {k: np.asarray(v).astype(np.float32) for k, v in recs.items()},
                    np.asarray(keys))
        part.left = part.n
        group, k0 = snapshot_groups(part.recs, self.steps)
        if (self.snapshot and 0 < len(k0) <= self.n_lanes and 4 * len(k0) <= part.n
                and k0.max() > 0):
            part.snap = (pre_push_snapshot(fns, part.recs, part.keys, self.params,
                                           self.schedule, self.n_lanes, group, k0,
                                           self.sharding), group)
        return part

    def busy(self) -> np.ndarray:
        return self.lane_part >= 0

    def _next_part(self, more) -> Part | None:
        """The part whose pushes the free lanes take next (None: none now)."""
        while self.queue and self.queue[0].next_push >= self.queue[0].n:
            self.queue.pop(0)
        if not self.queue:
            idle = not self.busy().any()
            if not (self.cross or idle):
                return None
            new = more(idle)
            if not new:
                return None
            for part in new:
                if part.n == 0:
                    self.finished(part)
            self.queue.extend(p for p in new if p.n)
            return self._next_part(more)
        part = self.queue[0]
        if part.fns is not self.fns:
            if self.busy().any():
                return None                  # another program: drain the lanes first
            self.fns, self.lanes = part.fns, None
        return part

    def _fill(self, more) -> list[np.ndarray]:
        """Give the next pushes to the free lanes (lowest first); the lanes filled, per part."""
        free, filled = np.flatnonzero(~self.busy()), []
        while len(free):
            part = self._next_part(more)
            if part is None:
                break
            take = free[:part.n - part.next_push]
            rows = np.arange(part.next_push, part.next_push + len(take))
            part.next_push += len(take)
            if self.lane_recs is None:
                self.lane_recs = {k: np.repeat(v[:1], self.n_lanes, 0)
                                  for k, v in part.recs.items()}
                self.lane_keys = np.repeat(part.keys[:1], self.n_lanes, 0)
            for k, v in part.recs.items():
                self.lane_recs[k][take] = v[rows]
            self.lane_keys[take] = part.keys[rows]
            if part.next_push == len(take):
                self.parts[self.n_parts], part.pid = part, self.n_parts
                self.n_parts += 1
            self.lane_part[take], self.lane_row[take] = part.pid, rows
            filled.append(take)
            free = free[len(take):]
        return filled

    def _starts(self, filled: list[np.ndarray]):
        """(the lanes' records, fresh lanes where filled): each part's lanes from its own
        snapshot where it has one, merged by a per-lane select."""
        busy = self.busy()
        limits = self.put(np.where(busy, self.fns.n_ticks, 0).astype(np.int32))
        recs = {k: self.put(v) for k, v in self.lane_recs.items()}
        args = (recs, self.put(self.lane_keys), self.params, self.schedule, limits)
        starts = None
        for take in filled:
            part = self.parts[self.lane_part[take[0]]]
            mine = np.zeros(self.n_lanes, bool)
            mine[take] = True
            if part.snap is None:
                fresh = self.fns.start(*args)
            else:
                group = np.where(mine, part.snap[1][np.where(mine, self.lane_row, 0)], -1)
                fresh = self.fns.start_snap(*args, part.snap[0],
                                            self.put(np.maximum(group, 0).astype(np.int32)),
                                            self.put(group >= 0))
            starts = fresh if starts is None else _pick(self.put(mine), fresh, starts)
        return recs, starts

    def run(self, more, finished) -> None:
        """Stream parts until `more(idle)` gives none and every push is decided. more(idle):
        the next parts (a list, possibly empty; idle: no lane holds a push, so None/[] ends the
        stream); finished(part): all of part's pushes are decided (part.out holds them)."""
        self.finished = finished
        recs_now, n_lanes = None, self.n_lanes
        while True:
            filled = self._fill(more)
            busy = self.busy()
            if not busy.any():
                return
            if filled:
                recs_now, starts = self._starts(filled)
                reset = np.zeros(n_lanes, bool)
                reset[np.concatenate(filled)] = True
                self.lanes = starts if self.lanes is None else self.lanes
            else:
                starts, reset = self.lanes, np.zeros(n_lanes, bool)
            self.lanes, done, res = self.fns.segment(self.lanes, starts, self.put(reset),
                                                     recs_now, self.params, self.schedule)
            self.stats["segments"] += 1
            self.stats["lane_segments"] += n_lanes
            self.stats["idle_lane_segments"] += int(n_lanes - busy.sum())
            self._collect(np.flatnonzero(np.asarray(done) & busy), res)

    def _collect(self, lanes: np.ndarray, res: dict) -> None:
        """Store the decided lanes' outcomes under their push's row; free the lanes."""
        if not len(lanes):
            return
        res = {k: np.asarray(v) for k, v in res.items()}
        pids = self.lane_part[lanes]
        for pid in np.unique(pids):
            part, mine = self.parts[pid], lanes[pids == pid]
            rows = self.lane_row[mine]
            for k, v in res.items():
                part.out.setdefault(k, np.empty((part.n,) + v.shape[1:], v.dtype))[rows] = v[mine]
            self.lane_part[mine] = -1
            part.left -= len(mine)
            if part.left == 0:
                del self.parts[pid]
                self.finished(part)
