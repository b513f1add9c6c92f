"""Per-push gradients of two losses through MJX, for the first measurement
(scripts/gradient_first_measurement.py): the tuning loss (tkujax.studies.tune.loss.push_loss)
and the bounded margin loss (margin.margin_loss), both of one rollout, in a few scalar
controller parameters z (latent: field = base + scale * z).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.controller import with_timing_gradient
from tkujax.control.controller_params import ControllerParams
from tkujax.sim.push import Push
from tkujax.sim.rollout_mjx import Episode, ProgramOptions, RolloutConfig, rollout
from tkujax.sim.metrics import outcomes
from tkujax.sim.setup import init
from tkujax.gradients.margin import MarginConfig, margin_loss
from tkujax.studies.tune.loss import LossConfig, push_loss

# field: latent scale (a unit of z moves the field by this much).
SCALES = {"step_period": 0.03, "cp_gain": 0.3, "cp_trigger_forward_m": 0.01,
          "cp_trigger_backward_m": 0.03, "cp_trigger_lateral_m": 0.02, "stance_ankle_kp": 0.1,
          "stance_ankle_kd": 0.03, "stance_hip_kp": 0.1, "stance_roll_kp": 0.1,
          "lift_height": 0.01}
# Margin losses measured beside the tuning loss: the default squash (centred at 0 m), and one
# centred in the gap between survivors' (< 5 cm) and falls' (> 15 cm) margins that
# scripts/gradient_margin_auc.py found on held-out pushes.
# "margin_early": the window closed 0.4 s after the onset, where the margin is continuous across
# the fall boundary (survivors' up to ~3 cm, falls' from ~1 cm), squashed around 2 cm.
MARGINS = {"margin": MarginConfig(), "margin_gap": MarginConfig(offset_m=0.10, scale_m=0.04),
           "margin_early": MarginConfig(window_s=0.4, offset_m=0.02, scale_m=0.02)}


@dataclasses.dataclass(frozen=True)
class Latent:
    """Scalar fields of a base ControllerParams moved by base + scale * z."""

    base: ControllerParams
    names: tuple[str, ...] = tuple(SCALES)
    scales: tuple[float, ...] = tuple(SCALES.values())
    timing_gradient: bool = False

    def apply(self, z) -> ControllerParams:
        moved = {n: getattr(self.base, n) + s * z[i]
                 for i, (n, s) in enumerate(zip(self.names, self.scales))}
        p = dataclasses.replace(self.base, **moved)
        return with_timing_gradient(p) if self.timing_gradient else p

    def concrete(self, z) -> ControllerParams:
        """Concrete (float) params at z, validated, for MuJoCo C (plain ControllerParams)."""
        z = np.asarray(z, float)
        moved = {n: float(getattr(self.base, n) + s * z[i])
                 for i, (n, s) in enumerate(zip(self.names, self.scales))}
        return dataclasses.replace(self.base, **moved).validate()


def pushes_from(impulse_ns, azimuth_rad, onset_s, height_m=0.36, duration_s=0.02) -> Push:
    n = len(impulse_ns)
    f = lambda v: jnp.broadcast_to(jnp.asarray(v, jnp.float32), (n,))  # noqa: E731
    return Push(f(impulse_ns), f(azimuth_rad), f(height_m), f(duration_s), f(onset_s))


def loss_names(margins: tuple[str, ...]) -> tuple[str, ...]:
    """The order of make_per_push's losses."""
    return ("soft", *margins)


def make_per_push(latent: Latent, duration_s: float, margins: tuple[str, ...] = ("margin",),
                  loss_cfg: LossConfig = LossConfig()):
    """f(z, push, key) -> (losses [soft, *margins] (MARGINS' names), aux {fell, diverged,
    margin_m}) of one push with control on, no sensor noise; the tuner's rollout settings
    (remat per substep, compact tree passes)."""
    setup = init(None)
    config = RolloutConfig(duration_s=duration_s,
                           program=ProgramOptions(remat="substep", tree_passes="compact"))

    def f(z, push, key):
        series = rollout(setup.device_model, setup.stand_state, Episode(push, 1.0, key),
                         latent.apply(z), config, setup.index)
        soft = push_loss(series, push.onset_s, loss_cfg)["total"]
        ms = [margin_loss(series, push.onset_s, MARGINS[name]) for name in margins]
        out = outcomes(series, push.onset_s)
        aux = dict(fell=out.fell, diverged=out.diverged, margin_m=ms[0]["margin_m"])
        return jnp.stack([soft, *(m["total"] for m in ms)]), aux

    return f


def batch_functions(per_push, compiler_options=None):
    """(forward, jacobian): jitted over a batch of pushes (z shared). forward(z, pushes, keys)
    -> (losses (n, k), aux); jacobian(...) -> (n, k, d) per-push gradients of the k losses."""
    fwd = jax.jit(jax.vmap(per_push, in_axes=(None, 0, 0)), compiler_options=compiler_options)
    jac = jax.jit(jax.vmap(lambda z, p, k: jax.jacrev(lambda zz: per_push(zz, p, k)[0])(z),
                           in_axes=(None, 0, 0)), compiler_options=compiler_options)
    return fwd, jac
