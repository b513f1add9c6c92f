"""A set of robots of one structure that differ in their numbers (masses, foot geometry, servo
gains, ...), simulated by one compiled program: each rollout picks its robot by a traced index.

Each robot is compiled by MuJoCo itself (its own MJCF, `tkujax.model.load_model`) and settled
on its stand (`physics.settled_stand_data`), so every derived quantity (inertias, invweights,
bounding radii, the settled contact state) is MuJoCo's, not a hand-written scaling. The set
then keeps robot 0's device model and stand state, and per robot only the leaves that differ
from it, stacked along a leading robot axis. `model_of` / `state_of` put a robot's leaves back
into robot 0's trees inside a traced program.

Used by the batched MJX calibration (a CMA-ES generation of candidate robots in one call) and by
sweeps over an ensemble of plausible robots ([randomize] ensemble).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.model import ModelParams, load_model
from tkujax.sim import physics
from tkujax.sim.mjx_import import mjx
from tkujax.sim.setup import SETTLE_S, ModelIndex, index_of


class UnlistedFieldError(ValueError):
    """A field varies across the robots that the caller's program does not vary."""


@dataclasses.dataclass(frozen=True, eq=False)
class RobotSet:
    """R robots of one structure (see the module doc).

    model_leaf_ids / state_leaf_ids: positions in the flattened device model / stand state of
    the leaves that vary (static); model_values / state_values: those leaves, (R, ...) each,
    numpy (arguments of the compiled program, so a new set of robots of the same structure and
    size reuses it)."""

    model_params: tuple[ModelParams, ...]
    base_model: mjx.Model
    base_state: mjx.Data
    index: ModelIndex
    model_leaf_ids: tuple[int, ...]
    state_leaf_ids: tuple[int, ...]
    model_values: tuple[np.ndarray, ...]
    state_values: tuple[np.ndarray, ...]

    @property
    def n(self) -> int:
        return len(self.model_params)

    @property
    def structure(self) -> tuple:
        """What a compiled program depends on besides the values' shapes."""
        return (self.model_leaf_ids, self.state_leaf_ids)

    def values(self) -> tuple[tuple[jax.Array, ...], tuple[jax.Array, ...]]:
        """(model values, state values) as device arrays: the program's robot arguments."""
        return (tuple(jnp.asarray(v) for v in self.model_values),
                tuple(jnp.asarray(v) for v in self.state_values))


def _host_robot(mp: ModelParams, settle_s: float):
    host = load_model(mp)
    return host, physics.settled_stand_data(host, settle_s)


def _index_mismatch(a: ModelIndex, b: ModelIndex) -> str | None:
    for f in dataclasses.fields(ModelIndex):
        if not np.array_equal(np.asarray(getattr(a, f.name)), np.asarray(getattr(b, f.name))):
            return f.name
    return None


def robot_set(model_params: Sequence[ModelParams], settle_s: float = SETTLE_S,
              model_leaf_ids: tuple[int, ...] | None = None,
              state_leaf_ids: tuple[int, ...] | None = None) -> RobotSet:
    """The RobotSet of `model_params` (robot 0 is the base).

    model_leaf_ids / state_leaf_ids: the varying leaves, fixed by the caller so that another set
    compiles to the same program (`varying_leaves`); None: those that differ here. A leaf that
    differs but is not listed, or a robot whose static structure (MJCF tree, static indices)
    differs from robot 0's, is refused with the field named."""
    if not model_params:
        raise ValueError("robot_set needs at least one ModelParams")
    hosts = [_host_robot(mp, settle_s) for mp in model_params]
    index = index_of(hosts[0][0], model_params[0])
    for k, ((host, _), mp) in enumerate(zip(hosts[1:], model_params[1:]), 1):
        bad = _index_mismatch(index, index_of(host, mp))
        if bad is not None:
            raise ValueError(f"robot {k} differs from robot 0 in its static model index "
                             f"({bad}): it needs its own compiled program, not a RobotSet")
    models = [jax.tree_util.tree_leaves(mjx.put_model(h, device=jax.devices("cpu")[0]))
              for h, _ in hosts]
    states = [jax.tree_util.tree_leaves(mjx.put_data(h, d, device=jax.devices("cpu")[0]))
              for h, d in hosts]
    base_model = mjx.put_model(hosts[0][0], device=jax.local_devices()[0])
    base_state = mjx.put_data(hosts[0][0], hosts[0][1], device=jax.local_devices()[0])
    m_ids = _varying(models, model_leaf_ids, "model", base_model)
    s_ids = _varying(states, state_leaf_ids, "stand state", base_state)
    return RobotSet(
        model_params=tuple(model_params), base_model=base_model, base_state=base_state,
        index=index, model_leaf_ids=m_ids, state_leaf_ids=s_ids,
        model_values=tuple(np.stack([np.asarray(m[i]) for m in models]) for i in m_ids),
        state_values=tuple(np.stack([np.asarray(s[i]) for s in states]) for i in s_ids))


def _leaf_names(tree) -> list[str]:
    return [jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_flatten_with_path(tree)[0]]


def _varying(leaves: list[list], fixed: tuple[int, ...] | None, what: str, tree) -> tuple[int, ...]:
    n = len(leaves[0])
    if any(len(x) != n for x in leaves):
        raise ValueError(f"the robots' {what}s have different numbers of fields: not one "
                         "structure")
    differ = tuple(i for i in range(n)
                   if any(np.shape(x[i]) != np.shape(leaves[0][i])
                          or not np.array_equal(np.asarray(x[i]), np.asarray(leaves[0][i]))
                          for x in leaves[1:]))
    for i in differ:
        if any(np.shape(x[i]) != np.shape(leaves[0][i]) for x in leaves[1:]):
            raise ValueError(f"the robots' {what} field {_leaf_names(tree)[i]} changes shape: "
                             "not one structure")
    if fixed is None:
        return differ
    extra = sorted(set(differ) - set(fixed))
    if extra:
        names = _leaf_names(tree)
        raise UnlistedFieldError(f"{what} fields vary that the program does not vary: "
                         f"{', '.join(names[i] for i in extra)}")
    return tuple(fixed)


def varying_leaves(model_params: Sequence[ModelParams], settle_s: float = SETTLE_S
                   ) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The (model, state) leaves that vary across `model_params`: probe a family of robots once
    (for example its bounds' corners) and pass the result to every `robot_set` of that family,
    so they all share one compiled program."""
    rs = robot_set(model_params, settle_s)
    return rs.model_leaf_ids, rs.state_leaf_ids


def put_leaves(tree, ids: tuple[int, ...], values, robot_id):
    """`tree` with its leaves `ids` replaced by values[k][robot_id] (robot_id may be traced)."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    for i, v in zip(ids, values):
        leaves[i] = v[robot_id].astype(leaves[i].dtype)
    return jax.tree_util.tree_unflatten(treedef, leaves)


def model_of(robots: RobotSet, model_values, robot_id) -> mjx.Model:
    """Robot `robot_id`'s device model (robot_id may be traced; model_values from .values())."""
    return put_leaves(robots.base_model, robots.model_leaf_ids, model_values, robot_id)


def state_of(robots: RobotSet, state_values, robot_id) -> mjx.Data:
    """Robot `robot_id`'s settled stand state (robot_id may be traced)."""
    return put_leaves(robots.base_state, robots.state_leaf_ids, state_values, robot_id)
