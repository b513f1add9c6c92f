"""The tuning loss of one rollout (fall, recovery, step terms; see the package docstring)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from tkujax.sim.metrics import FALL_BODY_CLEARANCE_M, FALL_PELVIS_HEIGHT_M
from tkujax.studies.tune.reparam import DEG


@dataclasses.dataclass(frozen=True)
class LossConfig:
    w_fall: float = 1.0
    fall_margin_m: float = 0.02       # wanted clearance above the fall thresholds
    fall_width_m: float = 0.01        # softplus width
    softmin_m: float = 0.002          # temperature of the soft minimum over time
    w_recovery: float = 1.0
    incl_ref_deg: float = 5.0
    w_step: float = 0.1
    step_ref_m: float = 0.05
    baseline_s: float = 0.3           # pre-push window defining the standing inclination
    # "Harm nowhere": a push's loss counts (1 + w_harm) times when the robot survives
    # it with control OFF (`harm_weighted_mean`). 0: every push counts once (the program does
    # not change).
    w_harm: float = 0.0


LOSS_FIELDS = {  # spec key: (lo, hi, unit)
    "w_fall": (0.0, 1e3, ""), "fall_margin_m": (0.0, 0.2, "m"), "fall_width_m": (1e-4, 0.1, "m"),
    "softmin_m": (1e-4, 0.05, "m"), "w_recovery": (0.0, 1e3, ""),
    "incl_ref_deg": (0.1, 45.0, "deg"), "w_step": (0.0, 1e3, ""), "step_ref_m": (1e-3, 1.0, "m"),
    "baseline_s": (0.03, 2.0, "s"), "w_harm": (0.0, 1e3, ""),
}
# The per-push column (1.0 / 0.0) that says whether the push is survived with control off: a
# batch column of the tuning problem when w_harm > 0 (TuneProblem.with_off_survived).
OFF_SURVIVED = "off_survived"


def push_loss(series: dict, onset_s, cfg: LossConfig) -> dict:
    """Loss terms of one rollout (series fields (n_ticks, ...)); see the module docstring."""
    t = series["t"]
    before = (t <= onset_s) & (t > onset_s - cfg.baseline_s)
    after = t > onset_s
    n_before = jnp.maximum(jnp.sum(before), 1)
    p0 = jnp.sum(jnp.where(before, series["pitch"], 0.0)) / n_before
    r0 = jnp.sum(jnp.where(before, series["roll"], 0.0)) / n_before
    ref = cfg.incl_ref_deg * DEG
    dev2 = ((series["pitch"] - p0) ** 2 + (series["roll"] - r0) ** 2) / ref ** 2
    recovery = (jnp.sum(jnp.where(after, jnp.log1p(dev2), 0.0))
                / jnp.maximum(jnp.sum(after), 1))
    clearance = jnp.minimum(series["lowest_body_z"] - FALL_BODY_CLEARANCE_M,
                            series["pelvis_z"] - FALL_PELVIS_HEIGHT_M)
    s = cfg.softmin_m
    margin = -s * jax.nn.logsumexp(-clearance / s)
    fall = jax.nn.softplus((cfg.fall_margin_m - margin) / cfg.fall_width_m)
    delta = 1e-3
    step = (jnp.sqrt(series["x_sup"][-1] ** 2 + series["y_sup"][-1] ** 2 + delta ** 2)
            - delta) / cfg.step_ref_m
    total = cfg.w_fall * fall + cfg.w_recovery * recovery + cfg.w_step * step
    return dict(total=total, fall=fall, recovery=recovery, step=step, margin_m=margin)


def harm_weighted_mean(per_push, kept, off_survived=None, w_harm: float = 0.0):
    """The batch loss: the mean over the kept pushes (not diverged) of each push's loss, a push
    counting (1 + w_harm) times when control off survives it (off_survived 1.0), once otherwise.
    Divided by the number of kept pushes (not by the weights' sum): w_harm scales up the pushes
    where a controller can only do harm, it does not scale down the others.

    off_survived None (or w_harm 0, a static Python value): the plain mean, the same operations
    as before w_harm existed (the compiled program does not change)."""
    if off_survived is None or not w_harm:
        return jnp.sum(jnp.where(kept, per_push, 0.0)) / jnp.maximum(jnp.sum(kept), 1)
    weight = 1.0 + w_harm * off_survived
    return jnp.sum(jnp.where(kept, weight * per_push, 0.0)) / jnp.maximum(jnp.sum(kept), 1)
