"""Walking from the controller's own CPG: the recovery step of Eq. 11-18, repeated.

Each step is the paper's oscillator step (`cpg.unit_oscillators`: a double support of
gamma T / 2, a quarter sine in x and y during the swing, a half sine lift of the swing foot,
a double support of gamma T / 2), with walking amplitudes instead of Table 2's: relative to the
waist P_W the swing foot moves from where the last step left it to +d / 2 and the support foot
to -d / 2, where d = (speed_mps, lateral_mps) x step_period_s is the step: the distance between
successive footprints and the waist's travel per step. The first step from the stand is
exactly the paper's recovery step with x_Sup = d; every later one moves each foot by d relative
to the waist, so the body travels d per step and each foot 2 d per swing. With d = 0 it steps
in place. Sideways, the stance is 2 d_y + |d_y step| wide after the leading foot's step and
2 d_y - |d_y step| after the trailing foot's; the leading foot (the left one for
lateral_mps >= 0) swings first.

Three tkujax extensions of the paper's gait, on by default (`WalkCommand.for_params`):

- a lateral sway of the waist toward the support foot, sway_m sin(pi t / T) during each step,
  a third of d_y (without it TKU-X falls within 1.3 s stepping in place with a 4.5 cm lift,
  and within 2 s at 0.1 m/s with 3 cm; docs/walking.md);
- a ramp that grows the step over the first `ramp_steps` steps (4: TKU-X holds 0.35 m/s,
  without it 0.3 m/s);
- a heading hold: each step turns by -heading_gain x the heading error through the hip yaws
  (`advance`'s turn, `gait_yaws`; `walking.yaw_rate` integrates the heading from the gyro).
  Sideways at 0.1 m/s for 20 s TKU-X turns 21 deg without it, 1.3 deg with it; OP3 about
  200 deg and 2 deg (`tests/test_walk.py`: 8 s).

Gait phase: one gait cycle is two steps (left swing, right swing); `gait_phase` is 0 at the left
foot's touchdown (the end of a left swing, T - gamma T / 2 into it) and grows to 1 over 2 T.

Everything here is a pure function of traced values (the command's fields are pytree leaves:
one compiled program serves every speed); the step counter advances by `where`, and the turn
and the footstep offsets (`walk_recovery`, the recovery while walking) enter as arguments.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from tkujax.control.cpg import unit_oscillators
from tkujax.control.controller_params import ControllerParams

WALK_START_S = 0.3     # the stand is held this long before the first step (the filter settles)
SWAY_FRAC = 1.0 / 3.0  # the default sway, a fraction of d_y (docs/walking.md: the scan)
RAMP_STEPS = 4.0       # the default ramp (docs/walking.md: the speed range with and without)
BAND_FRAC = 0.07       # the default recovery band, a fraction of thigh + calf (walk_recovery)
HEADING_GAIN = 0.5     # the default heading hold: the share of the heading error turned per step
MAX_TURN_RAD = 0.1     # the most a step turns (5.7 deg)


# Each WalkCommand field's allowed range (`WalkCommand.validate`; the sweep spec's and the robot
# file's [walk] tables check theirs against these).
WALK_LIMITS = dict(speed_mps=(-1.0, 1.0), lateral_mps=(-0.5, 0.5), step_period_s=(0.1, 2.0),
                   lift_m=(0.0, 0.1), double_support_ratio=(0.0, 0.8), sway_m=(-0.25, 0.25),
                   start_s=(0.0, 100.0), ramp_steps=(0.0, 20.0), recovery=(0.0, 1.0),
                   recovery_band_m=(0.0, 0.5), recovery_forward_gain=(0.0, 2.0),
                   recovery_late_swing_gain=(0.0, 1.0), heading_gain=(0.0, 2.0),
                   recovery_hurry=(-0.8, 0.8), com_shift_m=(-0.1, 0.1))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class WalkCommand:
    """What the robot is told to walk (every field a traced leaf; batch by stacking).

    speed_mps: forward (+x) speed; lateral_mps: sideways speed (+y, left); step_period_s: T of
    one step (one foot's swing and the double supports around it); the step is (speed_mps,
    lateral_mps) x step_period_s. lift_m: the swing foot's lift H_Sup. double_support_ratio:
    gamma. sway_m: the waist's lateral sway toward the support foot (0: none, the paper's
    Table 2 amplitude). start_s: when the first step starts (controller clock). ramp_steps:
    the step grows linearly over this many steps (0: the full step from the first).
    recovery: 1 = the capture point moves the next footstep (`walk_recovery`), 0 = the nominal
    gait; recovery_band_m: how far the capture point must leave the undisturbed gait's for
    that; recovery_forward_gain: multiplies the footstep's forward move (a push from behind; 1:
    as far as backward, 0: forward moves off, for a robot that they harm: docs/walking.md);
    recovery_late_swing_gain: multiplies the swing foot's half of the sideways offset in the
    steps of a push first seen sideways while the foot that must step outward was not the one
    to step (`walk_recovery`: a late push; 1: centred like any step, 0: the support foot alone
    moves, for a robot that the late swing harms: docs/walking.md).
    recovery_hurry: the share of its remaining time that a step cuts once it has taken a
    recovery offset, until its touchdown (the phase modification of Adiwahono et al. 2013:
    the swing lands sooner and every later step comes sooner by as much; `hurry`); negative:
    time is added, the step slows; 0 (default): the timing stays nominal, the placement alone
    moves (docs/walking.md measures both: nominal timing falls least).
    com_shift_m: the waist's forward shift relative to the feet while walking (m; negative:
    backward), grown linearly over the ramp's time ((ramp_steps + 1) T from start_s): a robot
    file's default centres its stand's CoM over its support polygon (`tkujax.robot.walk_defaults`:
    Booster T1 stands with its CoM 2.8 cm ahead of the polygon's middle and falls forward
    walking at 0.05 m/s without the shift; docs/walking.md).
    heading_gain: each step turns by -heading_gain x the heading error (the yaw the
    controller integrates from the gyro since the start; at most MAX_TURN_RAD), with the hip
    yaws (`advance`'s turn); 0: the hip yaws stay 0. The defaults are TKU-X's
    (`for_params(ControllerParams.paper())`)."""

    speed_mps: jax.Array = 0.0
    lateral_mps: jax.Array = 0.0
    step_period_s: jax.Array = 0.3
    lift_m: jax.Array = 0.03
    double_support_ratio: jax.Array = 0.2
    sway_m: jax.Array = 0.015
    start_s: jax.Array = WALK_START_S
    ramp_steps: jax.Array = RAMP_STEPS
    recovery: jax.Array = 0.0
    recovery_band_m: jax.Array = 0.0154
    recovery_forward_gain: jax.Array = 1.0
    recovery_late_swing_gain: jax.Array = 1.0
    heading_gain: jax.Array = HEADING_GAIN
    recovery_hurry: jax.Array = 0.0
    com_shift_m: jax.Array = 0.0

    @classmethod
    def for_params(cls, params: ControllerParams, speed_mps: float = 0.0,
                   lateral_mps: float = 0.0, **fields) -> WalkCommand:
        """The robot's walk: step period, lift and gamma from its controller (T, H_Sup and
        gamma, scaled to the robot by `tkujax.robot.geometry.controller_params_for`), the sway
        SWAY_FRAC of its d_y, the recovery band BAND_FRAC of its thigh + calf, the rest of the
        fields as given (keyword) or their defaults."""
        base = dict(step_period_s=float(params.step_period), lift_m=float(params.lift_height),
                    double_support_ratio=float(params.double_support_ratio),
                    sway_m=SWAY_FRAC * float(params.hip_offset_y),
                    recovery_band_m=BAND_FRAC * float(params.thigh_length + params.calf_length))
        base.update(fields)
        return cls(speed_mps=float(speed_mps), lateral_mps=float(lateral_mps), **base)

    def validate(self) -> WalkCommand:
        """Check ranges on concrete values (outside jit); raises ValueError naming the field."""
        for name, (lo, hi) in WALK_LIMITS.items():
            v = float(getattr(self, name))
            if not lo <= v <= hi:       # also refuses NaN
                raise ValueError(f"WalkCommand.{name} must be in [{lo:g}, {hi:g}], got {v!r}")
        if float(self.recovery) not in (0.0, 1.0):
            raise ValueError(f"WalkCommand.recovery must be 0 or 1, got {self.recovery!r}")
        return self


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class GaitState:
    """count: the current step's index (-1 before the first); start_s: when it started;
    swing_left: 1 when the left foot swings in it; feet_from / feet_to: (4,) ankle
    displacements from the stand pose [x_right, y_right, x_left, y_left] (m, relative to the
    waist) at its start and its end; yaw_from / yaw_to: (2,) the feet's yaw relative to the
    waist [right, left] (rad, the hip yaws) at its start and its end; lead_s: how far the gait
    runs ahead of its nominal schedule (s), the time the hurried steps gained (`hurry`)."""

    count: jax.Array
    start_s: jax.Array
    swing_left: jax.Array
    feet_from: jax.Array
    feet_to: jax.Array
    yaw_from: jax.Array
    yaw_to: jax.Array
    lead_s: jax.Array


def gait_init(command: WalkCommand, dtype=jnp.float32) -> GaitState:
    """Before the first step: a step -1 that ends at start_s, the feet at the stand, its swing
    foot the one that does not lead (the first real step flips it)."""
    c = _as(command, dtype)
    first_left = c.lateral_mps >= 0.0
    return GaitState(count=jnp.asarray(-1.0, dtype), start_s=c.start_s - c.step_period_s,
                     swing_left=jnp.where(first_left, 0.0, 1.0).astype(dtype),
                     feet_from=jnp.zeros((4,), dtype), feet_to=jnp.zeros((4,), dtype),
                     yaw_from=jnp.zeros((2,), dtype), yaw_to=jnp.zeros((2,), dtype),
                     lead_s=jnp.zeros((), dtype))


def _as(command: WalkCommand, dtype) -> WalkCommand:
    return jax.tree_util.tree_map(lambda v: jnp.asarray(v, dtype), command)


def batch_walk(command: WalkCommand, n: int, dtype=jnp.float32) -> WalkCommand:
    """The command with every field broadcast to (n,) (one command for the batch, or already
    stacked along axis 0)."""
    return jax.tree_util.tree_map(lambda v: jnp.broadcast_to(jnp.asarray(v, dtype), (n,)),
                                  command)


def step_vector(command: WalkCommand, count) -> jax.Array:
    """(2,) the step d of step `count` (0, 1, ...): (speed, lateral) x T, grown linearly over the
    first ramp_steps steps ((count + 1) / (ramp_steps + 1) of it until then)."""
    ramp = jnp.minimum(1.0, (count + 1.0) / (command.ramp_steps + 1.0))
    return jnp.stack([command.speed_mps, command.lateral_mps], -1) * (
        command.step_period_s * ramp)[..., None]


def planned_feet(swing_left, d, offset) -> jax.Array:
    """(4,) where a step ends: the swing foot at +d / 2 + offset, the support foot at -d / 2
    (relative to the waist, from the stand pose), in [x_r, y_r, x_l, y_l] order."""
    swing = 0.5 * d + offset
    support = -0.5 * d
    return jnp.where(swing_left > 0.5, jnp.concatenate([support, swing], -1),
                     jnp.concatenate([swing, support], -1))


def advance(state: GaitState, time_s, command: WalkCommand, offset=(0.0, 0.0),
            turn=0.0) -> tuple[GaitState, jax.Array]:
    """The gait at controller time time_s: when the current step is over (time_s >= start + T)
    the next one starts at start + T (not at this tick: the period stays T exactly whatever the
    control period), the other foot swinging from where the last step left it to
    `planned_feet` with the footstep offset (2,) added to the swing foot, and turning: its
    swing foot to +turn / 2 and its support foot to -turn / 2 of yaw relative to the waist
    (rad; the waist turns by about turn over the step and the next). Returns (state, whether a
    step started at this tick)."""
    dtype = state.feet_to.dtype
    c = _as(command, dtype)
    due = time_s >= state.start_s + c.step_period_s
    count = state.count + 1.0
    swing_left = 1.0 - state.swing_left
    feet_to = planned_feet(swing_left, step_vector(c, count), jnp.asarray(offset, dtype))
    new = GaitState(count=jnp.where(due, count, state.count),
                    start_s=jnp.where(due, state.start_s + c.step_period_s, state.start_s),
                    swing_left=jnp.where(due, swing_left, state.swing_left),
                    feet_from=jnp.where(due, state.feet_to, state.feet_from),
                    feet_to=jnp.where(due, feet_to, state.feet_to),
                    yaw_from=jnp.where(due, state.yaw_to, state.yaw_from),
                    yaw_to=jnp.where(due, planned_yaws(swing_left, turn, dtype), state.yaw_to),
                    lead_s=state.lead_s)
    return new, due


def hurry(state: GaitState, time_s, command: WalkCommand, active, period_s) -> GaitState:
    """The gait one control period (period_s) on, hurried where `active` (0 or 1) and its
    swing foot has not landed yet: the step's clock runs 1 / (1 - recovery_hurry) times as
    fast, so its touchdown and every later step come sooner; the step's start moves back by
    the time gained, which lead_s accumulates. Inactive, or with recovery_hurry 0: unchanged."""
    dtype = state.start_s.dtype
    share = jnp.asarray(command.recovery_hurry, dtype)
    airborne = jnp.asarray(time_s, dtype) < touchdown_time(state, command)
    gain = jnp.where((jnp.asarray(active, dtype) > 0.5) & airborne & (share != 0.0),
                     jnp.asarray(period_s, dtype) * share / (1.0 - share), 0.0)
    return dataclasses.replace(state, start_s=(state.start_s - gain).astype(dtype),
                               lead_s=(state.lead_s + gain).astype(dtype))


def planned_yaws(swing_left, turn, dtype=jnp.float32) -> jax.Array:
    """(2,) [right, left] yaws a step ends at: the swing foot +turn / 2, the support -turn / 2."""
    half = 0.5 * jnp.asarray(turn, dtype)
    return jnp.where(swing_left > 0.5, jnp.stack([-half, half]),
                     jnp.stack([half, -half])).astype(dtype)


def gait_yaws(state: GaitState, time_s, command: WalkCommand, params: ControllerParams):
    """(yaw_right, yaw_left) of the gait at time_s (rad, relative to the waist): from yaw_from
    to yaw_to with the CPG's quarter sine, as the feet's x (`gait_feet`)."""
    dtype = state.yaw_to.dtype
    t_step = jnp.asarray(time_s, dtype) - state.start_s
    unit_x, _, _ = unit_oscillators(t_step, walk_params(params, _as(command, dtype)))
    yaw = state.yaw_from + (state.yaw_to - state.yaw_from) * unit_x
    return yaw[..., 0], yaw[..., 1]


def swing_in_reach(state: GaitState, time_s, command: WalkCommand, margin_s) -> jax.Array:
    """Whether the current step's swing foot can still be moved: a step has started and its
    touchdown (`touchdown_time`) is more than margin_s away."""
    return (state.count > -0.5) & (time_s < touchdown_time(state, command) - margin_s)


def move_footstep(state: GaitState, offset, swing_y=1.0) -> GaitState:
    """The current step lengthened by `offset` (2,): its swing foot lands offset / 2 further
    and its support foot ends offset / 2 further back, relative to the waist (the feet end
    offset further apart, centred on the waist: the body travels d + offset / 2 in this step
    and in the next, not d now and d + offset next). In the air the rest of the swing goes
    there (`gait_feet` interpolates from feet_from by the CPG's quarter sine). swing_y scales
    the swing foot's sideways half (1: centred; 0: the support foot alone moves, the feet end
    offset_y / 2 further apart and the body shifts offset_y / 2 sideways over the step)."""
    dtype = state.feet_to.dtype
    half = 0.5 * jnp.asarray(offset, dtype)
    swing = half * jnp.stack([jnp.ones((), dtype), jnp.asarray(swing_y, dtype)])
    add = jnp.where(state.swing_left > 0.5, jnp.concatenate([-half, swing], -1),
                    jnp.concatenate([swing, -half], -1))
    return dataclasses.replace(state, feet_to=state.feet_to + add)


def walk_params(params: ControllerParams, command: WalkCommand) -> ControllerParams:
    """params with the walk's step period and gamma (the CPG's T and gamma)."""
    return dataclasses.replace(params, step_period=command.step_period_s,
                               double_support_ratio=command.double_support_ratio)


def gait_feet(state: GaitState, time_s, command: WalkCommand, params: ControllerParams):
    """Ankle targets (p_right, p_left), each (3,) m relative to P_W in the level frame, of the
    gait at controller time time_s: both feet from feet_from to feet_to with the CPG's quarter
    sine (Eq. 13/16), the swing foot lifted by lift_m (Eq. 15/18), the sway added to both feet's
    y, the waist's forward shift com_shift_m (ramped, `shift_ramp`) taken off both feet's x.
    Before the first step: the stand."""
    dtype = state.feet_to.dtype
    c = _as(command, dtype)
    t_step = jnp.asarray(time_s, dtype) - state.start_s
    unit_x, _, unit_z = unit_oscillators(t_step, walk_params(params, c))
    walking = state.count > -0.5
    d = state.feet_from + (state.feet_to - state.feet_from) * unit_x
    lift = jnp.where(walking, c.lift_m * unit_z, 0.0)
    left_swings = state.swing_left > 0.5
    # The waist leans over the support foot: the feet move toward the swing side.
    side = jnp.where(left_swings, 1.0, -1.0)
    sway = jnp.where(walking, side * c.sway_m * jnp.sin(
        jnp.pi * jnp.clip(t_step / c.step_period_s, 0.0, 1.0)), 0.0)
    d_y, d_z = params.hip_offset_y, params.hip_to_ankle_z
    back = c.com_shift_m * shift_ramp(time_s, c)
    p_right = jnp.stack([d[..., 0] - back, -d_y + d[..., 1] + sway,
                         -d_z + jnp.where(left_swings, 0.0, lift)], -1)
    p_left = jnp.stack([d[..., 2] - back, d_y + d[..., 3] + sway,
                        -d_z + jnp.where(left_swings, lift, 0.0)], -1)
    return p_right.astype(dtype), p_left.astype(dtype)


def shift_ramp(time_s, command: WalkCommand):
    """The share of com_shift_m in place at time_s: 0 until start_s, then growing linearly to 1
    over the step ramp's time, (ramp_steps + 1) step periods (continuous: no jump in the feet)."""
    span = (command.ramp_steps + 1.0) * command.step_period_s
    return jnp.clip((time_s - command.start_s) / span, 0.0, 1.0)


def touchdown_time(state: GaitState, command: WalkCommand):
    """When the current step's swing foot lands (controller clock, s): start + T - gamma T / 2."""
    c = _as(command, state.start_s.dtype)
    return state.start_s + c.step_period_s * (1.0 - 0.5 * c.double_support_ratio)


def first_left_touchdown(command: WalkCommand):
    """The nominal time of the first left touchdown: the left foot swings in the first step
    when lateral_mps >= 0, else in the second."""
    T = command.step_period_s
    land = T * (1.0 - 0.5 * command.double_support_ratio)
    return command.start_s + jnp.where(command.lateral_mps >= 0.0, 0.0, T) + land


def gait_phase(time_s, command: WalkCommand):
    """The gait phase in [0, 1) at time_s: 0 at a left touchdown, 1/2 at a right one (the
    nominal schedule; before the first left touchdown it counts back from it)."""
    return jnp.mod((time_s - first_left_touchdown(command)) / (2.0 * command.step_period_s), 1.0)


def time_at_phase(phase, cycle, command: WalkCommand):
    """The controller time of `gait_phase` = phase in gait cycle `cycle` (0: the cycle that
    begins at the first left touchdown): the inverse of `gait_phase`."""
    return first_left_touchdown(command) + (cycle + phase) * 2.0 * command.step_period_s
