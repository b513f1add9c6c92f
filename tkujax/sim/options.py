"""What a closed-loop rollout simulates, and how its program is built.

  RolloutConfig   the physics: what changes the simulated result (duration, control period,
                  servo quantisation, the fixed-point controller, what is recorded);
  ProgramOptions  the program: how the same arithmetic is laid out for XLA (checkpointing,
                  scan unrolling, loop structure, tree passes) and the gradient window, which
                  changes gradients but never a forward value. It rides in
                  `RolloutConfig.program`;
  Episode         one robot's episode: its push, whether balance control is on, the sensor
                  noise key and levels, and an optional walk (a pytree: batch it by stacking).

Both configs are static (frozen, hashable: changing them recompiles) and check their values
when built: a ValueError names the field, the allowed values and the bad value.
"""

from __future__ import annotations

import dataclasses
import functools
import numbers

import jax

from tkujax.control.fixed import FixedPointConfig
from tkujax.control.gait import WalkCommand
from tkujax.sim.push import CONTROL_PERIOD_S, Push
from tkujax.sim.slope import Floor, check_floor_pitch, check_floor_roll

# jax.checkpoint (less memory under grad): False / "none": off; True / "tick": each control
# tick; "tick_nocse": the same with prevent_cse=False (JAX's advice inside scan); "tick_dots":
# each tick, saving the results of matrix products
# (jax.checkpoint_policies.dots_with_no_batch_dims_saveable); "substep": each physics substep
# instead; "nested": each tick and each substep.
REMAT_MODES = (False, True, "none", "tick", "tick_nocse", "tick_dots", "substep", "nested")
LOOPS = ("nested", "flat")
TREE_PASSES = ("mjx", "compact")


def _one_of(field: str, value, allowed) -> None:
    if value not in allowed:
        raise ValueError(f"ProgramOptions.{field} must be one of {allowed}, got {value!r}")


def _at_least_one(field: str, value) -> None:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
        raise ValueError(f"ProgramOptions.{field} must be an integer >= 1, got {value!r}")


@dataclasses.dataclass(frozen=True)
class ProgramOptions:
    """How the rollout's program is laid out. Every option but `gradient_window_ticks` keeps
    the arithmetic: the Series agree to float rounding (XLA fuses each layout differently)."""

    # jax.checkpoint of the tick and/or substep functions (REMAT_MODES; see `checkpoints`).
    remat: bool | str = False
    # lax.scan unrolling of the control-tick scan and of each tick's physics-substep scan
    # (1: a rolled loop); in the flat loop, unroll_substeps unrolls its scan over physics
    # steps and unroll_ticks is unused.
    unroll_ticks: int = 1
    unroll_substeps: int = 1
    # The loop structure (LOOPS): "nested", a scan over control ticks, each with a scan over
    # its physics substeps; "flat", one scan over physics steps, the control tick and the
    # Series row in `lax.cond`s on the step counter (not batched, so vmap keeps them branches;
    # remat's tick checkpoint then wraps the control tick alone). The sweeps run "flat"
    # (tkujax.sweeps.sweep.SWEEP_LOOP, with its XLA options: faster at batch 1,024 on a
    # GPU); gradients and `simulate` keep "nested".
    loop: str = "nested"
    # MJX's passes over the body tree inside each physics step (TREE_PASSES): "mjx", MJX's own
    # (`mjx.forward`); "compact", tkujax.sim.tree_passes: the kinematics, com_vel and rne with
    # MJX's formulas traced once for all bodies (MJX traces each per body group): one step's
    # program a third smaller, its gradient's 41 %; equal to float rounding. The tuner runs
    # "compact" (TUNE_TREE_PASSES); the sweeps keep "mjx", so their committed results replay
    # bit for bit on the same device.
    tree_passes: str = "mjx"
    # Truncated backpropagation (Brax APG's truncation_length): K, a stop_gradient on the
    # carried simulation state (MJX data, IMU filter state, controller state) at the start of
    # every K-th control tick (ticks 0, K, 2K, ...), so that gradients flow within windows of
    # K ticks only. Forward values are unchanged, bit for bit. None: off (no op in the program).
    gradient_window_ticks: int | None = None

    def __post_init__(self):
        _one_of("remat", self.remat, REMAT_MODES)
        _at_least_one("unroll_ticks", self.unroll_ticks)
        _at_least_one("unroll_substeps", self.unroll_substeps)
        _one_of("loop", self.loop, LOOPS)
        _one_of("tree_passes", self.tree_passes, TREE_PASSES)
        if self.gradient_window_ticks is not None:
            _at_least_one("gradient_window_ticks", self.gradient_window_ticks)


@dataclasses.dataclass(frozen=True)
class RolloutConfig:
    """What the rollout simulates (static: changing it recompiles)."""

    duration_s: float = 2.4
    control_period_s: float = CONTROL_PERIOD_S
    quantise_targets: bool = True
    record_qpos: bool = False      # add the full qpos to the series (for rendering)
    # The FPGA twin of the controller (tkujax.control.fixed); None: the float controller (its
    # program is unchanged by this field: the choice is a Python branch on None at trace time).
    fixed: FixedPointConfig | None = None
    # How the program is laid out (the same simulated result; see ProgramOptions).
    program: ProgramOptions = ProgramOptions()
    # The floor's pitch, deg (+ = uphill toward +x; tkujax.sim.slope), and its roll after it,
    # deg (+ = the floor rises toward +y): a tilted gravity. Both 0: the level floor, and the
    # program unchanged (a Python branch on the values).
    floor_pitch_deg: float = 0.0
    floor_roll_deg: float = 0.0

    def __post_init__(self):
        if not isinstance(self.program, ProgramOptions):
            raise ValueError(f"RolloutConfig.program must be a ProgramOptions, got "
                             f"{self.program!r}")
        check_floor_pitch(self.floor_pitch_deg)
        check_floor_roll(self.floor_roll_deg)

    @property
    def floor(self) -> Floor:
        """The floor of floor_pitch_deg and floor_roll_deg (tkujax.sim.slope.Floor)."""
        return Floor(self.floor_pitch_deg, self.floor_roll_deg)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Episode:
    """One robot's episode (every field traced; batch by stacking along a leading axis).

    push: the Push. enabled: 1 = balance control on, 0 = off. key: the PRNG key of the sensor
    noise. gyro_noise_std (rad/s), accel_noise_std (m/s^2): Gaussian noise on the IMU
    reading at each control tick. walk: a `tkujax.control.gait.WalkCommand` (the robot walks,
    `tkujax.control.walking`); None: it stands, and the program is the standing one (an empty
    subtree, a Python branch on None at trace time)."""

    push: Push
    enabled: jax.Array
    key: jax.Array
    gyro_noise_std: jax.Array = 0.0
    accel_noise_std: jax.Array = 0.0
    walk: WalkCommand | None = None


def checkpoints(remat: bool | str):
    """(wrap for the tick function, wrap for the substep function) of a ProgramOptions.remat."""
    _one_of("remat", remat, REMAT_MODES)
    same = lambda f: f   # noqa: E731
    if remat in (False, "none"):
        return same, same
    if remat in (True, "tick"):
        return jax.checkpoint, same
    if remat == "tick_nocse":
        return functools.partial(jax.checkpoint, prevent_cse=False), same
    if remat == "tick_dots":
        return functools.partial(
            jax.checkpoint, policy=jax.checkpoint_policies.dots_with_no_batch_dims_saveable), same
    if remat == "substep":
        return same, functools.partial(jax.checkpoint, prevent_cse=False)
    return jax.checkpoint, functools.partial(jax.checkpoint, prevent_cse=False)   # nested
