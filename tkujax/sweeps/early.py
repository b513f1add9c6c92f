"""Early decisions with lane refill: a sweep chunk's pushes streamed through a fixed batch of
lanes (`[sweep] decisions = "early"`, docs/sweeps.md).

`make_lane_fns` compiles three programs, each jit(vmap) over lanes (`tkujax.sim.lanes`):
  start(recs, keys, params, schedule, limits) -> lanes
      fresh lanes for the records, each to run until tick limits[i];
  start_snap(recs, keys, params, schedule, limits, snap, gidx, use_snap) -> lanes
      the same, but where use_snap the pre-push snapshot snap[gidx] with the record's own
      noise keys;
  segment(lanes, starts, reset, recs, params, schedule) -> (lanes, done, outcomes)
      the lanes where `reset` replaced by `starts`, then segment_ticks control ticks of every
      lane, then each lane's outcomes read from its rows up to its decision.
`run_lanes` is the host loop: pushes go to free lanes in index order (lowest lane first),
decided lanes' outcomes are written under their push's index, and the lanes are refilled.
Nothing depends on Python branching on traced values; which lane a push lands in depends
only on the decisions before it, so a chunk's records are the same on every run. A sweep
streams all the chunks of a process through one batch of lanes instead
(`tkujax.sweeps.lane_stream`, the same programs and records: no lane reads another).

Pre-push snapshot: where the pushes of a chunk differ only in the push itself (the same
control setting, robot, controller and no sensor noise), every one of them stands the same
way until its push: the force is exactly zero before the control tick k0 = floor(onset /
period), and nothing else differs. The lanes then start from one snapshot per (k0, setting),
computed once by the same program, instead of from the stand (tests/test_early.py checks
that the records are the same bit for bit).
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.fixed import FixedPointConfig
from tkujax.model import ModelParams
from tkujax.sim import lanes as lane_sim
from tkujax.sim.closed_loop import tick_pieces
from tkujax.sim.metrics import WALK_KEYS, capture_outcomes, walk_outcomes
from tkujax.sim.metrics import outcomes as rollout_outcomes
from tkujax.sim.options import ProgramOptions, RolloutConfig
from tkujax.sim.push import CONTROL_PERIOD_S
from tkujax.sweeps.chunk_program import (OUTCOME_KEYS, SWEEP_COMPILER_OPTIONS, record_episode,
                                         sweep_base)
from tkujax.dialects.sweep_spec import PHASE_KEY, PUSH_FIELDS, EnsembleRef
from tkujax.dialects.walk_table import GAIT_PHASE_KEY

DECIDED_COLUMN = "decided_s"   # early records: the time of the last simulated tick
# The readings an early record takes up to the fall decision when the push fell (the full
# horizon reads them after the robot has tumbled further); every other reading, and all of a
# settled push's, mean what they mean at the full horizon.
TRUNCATED_WHEN_FALLEN = ("peak_incl_deg", "step_length_m", "step_width_m", "zmp_excursion_m")


@dataclasses.dataclass(frozen=True)
class LaneFns:
    """The compiled start and segment programs of one early sweep program, and its horizon."""

    start: object
    start_snap: object
    segment: object
    n_ticks: int
    segment_ticks: int
    columns: tuple[str, ...]


def make_lane_fns(varied: tuple[str, ...], duration_s: float,
                  model_params: ModelParams | None = None, steps: bool = False,
                  fixed: FixedPointConfig | None = None, ensemble: EnsembleRef | None = None,
                  tree_passes: str = "compact", segment_ticks: int = 4,
                  walk=None) -> LaneFns:
    """The early-decision programs of a sweep (cached per argument tuple, like
    `make_chunk_fn`): see the module docstring. walk: a [walk] sweep's base WalkCommand
    (`make_chunk_fn`'s): walking lanes, decided by a fall only, with the WALK_KEYS outcomes."""
    return _make_lane_fns(tuple(varied), float(duration_s), model_params, bool(steps), fixed,
                          ensemble, tree_passes, int(segment_ticks), walk)


@functools.lru_cache(maxsize=8)
def _make_lane_fns(varied, duration_s, model_params, steps, fixed, ensemble, tree_passes,
                   segment_ticks, walk):
    base = sweep_base(model_params, ensemble)
    index, robots = base[1], base[3]
    config = RolloutConfig(duration_s=duration_s, fixed=fixed,
                           program=ProgramOptions(tree_passes=tree_passes))

    def pieces_of(rec, key, base_params, schedule, values):
        m, s, episode, params, override = record_episode(base, rec, key, base_params, varied,
                                                         steps, values, walk)
        params = dataclasses.replace(params, control_period=config.control_period_s)
        if override is not None:
            override = dataclasses.replace(override, onset_s=episode.push.onset_s)
        return tick_pieces(m, index, episode, params, config, override, schedule), s, episode, \
            params

    def start_one(rec, key, base_params, schedule, values, limit, snap=None, use_snap=None):
        pieces, s, episode, params = pieces_of(rec, key, base_params, schedule, values)
        lane = lane_sim.lane_start(pieces, s, index, episode, params, config)
        if snap is not None:
            lane = dict(jax.tree.map(lambda a, b: jnp.where(use_snap, a, b), snap, lane),
                        keys=lane["keys"])
        return dict(lane, limit=limit.astype(jnp.int32))

    def start(recs, keys, base_params, schedule, limits, values=None):
        return jax.vmap(start_one, in_axes=(0, 0, None, None, None, 0))(
            recs, keys, base_params, schedule, values, limits)

    def start_snap(recs, keys, base_params, schedule, limits, snap, gidx, use_snap,
                   values=None):
        picked = jax.tree.map(lambda x: x[gidx], snap)
        return jax.vmap(start_one, in_axes=(0, 0, None, None, None, 0, 0, 0))(
            recs, keys, base_params, schedule, values, limits, picked, use_snap)

    def segment_one(lane, fresh, reset, rec, base_params, schedule, values):
        lane = jax.tree.map(lambda a, b: jnp.where(reset, a, b), fresh, lane)
        pieces, _, episode, params = pieces_of(rec, lane["keys"][0], base_params, schedule,
                                               values)
        lane = lane_sim.lane_ticks(pieces, episode, config, lane, segment_ticks)
        series = lane_sim.truncated(lane["rows"], lane["k"])
        out = rollout_outcomes(series, episode.push.onset_s)
        res = {k: out[k] for k in OUTCOME_KEYS} | {DECIDED_COLUMN: series.t[-1]}
        if walk is not None:
            res |= walk_outcomes(series, walk.start_s)
        if steps:
            res |= capture_outcomes(series, episode.push.onset_s, params.gravity)
        return lane, lane_sim.lane_done(lane), res

    def segment(lanes, starts, reset, recs, base_params, schedule, values=None):
        return jax.vmap(segment_one, in_axes=(0, 0, 0, 0, None, None, None))(
            lanes, starts, reset, recs, base_params, schedule, values)

    jit = functools.partial(jax.jit, compiler_options=SWEEP_COMPILER_OPTIONS)
    fns = [jit(start), jit(start_snap), jit(segment)]
    if robots is not None:   # the members' values: arguments of the programs, not constants
        fns = [functools.partial(f, values=robots.values()) for f in fns]
    columns = OUTCOME_KEYS + (DECIDED_COLUMN,) + (WALK_KEYS if walk is not None else ())
    if steps:
        from tkujax.sim.metrics import CAPTURE_KEYS
        columns += CAPTURE_KEYS
    return LaneFns(start=fns[0], start_snap=fns[1], segment=fns[2],
                   n_ticks=lane_sim.n_ticks_of(config), segment_ticks=segment_ticks,
                   columns=columns)


def snapshot_groups(recs: dict[str, np.ndarray], steps: bool) -> tuple[np.ndarray, np.ndarray]:
    """(group per record, pre-push tick k0 per group): records in one group stand the same
    way until tick k0 (see the module docstring); group -1: the record starts from the stand
    (sensor noise, whose keys differ per push, or a commanded step)."""
    n = len(recs["onset_s"])
    k0 = np.floor(np.asarray(recs["onset_s"], np.float64) / CONTROL_PERIOD_S + 1e-6)
    # The push's timing (its onset's phase in the control period and in the gait) is the
    # push's, not the setting's: records that differ only there share their walk until k0.
    setting = [np.asarray(v, np.float64) for k, v in sorted(recs.items())
               if k not in PUSH_FIELDS and k not in (PHASE_KEY, GAIT_PHASE_KEY)]
    quiet = (np.asarray(recs["gyro_noise_std"]) == 0) & (np.asarray(recs["accel_noise_std"]) == 0)
    if steps or not quiet.any():
        return np.full(n, -1), np.zeros(0, np.int64)
    keys = np.stack([k0] + setting, 1)
    uniq, group = np.unique(keys[quiet], axis=0, return_inverse=True)
    out = np.full(n, -1)
    out[quiet] = group.ravel()
    return out, uniq[:, 0].astype(np.int64)


def _put(x, sharding):
    return jax.device_put(x, sharding) if sharding is not None else jnp.asarray(x)


@dataclasses.dataclass
class _Lanes:
    """The host's view of a chunk's lanes: which push each holds (-1: idle), the next push."""

    fns: LaneFns
    recs: dict
    keys: jax.Array
    params: object
    schedule: object
    sharding: object
    lane_push: np.ndarray
    snap: tuple | None = None      # (snapshot lanes, group per record)
    next_push: int = 0

    def put(self, x):
        return _put(x, self.sharding)

    def starts(self, limits: np.ndarray):
        """Start lanes for lane_push (an idle lane: record 0, limit 0)."""
        rows = np.maximum(self.lane_push, 0)
        recs = {k: self.put(np.asarray(v)[rows].astype(np.float32))
                for k, v in self.recs.items()}
        args = (recs, self.put(np.asarray(self.keys)[rows]), self.params, self.schedule,
                self.put(limits.astype(np.int32)))
        if self.snap is None:
            return recs, self.fns.start(*args)
        group = self.snap[1][rows]
        use = (group >= 0) & (self.lane_push >= 0)
        return recs, self.fns.start_snap(*args, self.snap[0],
                                         self.put(np.maximum(group, 0).astype(np.int32)),
                                         self.put(use))

    def fill(self, free: np.ndarray) -> np.ndarray:
        """Give the next pushes, in index order, to the free lanes (lowest first); returns
        the lanes filled."""
        n = len(self.recs["onset_s"])
        take = free[:max(0, min(len(free), n - self.next_push))]
        self.lane_push[take] = np.arange(self.next_push, self.next_push + len(take))
        self.next_push += len(take)
        return take


def _snapshot(state: _Lanes, group: np.ndarray, k0: np.ndarray):
    """The pre-push lanes: group g's first record run to tick k0[g] in lane g."""
    n_lanes = len(state.lane_push)
    first = np.array([np.flatnonzero(group == g)[0] for g in range(len(k0))])
    state.lane_push[:] = -1
    state.lane_push[:len(first)] = first
    limits = np.zeros(n_lanes, np.int64)
    limits[:len(first)] = k0
    recs, lanes = state.starts(limits)
    reset = state.put(np.zeros(n_lanes, bool))
    for _ in range(math.ceil(int(k0.max()) / state.fns.segment_ticks)):
        lanes, _, _ = state.fns.segment(lanes, lanes, reset, recs, state.params, state.schedule)
    state.lane_push[:] = -1
    return lanes


def pre_push_snapshot(fns: LaneFns, recs: dict, keys, params, schedule, n_lanes: int,
                      group: np.ndarray, k0: np.ndarray, sharding=None):
    """The pre-push snapshot lanes of these records (`snapshot_groups`' group and k0), as
    `run_lanes` computes them in its `n_lanes` lanes."""
    state = _Lanes(fns, recs, keys, params, schedule, sharding, np.full(n_lanes, -1))
    return _snapshot(state, group, k0)


def run_lanes(fns: LaneFns, recs: dict[str, np.ndarray], keys: jax.Array, params,
              schedule, n_lanes: int, sharding=None, snapshot: bool = True,
              steps: bool = False) -> dict[str, np.ndarray]:
    """Every record's outcomes (columns fns.columns, in record order), its push streamed
    through `n_lanes` lanes with early decisions. recs: the records' input columns; keys:
    one noise key per record; snapshot: start pushes from the pre-push snapshot where that
    gives the same records (`snapshot_groups`)."""
    n = len(recs["onset_s"])
    state = _Lanes(fns, recs, keys, params, schedule, sharding, np.full(n_lanes, -1))
    group, k0 = snapshot_groups(recs, steps)
    if snapshot and 0 < len(k0) <= n_lanes and 4 * len(k0) <= n and k0.max() > 0:
        state.snap = (_snapshot(state, group, k0), group)
    out: dict[str, np.ndarray] = {}
    lanes, recs_now = None, None
    free = np.arange(n_lanes)
    while True:
        filled = state.fill(free)
        if lanes is None or len(filled):
            limits = np.where(state.lane_push >= 0, fns.n_ticks, 0)
            recs_now, starts = state.starts(limits)
            reset = np.zeros(n_lanes, bool)
            reset[filled] = True
            lanes = starts if lanes is None else lanes
        else:
            starts, reset = lanes, np.zeros(n_lanes, bool)
        if (state.lane_push < 0).all():
            break
        lanes, done, res = fns.segment(lanes, starts, state.put(reset), recs_now, params,
                                       schedule)
        finished = np.flatnonzero(np.asarray(done) & (state.lane_push >= 0))
        if len(finished):
            res = {k: np.asarray(v) for k, v in res.items()}
            for k, v in res.items():
                out.setdefault(k, np.empty((n,) + v.shape[1:], v.dtype))[
                    state.lane_push[finished]] = v[finished]
            state.lane_push[finished] = -1
        free = np.flatnonzero(state.lane_push < 0)
    return out
