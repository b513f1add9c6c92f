"""Hard-gate evaluation of tuned latents on held-out pushes and a grid."""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import numpy as np

from tkujax.control.params import ControllerParams
from tkujax.studies.tune.methods import _f
from tkujax.studies.tune.problem import TuneProblem


def evaluate(problem: TuneProblem, latents: dict[str, np.ndarray], heldout: dict,
             grid: dict, batch: int, seed: int) -> dict:
    """Hard-controller (gate_temperature = 0) evaluation of each named latent.

    Returns {name: dict(heldout_fall_rate, heldout_mean_recovery_s, heldout_recovered,
    heldout_loss, grid_fall_rate, max_impulse {azimuth_deg: N s}, per_push arrays)}."""
    from tkujax.studies.maps import max_recoverable_impulse

    key = jax.random.PRNGKey(seed)
    k_held, k_grid = jax.random.split(key)
    keys_held = jax.random.split(k_held, max(len(heldout["impulse_ns"]), 1))
    keys_grid = jax.random.split(k_grid, max(len(grid["impulse_ns"]), 1))
    result = {}
    for name, z in latents.items():
        r: dict[str, Any] = {}
        if len(heldout["impulse_ns"]):
            aux = problem.forward_padded(z, 0.0, heldout, keys_held, batch)
            # Diverged pushes are counted apart, never as fell or survived.
            div = aux["outcomes"]["diverged"].astype(bool)
            fell = aux["outcomes"]["fell"].astype(bool)[~div]
            rec_t = aux["outcomes"]["recovery_time_s"][~div]
            r.update(heldout_n=int(fell.size), heldout_diverged=int(div.sum()),
                     heldout_fall_rate=float(fell.mean()) if fell.size else None,
                     heldout_mean_recovery_s=_f(np.nanmean(rec_t)) if np.isfinite(rec_t).any()
                     else None,
                     heldout_recovered=int(np.isfinite(rec_t).sum()),
                     heldout_loss=float(np.mean(aux["terms"]["total"][~div])) if fell.size
                     else None,
                     heldout_push_loss=aux["terms"]["total"].tolist(),
                     heldout_fell=fell.tolist(),
                     heldout_terms={k: float(np.mean(aux["terms"][k]))
                                    for k in ("fall", "recovery", "step")})
        if len(grid["impulse_ns"]):
            aux = problem.forward_padded(z, 0.0, grid, keys_grid, batch)
            fell = aux["outcomes"]["fell"].astype(bool)
            div = aux["outcomes"]["diverged"].astype(bool)
            rec = dict(control=np.ones(fell.size, bool), azimuth_deg=grid["azimuth_deg"],
                       impulse_ns=grid["impulse_ns"], fell=fell, diverged=div)
            azs, jmax = max_recoverable_impulse(rec, True)
            r.update(grid_fall_rate=float(fell[~div].mean()) if (~div).any() else None,
                     grid_diverged=int(div.sum()),
                     max_impulse={f"{a:g}": float(j) for a, j in zip(azs, jmax)},
                     grid_fell=fell.tolist(),
                     grid_recovery_s=[_f(x) for x in aux["outcomes"]["recovery_time_s"]])
        result[name] = r
    return result


def params_json(params: ControllerParams) -> dict[str, float]:
    """{field: value} (SI, radians) of the hard controller, as load_params_json reads."""
    d = {k: float(v) for k, v in dataclasses.asdict(params).items()}
    d["gate_temperature"] = 0.0
    return d
