"""Lanes: closed-loop episodes on their own clocks, advanced a segment of control ticks at a
time, each stopping as soon as its push is decided (early decisions).

A lane holds one episode's state: the MJX data, the IMU carry, the controller state, its
Series rows so far (a buffer of the horizon's length), its tick counter `k` and tick limit,
and the decision. `lane_ticks` advances a lane by a static number of control ticks; a lane
that is decided, or has reached its limit, keeps its state unchanged, bit for bit (a select
per tick), so what it records does not depend on where the segments end. Under vmap every
lane runs the same program; the host refills decided lanes between segments
(`tkujax.sweeps.early`).

Decided (`decision_of`):
  fallen   the sweeps' fall test (`tkujax.sim.metrics.fall_indicator`: the pelvis below
           FALL_PELVIS_HEIGHT_M, or a non-foot collision geom within FALL_BODY_CLEARANCE_M of
           the floor) holds at a tick;
  settled  after the push has ended, for SETTLE_HOLD_S in a row: the pelvis's angular rate
           below SETTLE_ANGULAR_RATE_RAD_S, the CoM's speed (between successive ticks) below
           SETTLE_COM_SPEED_M_S. A robot that still leans (out of the recovery band) but has
           come to rest is settled too: it reads "not recovered" (NaN) as it would at the
           horizon, where it would still lean.
           A walking robot (Episode.walk) is never settled: it is meant to keep moving, and
           coming to rest says nothing about whether it will fall later. Its lane is decided
           by a fall, or runs to the horizon.

`truncated` gives a lane's rows up to the decision with the last recorded row repeated to the
horizon, so that `tkujax.sim.metrics.outcomes` reads the series as if the robot stayed where
it was decided (a lane that ran its horizon: its rows as they are).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from tkujax.control.controller import controller_init
from tkujax.control.fixed import controller_init_fx
from tkujax.control.controller_params import ControllerParams
from tkujax.control.walking import walking_init
from tkujax.sim.closed_loop import TickPieces, imu_read
from tkujax.sim.metrics import fall_indicator
from tkujax.sim.mjx_import import mjx
from tkujax.sim.options import Episode, RolloutConfig
from tkujax.sim.records import Series

# The settled criterion (see the module docstring).
SETTLE_ANGULAR_RATE_RAD_S = 0.1
SETTLE_COM_SPEED_M_S = 0.02
SETTLE_HOLD_S = 0.3

# Decision codes (the lane's `decision`).
UNDECIDED, FALLEN, SETTLED = 0, 1, 2


def n_ticks_of(config: RolloutConfig) -> int:
    """Control ticks of the horizon config.duration_s."""
    return int(round(config.duration_s / config.control_period_s))


def lane_start(pieces: TickPieces, state: mjx.Data, index, episode: Episode,
               params: ControllerParams, config: RolloutConfig) -> dict:
    """A fresh lane at t = 0 (the settled stand `state`): tick 0 of n_ticks_of(config), no
    rows yet, undecided. `params` as the controller runs them (control_period set)."""
    n_ticks = n_ticks_of(config)
    dtype = state.qpos.dtype
    ctrl = (controller_init(params, dtype) if config.fixed is None else
            controller_init_fx(params, config.fixed, dtype))
    if episode.walk is not None:     # a walking lane (a Python branch on None)
        ctrl = walking_init(params, episode.walk, dtype)
    imu = imu_read(index, state)
    keys = jax.random.split(episode.key, n_ticks)
    shapes = jax.eval_shape(pieces.control, imu, ctrl, keys[0])
    out0 = jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), shapes[3])
    row = jax.eval_shape(pieces.record, state, out0, ctrl)
    rows = jax.tree.map(lambda a: jnp.zeros((n_ticks,) + a.shape, a.dtype), row)
    return dict(d=state, imu=imu, ctrl=ctrl, rows=rows, keys=keys, k=jnp.int32(0),
                limit=jnp.int32(n_ticks), quiet=jnp.int32(0), decision=jnp.int32(UNDECIDED))


def _physics(pieces: TickPieces, d, imu, ctrl, n: int):
    carry, _ = jax.lax.scan(lambda c, _: (pieces.substep(c), None), (d.replace(ctrl=ctrl), imu),
                            None, length=n)
    return carry


def decision_of(lane: dict, row: Series, d: mjx.Data, episode: Episode,
                control_period_s: float) -> tuple[jax.Array, jax.Array]:
    """(quiet ticks in a row, decision code) after the tick whose row is `row` (k not yet
    advanced: the previous row is rows[k - 1])."""
    k, push = lane["k"], episode.push
    prev = jax.tree.map(lambda b: b[jnp.maximum(k - 1, 0)], lane["rows"])
    com_speed = jnp.linalg.norm(row.com - prev.com) / control_period_s
    rate = jnp.linalg.norm(d.qvel[3:6])
    quiet_now = ((row.t > push.onset_s + push.duration_s) & (k > 0)
                 & (rate < SETTLE_ANGULAR_RATE_RAD_S) & (com_speed < SETTLE_COM_SPEED_M_S))
    quiet = jnp.where(quiet_now, lane["quiet"] + 1, 0)
    hold_ticks = int(round(SETTLE_HOLD_S / control_period_s))
    fallen = fall_indicator(row)
    settled = (quiet >= hold_ticks) if episode.walk is None else False   # walking: falls only
    decision = jnp.where(fallen, FALLEN, jnp.where(settled, SETTLED, UNDECIDED))
    return quiet.astype(jnp.int32), decision.astype(jnp.int32)


def lane_ticks(pieces: TickPieces, episode: Episode, config: RolloutConfig, lane: dict,
               n: int) -> dict:
    """`n` control ticks of one lane. A lane runs a tick while k < limit and it is undecided;
    otherwise the tick's result is discarded and the lane stays as it was."""
    def tick(lane, _):
        k = jnp.minimum(lane["k"], lane["limit"] - 1)
        ctrl, command, earlier, out = pieces.control(lane["imu"], lane["ctrl"], lane["keys"][k])
        d, imu = lane["d"], lane["imu"]
        if pieces.switch > 0:
            d, imu = _physics(pieces, d, imu, earlier, pieces.switch)
        d, imu = _physics(pieces, d, imu, command, pieces.substeps - pieces.switch)
        row = pieces.record(d, out, ctrl)
        quiet, decision = decision_of(lane, row, d, episode, config.control_period_s)
        active = (lane["k"] < lane["limit"]) & (lane["decision"] == UNDECIDED)
        # Only row k can change: select the row, not the whole buffer (the same rows).
        row = jax.tree.map(lambda x, b: jnp.where(active, x, b[k]), row, lane["rows"])
        rows = jax.tree.map(lambda b, x: jax.lax.dynamic_update_index_in_dim(b, x, k, 0),
                            lane["rows"], row)
        new = dict(d=d, imu=imu, ctrl=ctrl, k=lane["k"] + 1, quiet=quiet, decision=decision)
        kept = {name: lane[name] for name in new}
        new = jax.tree.map(lambda a, b: jnp.where(active, a, b), new, kept)
        return dict(lane, rows=rows, **new), None

    lane, _ = jax.lax.scan(tick, lane, None, length=n)
    return lane


def lane_done(lane: dict) -> jax.Array:
    """Whether the lane's push is decided or has run its horizon."""
    return (lane["decision"] != UNDECIDED) | (lane["k"] >= lane["limit"])


def truncated(rows: Series, k) -> Series:
    """The rows up to the k-th, the last of them repeated to the horizon's length."""
    n = rows.t.shape[0]
    idx = jnp.minimum(jnp.arange(n), jnp.maximum(k - 1, 0))
    return jax.tree.map(lambda b: b[idx], rows)
