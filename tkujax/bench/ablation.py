"""The closed loop of the sweeps with parts replaced by trivial stand-ins, for the profile.

Built from the rollout's public pieces (`tkujax.sim.closed_loop.tick_pieces`, run by
`tkujax.sim.rollout_mjx.run_tick_pieces`), so the production rollout carries no ablation
switch. ABLATIONS, each a Python choice at trace time (the other parts' program unchanged):

  noise       no sensor-noise draws (the IMU reading as it is)
  controller  no controller: the legs hold the stand targets
  wrench      no push wrench computed per substep (xfrc_applied stays 0)
  records     no Series: the pelvis height per tick is the only output
"""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp

from tkujax.control.controller import ControllerOutput
from tkujax.sim import physics, tree_passes
from tkujax.sim.closed_loop import controller_tick, legs_slice, physics_substep, tick_pieces
from tkujax.sim.mjx_import import mjx
from tkujax.sim.options import Episode, RolloutConfig, checkpoints
from tkujax.sim.rollout_mjx import run_tick_pieces
from tkujax.sim.setup import ModelIndex

ABLATIONS = ("noise", "controller", "wrench", "records")


def _raw_imu(imu, key, episode):
    return imu


def _stand_control(idx: ModelIndex, imu, ctrl_state, key):
    """The controller's stand-in: the stand targets, a zero output."""
    dtype = imu[0].dtype
    stand = jnp.asarray(idx.stand_ctrl, dtype)
    zero = jnp.zeros((), dtype)
    out = ControllerOutput(stand[legs_slice(idx)], zero, zero, zero, zero, zero)
    return ctrl_state, stand, stand, out


def _pelvis_height(d, out, ctrl_state):
    return d.qpos[2]


def ablated_rollout(model: mjx.Model, state: mjx.Data, episode: Episode, params,
                    config: RolloutConfig, index: ModelIndex, ablate: tuple[str, ...]):
    """`rollout_mjx.rollout` (no override, no schedule) with the `ablate`d parts stood in for;
    returns the Series, or the pelvis height per tick with "records" ablated."""
    unknown = set(ablate) - set(ABLATIONS)
    if unknown:
        raise ValueError(f"ablate: unknown {sorted(unknown)}; allowed {ABLATIONS}")
    params = dataclasses.replace(params, control_period=config.control_period_s)
    pieces = tick_pieces(model, index, episode, params, config)
    if "wrench" in ablate:
        forward = (tree_passes.forward if config.program.tree_passes == "compact"
                   else mjx.forward)
        substep = functools.partial(physics_substep, physics.without_sensors(model), index,
                                    forward, None)
        pieces = dataclasses.replace(pieces, substep=checkpoints(config.program.remat)[1](substep))
    if "noise" in ablate:
        pieces = dataclasses.replace(pieces, control=functools.partial(
            controller_tick, index, episode, params, config, None, None, pieces.switch,
            _raw_imu))
    if "controller" in ablate:
        pieces = dataclasses.replace(pieces, control=functools.partial(_stand_control, index))
    if "records" in ablate:
        pieces = dataclasses.replace(pieces, record=_pelvis_height)
    return run_tick_pieces(pieces, state, episode, params, config, index)
