"""Recovery while walking: the capture point moves the footstep (Adiwahono et al. 2013).

While walking the body's pitch and roll swing with the gait (TKU-X at 0.1 m/s: the capture
point below swings +-3 cm about its mean, +-1.8 cm about its mean at the same gait phase), so
neither the standing controller's thresholds nor its capture point of the absolute lean tell a
push from a step (with them the recovery doubled the falls of a small push set;
docs/walking.md). Here the capture point is compared with what the same gait phase gave in
earlier cycles:

  xi          the LIP capture point of Eq. 6-8 (`capture_point.capture_point_rate` with the
              gyro's rate: cp_rate_blend = 1, no lookahead) of the filtered pitch (from the
              standing lean) and roll, [sagittal, lateral] (m);
  baseline    xi per gait-phase bin (PHASE_BINS over the two-step cycle of `gait.gait_phase`,
              tent weights), an exponential average over cycles (BASELINE_GAIN per visit) of
              the steady gait (after the ramp), frozen for QUIET_CYCLES cycles after a trigger,
              and the mean squared deviation from it (its spread);
  deviation   xi - baseline at this phase;
  trigger     the deviation beyond command.recovery_band_m + SPREAD_SIGMAS x the spread's
              root, the spread at this phase or the cycle's mean where larger (sagittal;
              sideways only with params.lateral_steps), with recovery, `enabled`, and
              WARM_VISITS of learning in every bin (with the bin's spread alone and 3 cycles
              of learning, OP3 walking 0.2 m/s undisturbed triggered on its own gait and fell;
              docs/walking.md);
  offset      cp_gain x the deviation (its forward part x command.recovery_forward_gain),
              clipped per axis to MAX_OFFSET_FRAC of thigh + calf,
              taken by the current step if its swing foot lands more than one period later
              (before its lift, or in the air), else by the next: the step grows by it,
              centred (`gait.move_footstep`), sideways only outward for that swing foot (the
              legs never cross). While the trigger holds the step's offset follows the
              deviation, once per period (`move_footsteps`);
  late push   a push whose sideways deviation, when it first passes its band, points inward
              for the swing foot of the step that would take the offset (pushed left while
              the right foot swings): that step takes no sideways offset and the other
              foot's next one does, late. Until the recovery is quiet again (no trigger for
              QUIET_CYCLES) the swing foot's half of every sideways offset of the push is x
              command.recovery_late_swing_gain (1: centred; 0: the support foot alone moves,
              for a robot whose late centred steps overshoot to the other side, as OP3's:
              docs/walking.md).

tests/test_walk.py checks that an undisturbed walk never triggers it (-0.2 to 0.3 m/s, 20 s, in
docs/walking.md) and that a push from behind moves the footstep forward;
tests/test_walk_late_push.py the late push's rule and its steps' feet.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from tkujax.control.capture_point import capture_point_rate
from tkujax.control.gait import (GaitState, WalkCommand, gait_phase, move_footstep,
                                 swing_in_reach)
from tkujax.control.controller_params import ControllerParams

PHASE_BINS = 16
BASELINE_GAIN = 0.3
QUIET_CYCLES = 2.0
SPREAD_SIGMAS = 2.0      # the trigger: the band plus this many deviations of the gait's own
WARM_VISITS = 6.0       # summed weights per bin before the trigger arms (about 5 cycles)
# The offset's bound per axis, a fraction of thigh + calf (TKU-X: 0.22 m -> 8.8 cm, about
# twice the paper's longest recovery step, 4.15 cm).
MAX_OFFSET_FRAC = 0.4


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RecoveryState:
    """baseline: (PHASE_BINS, 2) the undisturbed capture point per phase bin [x, y] (m);
    spread: (PHASE_BINS, 2) the mean squared deviation from it there (m^2); seen:
    (PHASE_BINS,) the summed weights each bin has learned from; pending: (2,) the offset the
    next step takes (m); armed: 1 while a push is being handled (set by the trigger, cleared
    when a step takes the offset); applied: (2,) the offset the current step has taken (m);
    quiet_until_s: the baseline does not learn before this
    time (QUIET_CYCLES gait cycles after the last trigger); side_open: 1 from a push's first
    trigger (at or after quiet_until_s) until its sideways deviation first passes its band;
    side_now: 1 in a period whose trigger has the sideways deviation beyond its band; late: 1
    for the rest of a late push (module doc), set when side_open meets side_now."""

    baseline: jax.Array
    spread: jax.Array
    seen: jax.Array
    pending: jax.Array
    armed: jax.Array
    applied: jax.Array
    quiet_until_s: jax.Array
    side_open: jax.Array
    side_now: jax.Array
    late: jax.Array

    @staticmethod
    def init(dtype=jnp.float32) -> RecoveryState:
        return RecoveryState(baseline=jnp.zeros((PHASE_BINS, 2), dtype),
                             spread=jnp.zeros((PHASE_BINS, 2), dtype),
                             seen=jnp.zeros((PHASE_BINS,), dtype),
                             pending=jnp.zeros((2,), dtype), armed=jnp.zeros((), dtype),
                             applied=jnp.zeros((2,), dtype),
                             quiet_until_s=jnp.zeros((), dtype),
                             side_open=jnp.zeros((), dtype), side_now=jnp.zeros((), dtype),
                             late=jnp.zeros((), dtype))


def walking_capture_point(phi, psi, pitch_rate, psi_rate, params: ControllerParams):
    """(2,) the capture point [x, y] (m) of the pitch deviation from the standing lean and the
    lateral lean psi, with the gyro's rates (Eq. 6-8, cp_rate_blend = 1, no lookahead)."""
    p = dataclasses.replace(params, cp_rate_blend=1.0, cp_lookahead_s=0.0)
    return jnp.stack([capture_point_rate(phi - params.standing_lean, pitch_rate, p),
                      capture_point_rate(psi, psi_rate, p)], -1)


def recovery_update(state: RecoveryState, xi, time_s, command: WalkCommand,
                    params: ControllerParams, on, steady, lead_s=0.0
                    ) -> tuple[RecoveryState, jax.Array]:
    """One period: (state, deviation (2,) m) from this period's capture point xi (2,) at
    controller time time_s; `on` = recovery x enabled (0 or 1); `steady`: the gait is past its
    ramp (the baseline learns the steady gait only); lead_s: how far the gait runs ahead of its
    nominal schedule (`GaitState.lead_s`), so that the phase is the gait's own."""
    dtype = state.baseline.dtype
    weights = phase_weights(gait_phase(jnp.asarray(time_s, dtype) + lead_s, command), dtype)
    base = weights @ state.baseline
    seen = jnp.min(jnp.where(weights > 0.0, state.seen, jnp.inf))
    deviation = jnp.where(seen > 0.5, xi - base, 0.0)
    warm = jnp.min(state.seen) >= WARM_VISITS
    # The spread at this phase, or over the whole cycle where that is larger (a bin's spread
    # from a few cycles can be far below what the gait does there now and then).
    spread = jnp.maximum(weights @ state.spread, jnp.mean(state.spread, 0))
    band = jnp.asarray(command.recovery_band_m, dtype) + SPREAD_SIGMAS * jnp.sqrt(spread)
    sideways = (params.lateral_steps > 0.5) & (jnp.abs(deviation[1]) > band[1])
    beyond = (jnp.abs(deviation[0]) > band[0]) | sideways
    trigger = (on > 0.5) & warm & beyond
    reach = MAX_OFFSET_FRAC * (params.thigh_length + params.calf_length)
    forward = jnp.where(deviation[0] > 0.0, jnp.asarray(command.recovery_forward_gain, dtype),
                        jnp.ones((), dtype))
    offset = jnp.clip(params.cp_gain * deviation * jnp.stack(
        [forward, jnp.asarray(params.lateral_steps, dtype)]), -reach, reach)
    armed = jnp.where(trigger, 1.0, state.armed).astype(dtype)
    pending = jnp.where(trigger, offset, state.pending).astype(dtype)
    cycle = 2.0 * jnp.asarray(command.step_period_s, dtype)
    first = trigger & (time_s >= state.quiet_until_s)      # a new push, not one being handled
    quiet = jnp.where(trigger, time_s + QUIET_CYCLES * cycle, state.quiet_until_s).astype(dtype)
    # The baseline learns only away from pushes (the disturbed cycles are not the gait's).
    share = (steady & (time_s >= quiet)) * weights
    gain = share * jnp.where(state.seen > 0.0, BASELINE_GAIN, 1.0)
    baseline = state.baseline + gain[:, None] * (xi[None, :] - state.baseline)
    spread = state.spread + (share * BASELINE_GAIN * (state.seen > 0.0))[:, None] * (
        (xi[None, :] - state.baseline) ** 2 - state.spread)
    return dataclasses.replace(state, baseline=baseline.astype(dtype),
                               spread=spread.astype(dtype),
                               seen=(state.seen + share).astype(dtype), pending=pending,
                               armed=armed, quiet_until_s=quiet,
                               side_open=jnp.where(first, 1.0, state.side_open).astype(dtype),
                               side_now=(trigger & sideways).astype(dtype),
                               late=jnp.where(first, 0.0, state.late).astype(dtype)), deviation


def phase_weights(phase, dtype=jnp.float32) -> jax.Array:
    """(PHASE_BINS,) tent weights of a gait phase in [0, 1) on the bins' centres (periodic):
    the two nearest bins share it linearly, so the baseline is smooth in the phase whatever the
    number of control periods per cycle."""
    x = phase * PHASE_BINS - 0.5
    lo = jnp.floor(x)
    frac = x - lo
    idx = jnp.arange(PHASE_BINS)
    lo_i = jnp.mod(lo, PHASE_BINS)
    return (jnp.where(idx == lo_i, 1.0 - frac, 0.0)
            + jnp.where(idx == jnp.mod(lo + 1.0, PHASE_BINS), frac, 0.0)).astype(dtype)


def step_offset(state: RecoveryState, swing_left) -> jax.Array:
    """(2,) the offset a step whose swing foot is the left one (swing_left 1) or the right one
    takes: the pending one, its sideways part only outward for that foot."""
    side = jnp.where(swing_left > 0.5, 1.0, -1.0)
    y = side * jnp.maximum(side * state.pending[1], 0.0)
    return jnp.stack([state.pending[0], y]).astype(state.pending.dtype)


def late_push(pending_y, swing_left, in_reach) -> jax.Array:
    """1 where a sideways offset pending_y (m, + = left) points inward for the swing foot of the
    step that would take it (the current step's while in reach, else the next one's, the other
    foot), so that step takes none and it waits for the other foot's step; 0 where it points
    outward for it."""
    taker_left = jnp.where(in_reach, swing_left > 0.5, swing_left < 0.5)
    return jnp.where(taker_left, pending_y < 0.0, pending_y > 0.0).astype(
        jnp.asarray(pending_y).dtype)


def move_footsteps(state: RecoveryState, gait: GaitState, started, time_s,
                   command: WalkCommand, margin_s) -> tuple[RecoveryState, GaitState, jax.Array]:
    """The pending offset into the gait: while armed, the current step (about to lift, or in the
    air and landing more than margin_s from now) takes it in place of what it had taken, so
    while the trigger holds the footstep follows the capture point's deviation, once per
    period; a step that started takes nothing yet. A push's sideways side, when first seen,
    decides whether it is late (`late_push`); a late push's sideways offsets move the swing
    foot by command.recovery_late_swing_gain of its half. Returns (state, gait, whether the
    footstep moved)."""
    dtype = state.applied.dtype
    applied = jnp.where(started, 0.0, state.applied)
    in_reach = swing_in_reach(gait, time_s, command, margin_s)
    decide = (state.side_open > 0.5) & (state.side_now > 0.5)
    late = jnp.where(decide, late_push(state.pending[1], gait.swing_left, in_reach), state.late)
    take = (state.armed > 0.5) & in_reach
    target = jnp.where(take, step_offset(state, gait.swing_left), applied)
    swing_y = jnp.where(late > 0.5, jnp.asarray(command.recovery_late_swing_gain, dtype), 1.0)
    gait = move_footstep(gait, target - applied, swing_y)
    state = dataclasses.replace(
        state, applied=target.astype(dtype),
        armed=jnp.where(take, 0.0, state.armed).astype(state.armed.dtype),
        side_open=jnp.where(decide, 0.0, state.side_open).astype(dtype),
        late=jnp.asarray(late, dtype))
    return state, gait, take & jnp.any(target != applied)
