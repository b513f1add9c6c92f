"""The tuning loss of one rollout (fall, recovery, step terms; see the package docstring).

LossConfig.kind selects the fall term:
  "soft"    (default) softplus((fall_margin_m - margin) / fall_width_m) of a soft minimum over
            the whole horizon of the fall test's clearance: unbounded (about 10 once fallen).
  "margin"  the bounded DCM margin of tkujax.gradients.margin: sigmoid((m - offset_m) /
            scale_m) in (0, 1), m the soft maximum (temperature softmax_m) of the DCM's distance
            outside the feet's hull from the push onset to the first tick whose clearance is
            below 1 cm, or window_s after the onset. The recovery term is then averaged over the
            ticks after the onset up to that first low tick only (a survivor's: all of them, as
            with "soft"), so a fallen body adds neither value nor gradient after its fall. The
            step term is the same. Every per-push term is bounded.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from tkujax.sim.metrics import FALL_BODY_CLEARANCE_M, FALL_PELVIS_HEIGHT_M
from tkujax.gradients.margin import MarginConfig, clearance_m, margin_loss
from tkujax.studies.tune.reparam import DEG
from tkujax.dialects.validation import SpecError, number, table


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
    # The fall term (module docstring): "soft" or "margin" (then the four margin_* settings).
    kind: str = "soft"
    window_s: float = 0.4             # margin: the window's length after the onset
    offset_m: float = 0.02            # margin: the squash's centre
    scale_m: float = 0.02             # margin: the squash's width
    softmax_m: float = 0.005          # margin: the soft maximum's temperature over ticks

    def margin_config(self) -> MarginConfig:
        """The MarginConfig of kind "margin" (the default robot's soles)."""
        return MarginConfig(window_s=self.window_s, offset_m=self.offset_m,
                            scale_m=self.scale_m, softmax_m=self.softmax_m)


LOSS_FIELDS = {  # spec key: (lo, hi, unit)
    "w_fall": (0.0, 1e3, ""), "fall_margin_m": (0.0, 0.2, "m"), "fall_width_m": (1e-4, 0.1, "m"),
    "softmin_m": (1e-4, 0.05, "m"), "w_recovery": (0.0, 1e3, ""),
    "incl_ref_deg": (0.1, 45.0, "deg"), "w_step": (0.0, 1e3, ""), "step_ref_m": (1e-3, 1.0, "m"),
    "baseline_s": (0.03, 2.0, "s"), "w_harm": (0.0, 1e3, ""),
    "window_s": (0.03, 30.0, "s"), "offset_m": (-0.2, 0.5, "m"), "scale_m": (1e-3, 0.2, "m"),
    "softmax_m": (1e-4, 0.05, "m"),
}
LOSS_KINDS = ("soft", "margin")
# The per-push column (1.0 / 0.0) that says whether the push is survived with control off: a
# batch column of the tuning problem when w_harm > 0 (TuneProblem.with_off_survived).
OFF_SURVIVED = "off_survived"


def push_loss(series, onset_s, cfg: LossConfig) -> dict:
    """Loss terms of one rollout (a Series, fields (n_ticks, ...)); see the module docstring.
    kind is static (a Python branch at trace time: "soft" is the program it always was)."""
    if cfg.kind == "margin":
        return margin_push_loss(series, onset_s, cfg)
    recovery = _recovery(series, onset_s, series["t"] > onset_s, cfg)
    clearance = jnp.minimum(series["lowest_body_z"] - FALL_BODY_CLEARANCE_M,
                            series["pelvis_z"] - FALL_PELVIS_HEIGHT_M)
    s = cfg.softmin_m
    margin = -s * jax.nn.logsumexp(-clearance / s)
    fall = jax.nn.softplus((cfg.fall_margin_m - margin) / cfg.fall_width_m)
    step = _step(series, cfg)
    total = cfg.w_fall * fall + cfg.w_recovery * recovery + cfg.w_step * step
    return dict(total=total, fall=fall, recovery=recovery, step=step, margin_m=margin)


def _recovery(series, onset_s, after, cfg: LossConfig, guard: bool = False):
    """Mean of log1p(squared inclination change / incl_ref^2) over the ticks `after`, the
    inclination measured from its mean over the baseline_s before the onset. guard: the
    ticks outside `after` are zeroed before the log (the double `where`: a non-finite or
    huge tick there gives no gradient)."""
    t = series["t"]
    before = (t <= onset_s) & (t > onset_s - cfg.baseline_s)
    n_before = jnp.maximum(jnp.sum(before), 1)
    p0 = jnp.sum(jnp.where(before, series["pitch"], 0.0)) / n_before
    r0 = jnp.sum(jnp.where(before, series["roll"], 0.0)) / n_before
    ref = cfg.incl_ref_deg * DEG
    dev2 = ((series["pitch"] - p0) ** 2 + (series["roll"] - r0) ** 2) / ref ** 2
    if guard:
        dev2 = jnp.where(after, dev2, 0.0)
    return (jnp.sum(jnp.where(after, jnp.log1p(dev2), 0.0))
            / jnp.maximum(jnp.sum(after), 1))


def _step(series, cfg: LossConfig):
    delta = 1e-3
    return (jnp.sqrt(series["x_sup"][-1] ** 2 + series["y_sup"][-1] ** 2 + delta ** 2)
            - delta) / cfg.step_ref_m


def margin_push_loss(series, onset_s, cfg: LossConfig) -> dict:
    """Terms of kind "margin" (module docstring): fall = the squashed DCM margin in (0, 1),
    recovery over the ticks after the onset up to the first low-clearance tick."""
    mcfg = cfg.margin_config()
    m = margin_loss(series, onset_s, mcfg)
    low = clearance_m(series) < mcfg.stop_clearance_m
    after_fall = (jnp.cumsum(low) - low) > 0
    recovery = _recovery(series, onset_s, (series["t"] > onset_s) & ~after_fall, cfg,
                         guard=True)
    step = _step(series, cfg)
    total = cfg.w_fall * m["total"] + cfg.w_recovery * recovery + cfg.w_step * step
    return dict(total=total, fall=m["total"], recovery=recovery, step=step,
                margin_m=m["margin_m"])


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


def parse_loss(raw) -> LossConfig:
    """[tune.loss]: kind ("soft" | "margin") and the numbers of LOSS_FIELDS."""
    loss_raw = table("tune.loss", raw, set(LOSS_FIELDS) | {"kind"})
    kind = loss_raw.pop("kind", "soft")
    if kind not in LOSS_KINDS:
        raise SpecError(f"tune.loss.kind: expected one of {list(LOSS_KINDS)}, got {kind!r}")
    margin_keys = {"window_s", "offset_m", "scale_m", "softmax_m"} & set(loss_raw)
    if margin_keys and kind != "margin":
        raise SpecError(f"tune.loss.{sorted(margin_keys)[0]}: a setting of the margin loss; "
                        "set tune.loss.kind = \"margin\" or remove it")
    return LossConfig(kind=kind, **{k: number(f"tune.loss.{k}", v, *LOSS_FIELDS[k])
                                    for k, v in loss_raw.items()})
