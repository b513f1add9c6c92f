"""Typed records of a rollout: the per-period `Series` and the per-push `Outcomes`.

Both are frozen dataclasses registered as JAX pytrees (they go through jit, vmap, lax.scan and
tree_map unchanged), with units in the field names where a field has one. Sweeps write them as
columns with the same names: `columns()` gives {name: array}, and `record["name"]` reads one
column, so code that treats a record as a table keeps working.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

import jax


class Columns:
    """Column access shared by the records: rec["name"], iteration over the column names,
    keys(), items(), columns() (a read-only mapping view; attributes are the typed access)."""

    def __getitem__(self, name: str):
        if name not in self.keys():
            raise KeyError(f"{type(self).__name__} has no column {name!r}; columns: {self.keys()}")
        return getattr(self, name)

    def __iter__(self) -> Iterator[str]:
        return iter(self.keys())

    def __len__(self) -> int:
        return len(self.keys())

    def __contains__(self, name: str) -> bool:
        return name in self.keys()

    def keys(self) -> tuple[str, ...]:
        return tuple(f.name for f in dataclasses.fields(self) if getattr(self, f.name) is not None)

    def items(self) -> Iterator[tuple[str, Any]]:
        return ((k, getattr(self, k)) for k in self.keys())

    def columns(self) -> dict[str, Any]:
        return dict(self.items())


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Series(Columns):
    """One rollout sampled at the end of every control period (leading axes: [batch,] tick).

    t: time (s). pitch, roll: true pelvis inclination (rad). pitch_est, roll_est: the Kalman
    estimates (rad). zmp: sole sensors' centre of pressure, world (x, y) m. fsr_total: their
    total force (N). com: whole-body CoM (m). r_ankle, l_ankle: ankle sites (m). pelvis_z (m).
    lowest_body_z: lowest point of any non-foot collision geom (m). gate: detection gate.
    x_sup, y_sup: the latched step (m). step_weight: 0 before the step, 1 once triggered.
    reachable: the IK reached its target. qpos: the full state, only with record_qpos.
    touchdown_s: when the executed step lands (controller clock = sim time, s; ~1e4 before a
    step is triggered), for the capture-point-at-touchdown analysis.
    """

    t: jax.Array
    pitch: jax.Array
    roll: jax.Array
    pitch_est: jax.Array
    roll_est: jax.Array
    zmp: jax.Array
    fsr_total: jax.Array
    com: jax.Array
    r_ankle: jax.Array
    l_ankle: jax.Array
    pelvis_z: jax.Array
    lowest_body_z: jax.Array
    gate: jax.Array
    x_sup: jax.Array
    y_sup: jax.Array
    step_weight: jax.Array
    reachable: jax.Array
    qpos: jax.Array | None = None
    touchdown_s: jax.Array | None = None


SERIES_FIELDS = tuple(f.name for f in dataclasses.fields(Series))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Outcomes(Columns):
    """Per-push outcomes (definitions: tkujax.sim.metrics)."""

    fell: jax.Array
    recovery_time_s: jax.Array
    recovery_time_pitch_s: jax.Array
    step_length_m: jax.Array
    step_width_m: jax.Array
    peak_incl_deg: jax.Array
    zmp_excursion_m: jax.Array
    capture_point_m: jax.Array
    capture_point_y_m: jax.Array
    standing_pitch_deg: jax.Array
    diverged: jax.Array


OUTCOME_FIELDS = tuple(f.name for f in dataclasses.fields(Outcomes))
