"""Simulation: MJX/MuJoCo physics plumbing, pushes and the ball rig, the closed-loop tick, the
MJX and MuJoCo C rollouts, per-push metrics and the typed records they produce.

  physics.py         host/device models, the stand state, stepping helpers
  setup.py           init(model_params) -> SimSetup: the one set-up every simulation starts from
  randomize.py       the differentiable model randomisation (mass, CoM, friction, servos)
  push.py            the Push pytree (half-sine force at a chest height) and the paper's balls
  ball_rig.py        the paper's pendulum rig simulated with a real ball (impulse calibration)
  tick.py            the control half of a tick, shared by both backends
  recording.py       the per-tick recording shared by both backends (ZMP, lowest point, Series)
  options.py         RolloutConfig (physics), ProgramOptions (program layout), Episode
  closed_loop.py     the pieces of one MJX control tick (physics substep, controller, records)
  loops.py           the nested and flat loops that run those pieces
  rollout_mjx.py     rollout / batched_rollout / simulate on MJX (jit, vmap, grad)
  rollout_mujoco.py  simulate_mujoco: the same loop on MuJoCo C (CPU)
  metrics.py         outcomes of one rollout (fell, recovery time, step, ...)
  records.py         the typed records: Series, Outcomes
"""

from __future__ import annotations

from tkujax.sim.metrics import outcomes
from tkujax.sim.push import Push, ball_push, make_push, stack_pushes
from tkujax.sim.records import OUTCOME_FIELDS, SERIES_FIELDS, Outcomes, Series
from tkujax.sim.options import Episode, ProgramOptions, RolloutConfig
from tkujax.sim.rollout_mjx import batched_rollout, rollout, simulate

__all__ = ["OUTCOME_FIELDS", "SERIES_FIELDS", "Episode", "Outcomes", "ProgramOptions", "Push",
           "RolloutConfig", "Series",
           "ball_push", "batched_rollout", "make_push", "outcomes", "rollout", "simulate",
           "stack_pushes"]
