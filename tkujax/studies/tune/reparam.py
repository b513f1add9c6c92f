"""Tuned parameters and their reparameterisation: latent z <-> bounded ControllerParams
values (see the package docstring)."""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.dialects.validation import SpecError


DEG = math.pi / 180.0

# field: (spec key in user units, default range in user units, log scale, unit)
TUNABLE: dict[str, tuple[str, tuple[float, float], bool, str]] = {
    "step_period": ("step_period", (0.15, 0.6), False, "s"),
    "double_support_ratio": ("double_support_ratio", (0.0, 0.6), False, ""),
    "lift_height": ("lift_height", (0.005, 0.06), False, "m"),
    "eps_forward": ("eps_forward_deg", (8.0, 24.0), False, "deg"),
    "eps_backward": ("eps_backward_deg", (0.0, 12.0), False, "deg"),
    "cp_gain": ("cp_gain", (0.3, 2.5), False, ""),
    "kalman_q": ("kalman_q", (1e-6, 1e-2), True, "rad^2"),
    "kalman_r": ("kalman_r", (1e-4, 3e-2), True, "rad^2"),
    "eps_lateral": ("eps_lateral_deg", (1.0, 15.0), False, "deg"),
    "accel_gate": ("accel_gate", (0.05, 5.0), True, "m/s^2"),
    # Recovery extensions (ControllerParams docstring)
    "cp_rate_blend": ("cp_rate_blend", (0.0, 1.0), False, ""),
    "cp_lookahead_s": ("cp_lookahead_s", (0.0, 0.3), False, "s"),
    "cp_trigger_forward_m": ("cp_trigger_forward_m", (0.0, 0.12), False, "m"),
    "cp_trigger_backward_m": ("cp_trigger_backward_m", (0.0, 0.15), False, "m"),
    "cp_trigger_lateral_m": ("cp_trigger_lateral_m", (0.02, 0.15), False, "m"),
    "cp_gain_lateral": ("cp_gain_lateral", (-2.0, 1.5), False, ""),
    "step_shift_m": ("step_shift_m", (0.0, 0.1), False, "m"),
    "stance_ankle_kp": ("stance_ankle_kp", (-1.0, 3.0), False, "rad/rad"),
    "stance_ankle_kd": ("stance_ankle_kd", (-0.1, 0.3), False, "rad/(rad/s)"),
    "stance_hip_kp": ("stance_hip_kp", (-2.0, 2.0), False, "rad/rad"),
    "stance_hip_kd": ("stance_hip_kd", (-0.3, 0.3), False, "rad/(rad/s)"),
    "stance_roll_kp": ("stance_roll_kp", (-1.0, 3.0), False, "rad/rad"),
    "stance_roll_kd": ("stance_roll_kd", (-0.1, 0.3), False, "rad/(rad/s)"),
}
DEFAULT_RANGES = {f: v[1] for f, v in TUNABLE.items()}
# The paper's own tunable parameters; the other TUNABLE fields are the recovery extensions and
# the accelerometer gate, whose "off" values lie on their range bounds.
PAPER_TUNABLE = ("step_period", "double_support_ratio", "lift_height", "eps_forward",
                 "eps_backward", "cp_gain", "kalman_q", "kalman_r")
DEFAULT_TUNED = ("step_period", "double_support_ratio", "lift_height", "eps_forward",
                 "eps_backward")
# XLA options for the CPU backend: skipping LLVM's expensive passes cut the compile of the
# gradient (minutes on a 2-core CPU) by about a third here, and ran no slower. Not used on GPUs.
CPU_COMPILER_OPTIONS = {"xla_llvm_disable_expensive_passes": True}
# Outcome fields kept per push in evaluations.
EVAL_KEYS = ("fell", "diverged", "recovery_time_s", "peak_incl_deg", "capture_point_m",
             "step_length_m")


def user_factor(field: str) -> float:
    """SI value = user value * factor (degrees for the thresholds, else 1)."""
    return DEG if TUNABLE[field][0].endswith("_deg") else 1.0


@dataclasses.dataclass(frozen=True)
class Reparam:
    """Latent z (k,) <-> tuned ControllerParams values, each kept in [lo, hi] by a sigmoid.

    lo/hi are in SI units (radians for angles); for log fields the sigmoid interpolates
    log10(value). Any finite z (and +-inf) maps inside [lo, hi]: nothing is clipped after an
    optimiser step. The final clip only guards floating-point rounding at saturation.
    """

    fields: tuple[str, ...]
    lo: tuple[float, ...]
    hi: tuple[float, ...]
    log: tuple[bool, ...]

    @staticmethod
    def make(fields=DEFAULT_TUNED, ranges: dict[str, tuple[float, float]] | None = None
             ) -> Reparam:
        """From field names and ranges in user units (degrees for eps_*), default ranges."""
        ranges = {**DEFAULT_RANGES, **(ranges or {})}
        lo, hi, log = [], [], []
        for f in fields:
            if f not in TUNABLE:
                raise ValueError(f"cannot tune {f!r}; tunable: {sorted(TUNABLE)}")
            a, b = ranges[f]
            k = user_factor(f)
            lo.append(a * k)
            hi.append(b * k)
            log.append(TUNABLE[f][2])
        return Reparam(tuple(fields), tuple(lo), tuple(hi), tuple(log))

    @property
    def size(self) -> int:
        return len(self.fields)

    def _bounds(self, dtype):
        lo = np.array([math.log10(v) if g else v for v, g in zip(self.lo, self.log)])
        hi = np.array([math.log10(v) if g else v for v, g in zip(self.hi, self.log)])
        return jnp.asarray(lo, dtype), jnp.asarray(hi, dtype)

    def values(self, z: jax.Array) -> jax.Array:
        """(k,) SI values of the latent z (k,)."""
        z = jnp.asarray(z)
        dtype = jnp.result_type(z.dtype, float)
        lo, hi = self._bounds(dtype)
        u = jax.nn.sigmoid(z.astype(dtype))
        x = lo * (1.0 - u) + hi * u              # exact at u = 0 and u = 1
        x = jnp.where(jnp.asarray(self.log), jnp.power(10.0, x), x)
        vlo = jnp.asarray(self.lo, dtype)
        vhi = jnp.asarray(self.hi, dtype)
        return jnp.clip(x, vlo, vhi)             # rounding guard only (saturated sigmoid)

    def latent(self, values) -> np.ndarray:
        """Inverse of `values`: SI values strictly inside (lo, hi) -> z (float64 numpy)."""
        v = np.asarray(values, float)
        out = []
        for f, x, a, b, g in zip(self.fields, v, self.lo, self.hi, self.log):
            if not a < x < b:
                raise ValueError(f"{f} = {x!r} must lie strictly inside its tuning range "
                                 f"({a!r}, {b!r}) (SI units) to have a latent value")
            if g:
                x, a, b = math.log10(x), math.log10(a), math.log10(b)
            u = (x - a) / (b - a)
            out.append(math.log(u) - math.log1p(-u))
        return np.array(out)

    def apply(self, base: ControllerParams, z: jax.Array) -> ControllerParams:
        v = self.values(z)
        return dataclasses.replace(base, **{f: v[i] for i, f in enumerate(self.fields)})

    def latent_of(self, params: ControllerParams) -> np.ndarray:
        return self.latent([float(getattr(params, f)) for f in self.fields])

    def values_np(self, z) -> np.ndarray:
        """`values` in numpy float64 (for reports and JSON, independent of jax_enable_x64)."""
        z = np.asarray(z, float)
        lo = np.array([math.log10(v) if g else v for v, g in zip(self.lo, self.log)])
        hi = np.array([math.log10(v) if g else v for v, g in zip(self.hi, self.log)])
        u = 0.5 * (1.0 + np.tanh(0.5 * z))       # sigmoid without overflow
        x = lo * (1.0 - u) + hi * u
        x = np.where(np.asarray(self.log), 10.0 ** x, x)
        return np.clip(x, self.lo, self.hi)

    def params_np(self, base: ControllerParams, z) -> ControllerParams:
        v = self.values_np(z)
        return dataclasses.replace(base, **{f: float(v[i]) for i, f in enumerate(self.fields)})

    def user(self, z) -> dict[str, float]:
        """Values in user units (s, -, m, deg, rad^2), keyed by field."""
        v = self.values_np(z)
        return {f: float(x) / user_factor(f) for f, x in zip(self.fields, v)}

    def user_ranges(self) -> dict[str, tuple[float, float]]:
        return {f: (a / user_factor(f), b / user_factor(f))
                for f, a, b in zip(self.fields, self.lo, self.hi)}


def check_start(spec) -> None:
    """A TuneSpec's start values must lie strictly inside the ranges (their latents are finite)."""
    for f, (a, b) in spec.reparam().user_ranges().items():
        v = float(getattr(spec.start, f)) / user_factor(f)
        if not a < v < b:
            raise SpecError(f"{TUNABLE[f][0]}: start value {v:g} (from [controller], the paper "
                            f"or the robot) must lie strictly inside tune.ranges ({a:g}, {b:g})")
