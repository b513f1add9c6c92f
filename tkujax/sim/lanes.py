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
  back on its gait (a walking robot, Episode.walk: it is meant to keep moving, so coming
           to rest says nothing; the decision code is SETTLED): after the push has ended, for
           GAIT_HOLD_CYCLES gait cycles (two steps each) in a row, the pelvis's pitch and roll
           and their rates stay inside GAIT_ENVELOPE_SCALE x their envelope in the
           GAIT_REFERENCE_CYCLES gait cycles before the onset (about those cycles' mean), plus
           GAIT_ANGLE_MARGIN_RAD and GAIT_RATE_MARGIN_RAD_S. Only where those cycles lie after
           the gait's ramp (`back_on_gait_armed`); otherwise the lane is decided by a fall or
           runs to the horizon. tests/test_walk_decisions.py checks the rule on a synthetic
           gait and against the full horizon.

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
# Back on its gait (see the module docstring). On 64 pushes each of TKU-X and OP3 walking at
# 0.1 m/s (13 s, MuJoCo C) no push so decided fell later; survivors were decided 1.3 s (TKU-X)
# and 0.8 s (OP3) after the onset on average.
GAIT_ENVELOPE_SCALE = 1.5
GAIT_ANGLE_MARGIN_RAD = 0.0175        # 1 deg
GAIT_RATE_MARGIN_RAD_S = 0.175        # 10 deg/s
GAIT_REFERENCE_CYCLES = 2.0
# Held for two cycles: with one, 20 of 16,384 walking pushes so decided (TKU-X, one H200) fell
# later within the 9 s horizon.
GAIT_HOLD_CYCLES = 2.0

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
    if episode.walk is None:      # a Python branch on None (the standing program)
        com_speed = jnp.linalg.norm(row.com - prev.com) / control_period_s
        rate = jnp.linalg.norm(d.qvel[3:6])
        quiet_now = ((row.t > push.onset_s + push.duration_s) & (k > 0)
                     & (rate < SETTLE_ANGULAR_RATE_RAD_S) & (com_speed < SETTLE_COM_SPEED_M_S))
        quiet = jnp.where(quiet_now, lane["quiet"] + 1, 0)
        settled = quiet >= int(round(SETTLE_HOLD_S / control_period_s))
    else:
        quiet_now = on_gait_now(lane["rows"], k, row, prev, episode, control_period_s)
        quiet = jnp.where(quiet_now, lane["quiet"] + 1, 0)
        hold_s = GAIT_HOLD_CYCLES * 2.0 * episode.walk.step_period_s
        settled = ((quiet * control_period_s >= hold_s - 0.5 * control_period_s)
                   & back_on_gait_armed(episode))
    fallen = fall_indicator(row)
    decision = jnp.where(fallen, FALLEN, jnp.where(settled, SETTLED, UNDECIDED))
    return quiet.astype(jnp.int32), decision.astype(jnp.int32)


def back_on_gait_armed(episode: Episode) -> jax.Array:
    """Whether the reference cycles before the onset lie after the gait's ramp (the steps
    reach their full length after ramp_steps + 1 steps from start_s)."""
    walk, push = episode.walk, episode.push
    steady_s = walk.start_s + (walk.ramp_steps + 1.0) * walk.step_period_s
    return push.onset_s - GAIT_REFERENCE_CYCLES * 2.0 * walk.step_period_s >= steady_s


def on_gait_now(rows: Series, k, row: Series, prev: Series, episode: Episode,
                control_period_s: float) -> jax.Array:
    """Whether this tick's pelvis pitch, roll and their rates lie inside the envelope of the
    reference cycles before the onset, after the push has ended (module docstring)."""
    push, cycle_s = episode.push, 2.0 * episode.walk.step_period_s
    n = rows.t.shape[0]
    idx = jnp.arange(n)
    ref = ((rows.t >= push.onset_s - GAIT_REFERENCE_CYCLES * cycle_s) & (rows.t < push.onset_s)
           & (idx < k) & (idx > 0))
    weight = ref.astype(rows.t.dtype)
    count = jnp.maximum(jnp.sum(weight), 1.0)

    def inside(series_now, series_prev, history):
        mean = jnp.sum(history * weight) / count
        spread = jnp.max(jnp.where(ref, jnp.abs(history - mean), 0.0))
        rates = jnp.abs(jnp.diff(history, prepend=history[:1])) / control_period_s
        rate_spread = jnp.max(jnp.where(ref, rates, 0.0))
        rate_now = jnp.abs(series_now - series_prev) / control_period_s
        return ((jnp.abs(series_now - mean) <= GAIT_ENVELOPE_SCALE * spread
                 + GAIT_ANGLE_MARGIN_RAD)
                & (rate_now <= GAIT_ENVELOPE_SCALE * rate_spread + GAIT_RATE_MARGIN_RAD_S))

    return ((row.t > push.onset_s + push.duration_s) & (k > 0) & jnp.any(ref)
            & inside(row.pitch, prev.pitch, rows.pitch) & inside(row.roll, prev.roll, rows.roll))


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
