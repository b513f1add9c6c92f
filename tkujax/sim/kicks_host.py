"""Velocity kicks (`tkujax.sim.push.Push.kick_mps`) on the MuJoCo C backend: the physics there
runs one control period at a time (`tkujax.sim.rollout_mujoco`), so each kick is added to the
base's velocity at the start of its period, the tick its onset lies on."""

from __future__ import annotations

import numpy as np

from tkujax.sim.push import Push


def kick_ticks(pushes: Push, n: int, n_ticks: int, period_s: float, dt: float):
    """(ticks, n, 2) the velocity kicks (Push.kick_mps) at each control period's start, as
    push.kick_velocity gives them at that time (None: no kicks). The physics here runs a
    period at a time, so a kick's onset must lie on the controller's tick grid (k x period_s)."""
    if pushes.kick_mps is None:
        return None
    onset = np.asarray(pushes.onset_s, np.float64)
    ticks = np.round(onset / period_s)
    if np.any(np.abs(onset - ticks * period_s) > 0.5 * dt):
        raise ValueError(f"velocity kicks (Push.kick_mps) act at a control tick on MuJoCo C: "
                         f"their onset_s must be multiples of {period_s} s, got {onset.ravel()}")
    kick = np.asarray(pushes.kick_mps, np.float64)
    az = np.asarray(pushes.azimuth_rad, np.float64)
    out = np.zeros((max(n_ticks, int(ticks.max()) + 1), n, 2))
    for idx in np.ndindex(onset.shape):   # (n,) or (n, pulses): each kick into its tick
        k = int(ticks[idx])
        out[k, idx[0]] += kick[idx] * np.array([np.cos(az[idx]), np.sin(az[idx])])
    return out
