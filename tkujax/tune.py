"""`tkujax tune SPEC --out DIR`: tune the recovery step and the push detection with gradients
through the MJX rollout, then evaluate honestly against a gradient-free baseline.

Tuned (the spec's `tune.params` chooses; ControllerParams field names):
  step_period (T, s), double_support_ratio (gamma), lift_height (H_Sup, m), eps_forward and
  eps_backward (epsilon_1, epsilon_2, rad), and optionally cp_gain, kalman_q, kalman_r.

Reparameterisation (never clipped after a step): optax updates an unconstrained latent z per
parameter; the value is lo + (hi - lo) sigmoid(z) for linear parameters and
10^(log10 lo + (log10 hi - log10 lo) sigmoid(z)) for the Kalman variances. Default ranges
(`DEFAULT_RANGES`, user units; a spec's [tune.ranges] may narrow or move them within the
ControllerParams limits of tkujax.spec.CONTROLLER_FIELDS):
  step_period [0.15, 0.6] s, double_support_ratio [0, 0.6], lift_height [0.005, 0.06] m,
  eps_forward [8, 24] deg (absolute pitch; the robot stands at ~7 deg), eps_backward [0, 12] deg,
  cp_gain [0.3, 2.5], kalman_q [1e-6, 1e-2] rad^2 (log), kalman_r [1e-4, 3e-2] rad^2 (log).

Loss (mean over a fixed batch of pushes, all terms dimensionless; `LossConfig`):
  fall      softplus((fall_margin_m - m) / fall_width_m), m = soft minimum over time of the
            clearance above the fall thresholds of tkujax.metrics (lowest non-foot body point
            above 5 mm, pelvis above 0.12 m): ~0 while standing (m ~ 0.1 m), ~10 when fallen.
  recovery  time average after onset of log(1 + (deviation / incl_ref)^2), deviation = the true
            pelvis inclination (pitch and roll) from its pre-push value: the squared deviation
            integrated over time, saturating so a fallen push does not drown the batch.
  step      sqrt(x_Sup^2 + y_Sup^2 + 1 mm^2) / step_ref: a small cost on the step length.
  loss = w_fall fall + w_recovery recovery + w_step step.
The detection gate is soft during tuning: gate_temperature follows the spec's annealing
schedule (geometric or linear from start_deg to end_deg), so gradients reach eps_1/eps_2. The
step's start is still the discrete instant at which the step weight crosses 1/2 (see
tkujax.control.controller), so the gradient sees the step's length and shape, not its timing.

Gradient notes (checked against central finite differences in float64, tests/test_tune.py):
  - Servo quantisation (tkujax.sim) makes the leg targets piecewise constant in the parameters;
    its straight-through gradient is deliberate, so finite differences only agree with the
    gradient with `quantise_targets=False` (tune.quantise_targets, default true as in sweeps).
  - At the paper's T = 0.3 s, gamma = 0.2 the lift-off (gamma T / 2) and landing instants fall
    exactly on 30 ms control ticks, where the loss has a kink in T and gamma: the gradient there
    is one-sided.
  - jax.checkpoint (remat) on each control tick gives the same gradient (1e-14 relative) and is
    what makes 1,024 pushes x 1.5 s fit on one GPU (2.7 GiB peak vs 125 GiB requested without).

Optimiser: optax chain(clip_by_global_norm, adam) on the latents. A non-finite loss or gradient
is counted, logged in history.json and skipped: neither the latents nor Adam's moments change.

Evaluation (after tuning, always with the HARD controller, gate_temperature = 0): held-out
pushes drawn from the same distribution with another seed (never used for tuning), and a grid
of impulses x azimuths: fall rate, mean recovery time, max recoverable impulse per direction
(tkujax.maps.max_recoverable_impulse), hard loss, for the parameters before tuning, after
gradient tuning, and after the gradient-free baseline: a (1+1) evolution strategy with the 1/5
success rule over the same latents, evaluated with the same loss on the same training batch and
given the same number of simulated pushes (iterations x batch).

Writes history.json, params_before.json, params_after.json (and params_baseline.json) in the
format tkujax.sweep.load_params_json reads, loss_curve.png, evaluation.png, summary.md.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax
from mujoco import mjx

from tkujax import physics
from tkujax.control.params import ControllerParams
from tkujax.metrics import FALL_BODY_CLEARANCE_M, FALL_PELVIS_HEIGHT_M, outcomes
from tkujax.push import Push
from tkujax.sim import RolloutConfig, model_index, rollout
from tkujax.spec import (CONTROLLER_FIELDS, PUSH_FIELDS, RANDOMIZE_DEFAULTS, RANDOMIZE_FIELDS,
                         SpecError, _number, _table, _uniform, _values, parse_randomize,
                         read_toml)
from tkujax.sweep import controller_params_from, randomize_model

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
}
DEFAULT_RANGES = {f: v[1] for f, v in TUNABLE.items()}
DEFAULT_TUNED = ("step_period", "double_support_ratio", "lift_height", "eps_forward",
                 "eps_backward")
# XLA options for the CPU backend: skipping LLVM's expensive passes cut the compile of the
# gradient (minutes on a 2-core CPU) by about a third here, and ran no slower. Not used on GPUs.
CPU_COMPILER_OPTIONS = {"xla_llvm_disable_expensive_passes": True}
# Outcome fields kept per push in evaluations.
EVAL_KEYS = ("fell", "recovery_time_s", "peak_incl_deg", "capture_point_m", "step_length_m")


def _user_factor(field: str) -> float:
    """SI value = user value * factor (degrees for the thresholds, else 1)."""
    return DEG if TUNABLE[field][0].endswith("_deg") else 1.0


# ----------------------------------------------------------------------------------------------
# Reparameterisation
# ----------------------------------------------------------------------------------------------

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
             ) -> "Reparam":
        """From field names and ranges in user units (degrees for eps_*), default ranges."""
        ranges = {**DEFAULT_RANGES, **(ranges or {})}
        lo, hi, log = [], [], []
        for f in fields:
            if f not in TUNABLE:
                raise ValueError(f"cannot tune {f!r}; tunable: {sorted(TUNABLE)}")
            a, b = ranges[f]
            k = _user_factor(f)
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
        return {f: float(x) / _user_factor(f) for f, x in zip(self.fields, v)}

    def user_ranges(self) -> dict[str, tuple[float, float]]:
        return {f: (a / _user_factor(f), b / _user_factor(f))
                for f, a, b in zip(self.fields, self.lo, self.hi)}


# ----------------------------------------------------------------------------------------------
# Loss
# ----------------------------------------------------------------------------------------------

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


LOSS_FIELDS = {  # spec key: (lo, hi, unit)
    "w_fall": (0.0, 1e3, ""), "fall_margin_m": (0.0, 0.2, "m"), "fall_width_m": (1e-4, 0.1, "m"),
    "softmin_m": (1e-4, 0.05, "m"), "w_recovery": (0.0, 1e3, ""),
    "incl_ref_deg": (0.1, 45.0, "deg"), "w_step": (0.0, 1e3, ""), "step_ref_m": (1e-3, 1.0, "m"),
    "baseline_s": (0.03, 2.0, "s"),
}


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


# ----------------------------------------------------------------------------------------------
# The tuning problem: one compiled loss (and its gradient) per batch shape
# ----------------------------------------------------------------------------------------------

RECORD_KEYS = ("impulse_ns", "azimuth_deg", "height_m", "duration_s", "onset_s",
               *RANDOMIZE_FIELDS)


def _x64(enabled: bool):
    return jax.enable_x64(True) if enabled else contextlib.nullcontext()


class TuneProblem:
    """The differentiable loss of latents z over a batch of push records.

    All jitted functions are traced and called inside this problem's float64 context when
    `float64` is set (the MJX model and state are put on the device in float64 too).
    `loss(z, temperature, batch, keys)` -> (loss, aux); `value_and_grad` and `forward` are its
    jitted gradient and forward-only versions (one compile each per batch size).
    """

    def __init__(self, reparam: Reparam, base: ControllerParams, loss_cfg: LossConfig = LossConfig(),
                 duration_s: float = 1.2, remat: bool = True, float64: bool = False,
                 model_params=None, compiler_options: dict | None = None,
                 quantise_targets: bool = True):
        self.reparam, self.base, self.loss_cfg = reparam, base, loss_cfg
        self.float64 = float64
        self.config = RolloutConfig(duration_s=duration_s, remat=remat,
                                    quantise_targets=quantise_targets)
        host = physics.host_model(model_params)
        self.index = model_index(model_params)
        with _x64(float64):
            self.dtype = jnp.float64 if float64 else jnp.float32
            self.model = mjx.put_model(host) if float64 else physics.device_model(model_params)
            state = physics.stand_state(host, 1.0)
            if float64:
                # mjx.step returns some integer fields (contact geom ids) as int64 under x64
                # while put_data makes int32: match the step's output types for lax.scan.
                shapes = jax.eval_shape(mjx.step, self.model, state)
                state = jax.tree_util.tree_map(lambda x, s: jnp.asarray(x, s.dtype), state,
                                               shapes)
            self.state = state
        self.n_ticks = int(round(duration_s / self.config.control_period_s))
        self.steps_per_push = int(round(duration_s / host.opt.timestep))
        if compiler_options is None and jax.default_backend() == "cpu":
            compiler_options = CPU_COMPILER_OPTIONS
        opts = compiler_options or None
        self._vg = jax.jit(jax.value_and_grad(self.loss, has_aux=True), compiler_options=opts)
        self._fwd = jax.jit(self.loss, compiler_options=opts)

    def loss(self, z, temperature, batch: dict, keys):
        params = dataclasses.replace(self.reparam.apply(self.base, z),
                                     gate_temperature=temperature)
        idx, cfg = self.index, self.loss_cfg

        def one(rec, key):
            push = Push(rec["impulse_ns"], rec["azimuth_deg"] * DEG, rec["height_m"],
                        rec["duration_s"], rec["onset_s"])
            model = randomize_model(self.model, rec["link_mass_scale"],
                                    rec["torso_com_offset_x_m"], rec["floor_friction"],
                                    rec["servo_kp_scale"], idx.chest_body)
            series = rollout(model, self.state, push, params, 1.0, key, rec["gyro_noise_std"],
                             rec["accel_noise_std"], self.config, idx)
            out = outcomes(series, push.onset_s)
            return push_loss(series, push.onset_s, cfg), {k: out[k] for k in EVAL_KEYS}

        terms, outs = jax.vmap(one)(batch, keys)
        return jnp.mean(terms["total"]), dict(terms=terms, outcomes=outs)

    def _args(self, z, temperature, batch, keys):
        cast = lambda x: jnp.asarray(x, self.dtype)  # noqa: E731
        return (cast(z), cast(temperature), {k: cast(batch[k]) for k in RECORD_KEYS}, keys)

    def value_and_grad(self, z, temperature, batch, keys):
        """(loss, aux, grad) as numpy (float64), computed in this problem's precision."""
        with _x64(self.float64):
            (loss, aux), g = self._vg(*self._args(z, temperature, batch, keys))
            return _np(loss), _np(aux), _np(g)

    def forward(self, z, temperature, batch, keys):
        with _x64(self.float64):
            loss, aux = self._fwd(*self._args(z, temperature, batch, keys))
            return _np(loss), _np(aux)

    def forward_padded(self, z, temperature, records: dict, keys, batch: int) -> dict:
        """Forward over any number of records in chunks of `batch` (one compiled shape).
        Returns the per-push aux (terms and outcomes) for the records, numpy."""
        n = len(records["impulse_ns"])
        parts = []
        for lo in range(0, n, batch):
            sel = np.resize(np.arange(lo, min(lo + batch, n)), batch)
            chunk = {k: records[k][sel] for k in RECORD_KEYS}
            _, aux = self.forward(z, temperature, chunk, keys[sel])
            parts.append(jax.tree_util.tree_map(lambda x: x[:min(batch, n - lo)], aux))
        return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *parts)


def _np(tree):
    return jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64)
                                  if np.issubdtype(np.asarray(x).dtype, np.floating)
                                  else np.asarray(x), tree)


# ----------------------------------------------------------------------------------------------
# Optimisation and baseline
# ----------------------------------------------------------------------------------------------

def temperature_schedule(start_deg: float, end_deg: float, n: int,
                         kind: str = "geometric") -> np.ndarray:
    """(n,) gate temperatures in radians from start to end (anneals toward the hard gate)."""
    k = np.arange(n) / max(n - 1, 1)
    if kind == "geometric":
        deg = start_deg * (end_deg / start_deg) ** k
    elif kind == "linear":
        deg = start_deg + (end_deg - start_deg) * k
    else:
        raise ValueError(f"schedule must be 'geometric' or 'linear', got {kind!r}")
    return deg * DEG


def make_optimizer(learning_rate: float, clip_norm: float) -> optax.GradientTransformation:
    return optax.chain(optax.clip_by_global_norm(clip_norm), optax.adam(learning_rate))


StepFn = Callable[[np.ndarray, float], tuple[float, dict, np.ndarray]]


def optimise(step_fn: StepFn, z0, temperatures, optimizer: optax.GradientTransformation,
             reparam: Reparam | None = None, log: Callable[[str], None] | None = print,
             pushes_per_step: int = 0) -> tuple[np.ndarray, list[dict]]:
    """Gradient descent on latents. step_fn(z, temperature) -> (loss, aux, grad) (numpy).

    A non-finite loss or gradient is skipped: the latents and the optimiser state stay as they
    were; the iteration is recorded with skipped = True. Returns (final z, history rows)."""
    z = jnp.asarray(np.asarray(z0, float))
    opt_state = optimizer.init(z)

    @jax.jit
    def apply(z, opt_state, g):
        updates, opt_state = optimizer.update(g, opt_state, z)
        return optax.apply_updates(z, updates), opt_state

    history, n_skipped = [], 0
    t0 = time.perf_counter()
    for it, tau in enumerate(np.asarray(temperatures, float)):
        z_before = np.asarray(z, float)
        loss, aux, g = step_fn(z_before, float(tau))
        g = np.asarray(g, float)
        finite = bool(np.isfinite(loss) and np.all(np.isfinite(g)))
        gnorm = float(np.linalg.norm(g)) if finite else float("nan")
        if finite:
            z, opt_state = apply(z, opt_state, jnp.asarray(g, z.dtype))
        else:
            n_skipped += 1
        terms = aux.get("terms", {}) if isinstance(aux, dict) else {}
        row = dict(iteration=it, temperature_deg=float(tau) / DEG, loss=_f(loss),
                   terms={k: _f(np.mean(v)) for k, v in terms.items()},
                   grad_norm=gnorm, grad=[_f(x) for x in g], finite=finite, skipped=not finite,
                   n_nonfinite_grad=int(np.sum(~np.isfinite(g))), latent=z_before.tolist(),
                   wall_s=round(time.perf_counter() - t0, 3),
                   pushes_simulated=(it + 1) * pushes_per_step)
        if reparam is not None:
            row["params"] = reparam.user(z_before)
        history.append(row)
        if log:
            log(_progress_line(row, len(temperatures), reparam, n_skipped))
    return np.asarray(z, float), history


def _f(x) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def _progress_line(row: dict, n: int, reparam: Reparam | None, n_skipped: int) -> str:
    loss = "nan" if row["loss"] is None else f"{row['loss']:.4f}"
    terms = " ".join(f"{k} {v:.3g}" for k, v in row["terms"].items()
                     if k in ("fall", "recovery", "step") and v is not None)
    terms = f" ({terms})" if terms else ""
    text = (f"it {row['iteration'] + 1:3d}/{n}  tau {row['temperature_deg']:.2f} deg  loss {loss}"
            f"{terms}  |g| {row['grad_norm']:.3g}")
    if reparam is not None:
        text += "  " + _fmt_params(row["params"])
    if row["skipped"]:
        text += f"  SKIPPED: non-finite loss/gradient ({n_skipped} so far)"
    return text


def _fmt_params(user: dict) -> str:
    names = {"step_period": "T", "double_support_ratio": "gamma", "lift_height": "H",
             "eps_forward": "eps1", "eps_backward": "eps2", "cp_gain": "k_cp",
             "kalman_q": "q", "kalman_r": "r"}
    out = []
    for f, v in user.items():
        unit = TUNABLE[f][3]
        out.append(f"{names[f]} {v:.3g}{' ' + unit if unit and unit != 'rad^2' else ''}")
    return ", ".join(out)


def evolution_baseline(loss_fn: Callable[[np.ndarray], float], z0, n_evals: int,
                       sigma0: float = 0.5, seed: int = 0,
                       log: Callable[[str], None] | None = print,
                       pushes_per_eval: int = 0) -> tuple[np.ndarray, list[dict]]:
    """(1+1)-ES with the 1/5 success rule in latent space, n_evals loss evaluations in all
    (the first is the start point). Candidates z + sigma N(0, I) (jax.random); a candidate
    replaces the incumbent when its loss is lower (non-finite losses never do). Returns
    (best z, rows)."""
    key = jax.random.PRNGKey(seed)
    z = np.asarray(z0, float)
    best = float(loss_fn(z))
    best = best if math.isfinite(best) else math.inf
    sigma = sigma0
    rows = [dict(evaluation=0, loss=_f(best), best_loss=_f(best), sigma=sigma, accepted=True,
                 latent=z.tolist(), pushes_simulated=pushes_per_eval)]
    up, down = 1.5, 1.5 ** -0.25              # 1/5 rule: stationary at a 20% success rate
    for i in range(1, n_evals):
        key, sub = jax.random.split(key)
        cand = z + sigma * np.asarray(jax.random.normal(sub, z.shape), float)
        loss = float(loss_fn(cand))
        ok = math.isfinite(loss) and loss < best
        if ok:
            z, best, sigma = cand, loss, sigma * up
        else:
            sigma = sigma * down
        rows.append(dict(evaluation=i, loss=_f(loss), best_loss=_f(best), sigma=sigma,
                         accepted=ok, latent=cand.tolist(),
                         pushes_simulated=(i + 1) * pushes_per_eval))
        if log:
            log(f"es  {i + 1:3d}/{n_evals}  loss {loss:.4f}  best {best:.4f}  sigma {sigma:.3f}"
                f"{'  accepted' if ok else ''}")
    return z, rows


# ----------------------------------------------------------------------------------------------
# Spec
# ----------------------------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class TuneSpec:
    name: str
    seed: int
    iterations: int
    batch: int
    duration_s: float
    learning_rate: float
    clip_norm: float
    params: tuple[str, ...]
    ranges: dict[str, tuple[float, float]]
    float64: bool
    remat: bool
    quantise_targets: bool
    anneal: tuple[float, float, str]                 # start_deg, end_deg, schedule
    loss: LossConfig
    push: dict[str, Any]                             # field -> value | (lo, hi) | list
    azimuth_jitter_deg: float
    controller: dict[str, float]
    randomize: dict[str, Any]
    baseline_sigma: float
    baseline_seed: int
    baseline_temperature_deg: float
    eval_seed: int
    eval_n: int
    eval_impulse_ns: np.ndarray
    eval_azimuth_deg: np.ndarray
    eval_duration_s: float
    raw: dict

    def reparam(self) -> Reparam:
        return Reparam.make(self.params, self.ranges)

    def base_params(self) -> ControllerParams:
        return controller_params_from(ControllerParams.paper(), self.controller).validate()


TUNE_FIELDS = {"name": str, "description": str, "seed": int, "iterations": int, "batch": int,
               "duration_s": (int, float), "learning_rate": (int, float),
               "clip_norm": (int, float), "params": list, "float64": bool, "remat": bool,
               "quantise_targets": bool,
               "anneal": dict, "loss": dict, "ranges": dict}
TUNE_PUSH_FIELDS = set(PUSH_FIELDS) | {"azimuth_jitter_deg"}


def _int(key: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise SpecError(f"{key}: expected an integer in [{lo}, {hi}], got {value!r}")
    return value


def _bool(key: str, value) -> bool:
    if not isinstance(value, bool):
        raise SpecError(f"{key}: expected true or false, got {value!r}")
    return value


def parse_tune_spec(data: dict) -> TuneSpec:
    """Validate a parsed tune TOML document (SpecError names the key and the allowed range)."""
    _table("top level", data, {"tune", "push", "controller", "randomize", "baseline", "evaluate"})
    tune = _table("tune", data.get("tune", {}), TUNE_FIELDS)
    for k in ("name", "description"):
        if k in tune and not isinstance(tune[k], str):
            raise SpecError(f"tune.{k}: expected a string, got {tune[k]!r}")
    seed = _int("tune.seed", tune.get("seed", 0), 0, 2**31 - 1)
    iterations = _int("tune.iterations", tune.get("iterations", 50), 1, 100_000)
    batch = _int("tune.batch", tune.get("batch", 64), 1, 1_048_576)
    duration = _number("tune.duration_s", tune.get("duration_s", 1.5), 0.1, 30.0, "s")
    lr = _number("tune.learning_rate", tune.get("learning_rate", 0.05), 1e-6, 10.0)
    clip = _number("tune.clip_norm", tune.get("clip_norm", 1.0), 1e-6, 1e6)
    float64 = _bool("tune.float64", tune.get("float64", False))
    remat = _bool("tune.remat", tune.get("remat", True))
    quantise = _bool("tune.quantise_targets", tune.get("quantise_targets", True))
    params = tune.get("params", list(DEFAULT_TUNED))
    if (not isinstance(params, list) or not params or len(set(params)) != len(params)
            or any(p not in TUNABLE for p in params)):
        raise SpecError(f"tune.params: expected a non-empty list of distinct names from "
                        f"{sorted(TUNABLE)}, got {params!r}")

    ranges_raw = _table("tune.ranges", tune.get("ranges", {}), {TUNABLE[f][0] for f in TUNABLE})
    by_key = {TUNABLE[f][0]: f for f in TUNABLE}
    ranges = {}
    for key, value in ranges_raw.items():
        f = by_key[key]
        lo, hi, unit = CONTROLLER_FIELDS[key]
        if TUNABLE[f][2]:
            lo = max(lo, 1e-12)                       # log scale: strictly positive
        if not (isinstance(value, list) and len(value) == 2):
            raise SpecError(f"tune.ranges.{key}: expected [lo, hi] within [{lo}, {hi}] {unit}, "
                            f"got {value!r}")
        a = _number(f"tune.ranges.{key}[0]", value[0], lo, hi, unit)
        b = _number(f"tune.ranges.{key}[1]", value[1], lo, hi, unit)
        if not a < b:
            raise SpecError(f"tune.ranges.{key}: lower bound {a} must be below upper bound {b}")
        ranges[f] = (a, b)

    anneal = _table("tune.anneal", tune.get("anneal", {}), {"start_deg", "end_deg", "schedule"})
    start = _number("tune.anneal.start_deg", anneal.get("start_deg", 3.0), 1e-3, 30.0, "deg")
    end = _number("tune.anneal.end_deg", anneal.get("end_deg", 0.5), 1e-3, start, "deg")
    schedule = anneal.get("schedule", "geometric")
    if schedule not in ("geometric", "linear"):
        raise SpecError(f"tune.anneal.schedule: expected 'geometric' or 'linear', got {schedule!r}")

    loss_raw = _table("tune.loss", tune.get("loss", {}), LOSS_FIELDS)
    loss = LossConfig(**{k: _number(f"tune.loss.{k}", v, *LOSS_FIELDS[k])
                         for k, v in loss_raw.items()})

    push_raw = _table("push", data.get("push", {}), TUNE_PUSH_FIELDS)
    push = {}
    for k in PUSH_FIELDS:
        lo, hi, default, unit = PUSH_FIELDS[k]
        v = push_raw.get(k, default)
        key = f"push.{k}"
        if isinstance(v, dict):
            push[k] = _uniform(key, v, lo, hi, unit)
        elif isinstance(v, list):
            push[k] = [float(x) for x in _values(key, v, lo, hi, unit)]
        else:
            push[k] = _number(key, v, lo, hi, unit)
    jitter = _number("push.azimuth_jitter_deg", push_raw.get("azimuth_jitter_deg", 0.0),
                     0.0, 180.0, "deg")
    onset_hi = push["onset_s"][1] if isinstance(push["onset_s"], tuple) else max(
        np.atleast_1d(push["onset_s"]))
    if onset_hi + 0.03 >= duration:
        raise SpecError(f"push.onset_s: onsets up to {onset_hi} s leave no time after the push "
                        f"within tune.duration_s = {duration} s")

    ctrl_raw = _table("controller", data.get("controller", {}), CONTROLLER_FIELDS)
    controller = {k: _number(f"controller.{k}", v, *CONTROLLER_FIELDS[k])
                  for k, v in ctrl_raw.items()}
    randomize = parse_randomize(data)

    base = _table("baseline", data.get("baseline", {}), {"method", "sigma", "seed",
                                                         "gate_temperature_deg"})
    if base.get("method", "es") != "es":
        raise SpecError(f"baseline.method: expected 'es' ((1+1) evolution strategy), "
                        f"got {base['method']!r}")
    sigma = _number("baseline.sigma", base.get("sigma", 0.5), 1e-4, 10.0, "(latent units)")
    bseed = _int("baseline.seed", base.get("seed", seed), 0, 2**31 - 1)
    btemp = _number("baseline.gate_temperature_deg", base.get("gate_temperature_deg", end),
                    0.0, 30.0, "deg")

    ev = _table("evaluate", data.get("evaluate", {}), {"seed", "n", "impulse_ns", "azimuth_deg",
                                                      "duration_s"})
    eseed = _int("evaluate.seed", ev.get("seed", seed + 1), 0, 2**31 - 1)
    if eseed == seed:
        raise SpecError(f"evaluate.seed: must differ from tune.seed ({seed}): held-out pushes "
                        "are never used for tuning")
    en = _int("evaluate.n", ev.get("n", 4 * batch), 0, 10_000_000)
    ej = _values("evaluate.impulse_ns", ev.get("impulse_ns", {"start": 0.2, "stop": 2.4,
                                                              "num": 12}),
                 *PUSH_FIELDS["impulse_ns"][:2], "N·s")
    ea = _values("evaluate.azimuth_deg", ev.get("azimuth_deg", [0.0, 180.0]),
                 *PUSH_FIELDS["azimuth_deg"][:2], "deg")
    edur = _number("evaluate.duration_s", ev.get("duration_s", duration), 0.1, 30.0, "s")

    spec = TuneSpec(name=tune.get("name", "tune"), seed=seed, iterations=iterations, batch=batch,
                    duration_s=duration, learning_rate=lr, clip_norm=clip, params=tuple(params),
                    ranges=ranges, float64=float64, remat=remat,
                    quantise_targets=quantise, anneal=(start, end, schedule),
                    loss=loss, push=push, azimuth_jitter_deg=jitter, controller=controller,
                    randomize=randomize, baseline_sigma=sigma, baseline_seed=bseed,
                    baseline_temperature_deg=btemp, eval_seed=eseed, eval_n=en,
                    eval_impulse_ns=ej, eval_azimuth_deg=ea, eval_duration_s=edur, raw=data)
    # Start values must lie strictly inside the ranges (their latents are finite).
    rep, start_params = spec.reparam(), spec.base_params()
    for f, (a, b) in rep.user_ranges().items():
        v = float(getattr(start_params, f)) / _user_factor(f)
        if not a < v < b:
            raise SpecError(f"{TUNABLE[f][0]}: start value {v:g} (from [controller] or the "
                            f"paper) must lie strictly inside tune.ranges ({a:g}, {b:g})")
    return spec


def load_tune_spec(path: str | Path) -> TuneSpec:
    return parse_tune_spec(read_toml(path))


def sample_pushes(spec: TuneSpec, n: int, seed: int) -> dict[str, np.ndarray]:
    """n push records (RECORD_KEYS columns) from the spec's distribution, seeded."""
    rng = np.random.default_rng(seed)
    out = {}
    for k in PUSH_FIELDS:
        v = spec.push[k]
        if isinstance(v, tuple):
            out[k] = rng.uniform(v[0], v[1], n)
        elif isinstance(v, list):
            out[k] = np.resize(np.array(v, float), n)       # cycled: balanced directions
        else:
            out[k] = np.full(n, v)
    if spec.azimuth_jitter_deg > 0:
        out["azimuth_deg"] = out["azimuth_deg"] + rng.uniform(-spec.azimuth_jitter_deg,
                                                              spec.azimuth_jitter_deg, n)
    return _with_randomize(out, spec, rng, n)


def grid_pushes(spec: TuneSpec) -> dict[str, np.ndarray]:
    """The evaluation grid: impulses x azimuths, other push fields at their mid values."""
    J, A = np.meshgrid(spec.eval_impulse_ns, spec.eval_azimuth_deg, indexing="ij")
    n = J.size
    out = dict(impulse_ns=J.ravel(), azimuth_deg=A.ravel())
    for k in ("height_m", "duration_s", "onset_s"):
        v = spec.push[k]
        mid = (0.5 * (v[0] + v[1]) if isinstance(v, tuple)
               else float(np.mean(v)) if isinstance(v, list) else v)
        out[k] = np.full(n, mid)
    # The grid uses the nominal model (no randomisation) and no sensor noise.
    return _with_randomize(out, None, None, n)


def _with_randomize(out: dict, spec: TuneSpec | None, rng, n: int) -> dict[str, np.ndarray]:
    rand = spec.randomize if spec is not None else {}
    for k, default in RANDOMIZE_DEFAULTS.items():
        v = rand.get(k)
        if isinstance(v, tuple):
            out[k] = rng.uniform(v[0], v[1], n)
        elif v is not None:
            out[k] = np.full(n, v)
        else:
            out[k] = np.full(n, -1.0 if default is None else default)  # friction -1: model's
    return {k: np.asarray(out[k], float) for k in RECORD_KEYS}


# ----------------------------------------------------------------------------------------------
# Evaluation
# ----------------------------------------------------------------------------------------------

def evaluate(problem: TuneProblem, latents: dict[str, np.ndarray], heldout: dict,
             grid: dict, batch: int, seed: int) -> dict:
    """Hard-controller (gate_temperature = 0) evaluation of each named latent.

    Returns {name: dict(heldout_fall_rate, heldout_mean_recovery_s, heldout_recovered,
    heldout_loss, grid_fall_rate, max_impulse {azimuth_deg: N s}, per_push arrays)}."""
    from tkujax.maps import max_recoverable_impulse

    key = jax.random.PRNGKey(seed)
    k_held, k_grid = jax.random.split(key)
    keys_held = jax.random.split(k_held, max(len(heldout["impulse_ns"]), 1))
    keys_grid = jax.random.split(k_grid, max(len(grid["impulse_ns"]), 1))
    result = {}
    for name, z in latents.items():
        r: dict[str, Any] = {}
        if len(heldout["impulse_ns"]):
            aux = problem.forward_padded(z, 0.0, heldout, keys_held, batch)
            fell = aux["outcomes"]["fell"].astype(bool)
            rec_t = aux["outcomes"]["recovery_time_s"]
            r.update(heldout_n=int(fell.size), heldout_fall_rate=float(fell.mean()),
                     heldout_mean_recovery_s=_f(np.nanmean(rec_t)) if np.isfinite(rec_t).any()
                     else None,
                     heldout_recovered=int(np.isfinite(rec_t).sum()),
                     heldout_loss=float(np.mean(aux["terms"]["total"])),
                     heldout_push_loss=aux["terms"]["total"].tolist(),
                     heldout_fell=fell.tolist(),
                     heldout_terms={k: float(np.mean(aux["terms"][k]))
                                    for k in ("fall", "recovery", "step")})
        if len(grid["impulse_ns"]):
            aux = problem.forward_padded(z, 0.0, grid, keys_grid, batch)
            fell = aux["outcomes"]["fell"].astype(bool)
            rec = dict(control=np.ones(fell.size, bool), azimuth_deg=grid["azimuth_deg"],
                       impulse_ns=grid["impulse_ns"], fell=fell)
            azs, jmax = max_recoverable_impulse(rec, True)
            r.update(grid_fall_rate=float(fell.mean()),
                     max_impulse={f"{a:g}": float(j) for a, j in zip(azs, jmax)},
                     grid_fell=fell.tolist(),
                     grid_recovery_s=[_f(x) for x in aux["outcomes"]["recovery_time_s"]])
        result[name] = r
    return result


# ----------------------------------------------------------------------------------------------
# run_tune
# ----------------------------------------------------------------------------------------------

def params_json(params: ControllerParams) -> dict[str, float]:
    """{field: value} (SI, radians) of the hard controller, as load_params_json reads."""
    d = {k: float(v) for k, v in dataclasses.asdict(params).items()}
    d["gate_temperature"] = 0.0
    return d


def run_tune(spec: TuneSpec | dict | str | Path, out_dir: str | Path, quiet: bool = False,
             iterations: int | None = None, compiler_options: dict | None = None,
             baseline: bool = True, evaluation: bool = True) -> dict:
    """Tune, run the baseline, evaluate, and write the outputs into out_dir. Returns a summary.

    spec: a TuneSpec, a parsed TOML dict, or a path. iterations overrides the spec's count.
    """
    if isinstance(spec, dict):
        spec = parse_tune_spec(spec)
    elif not isinstance(spec, TuneSpec):
        spec = load_tune_spec(spec)
    if iterations is not None:
        spec = dataclasses.replace(spec, iterations=int(iterations))
    with _x64(spec.float64):       # the optimiser's latents in the problem's precision too
        return _run_tune(spec, Path(out_dir), quiet, compiler_options, baseline, evaluation)


def _run_tune(spec: TuneSpec, out: Path, quiet: bool, compiler_options: dict | None,
              baseline: bool, evaluation: bool) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    log = (lambda s: None) if quiet else (lambda s: print(s, file=sys.stderr, flush=True))
    t_start = time.perf_counter()

    reparam, base = spec.reparam(), spec.base_params()
    z0 = reparam.latent_of(base)
    problem = TuneProblem(reparam, base, spec.loss, spec.duration_s, spec.remat, spec.float64,
                          compiler_options=compiler_options,
                          quantise_targets=spec.quantise_targets)
    train = sample_pushes(spec, spec.batch, spec.seed)
    train_keys = jax.random.split(jax.random.PRNGKey(spec.seed), spec.batch)
    temps = temperature_schedule(*spec.anneal[:2], spec.iterations, spec.anneal[2])
    log(f"tune {spec.name}: {spec.batch} pushes x {spec.duration_s} s, {spec.iterations} "
        f"iterations, tuning {', '.join(reparam.fields)}; float64={spec.float64}, "
        f"remat={spec.remat}. Compiling the gradient (minutes on a CPU) ...")

    # 1. Gradient descent.
    t0 = time.perf_counter()
    step_fn = lambda z, tau: problem.value_and_grad(z, tau, train, train_keys)  # noqa: E731
    z_grad, history = optimise(step_fn, z0, temps, make_optimizer(spec.learning_rate,
                                                                   spec.clip_norm),
                               reparam, log, pushes_per_step=spec.batch)
    grad_wall = time.perf_counter() - t0
    compile_note = history[0]["wall_s"] if history else None

    # 2. Gradient-free baseline, same loss (at a fixed temperature), same pushes simulated.
    tau_b = spec.baseline_temperature_deg * DEG
    es_rows, z_es, es_wall = [], None, 0.0
    if baseline:
        log(f"baseline: (1+1)-ES, {spec.iterations} evaluations x {spec.batch} pushes at "
            f"gate temperature {spec.baseline_temperature_deg:g} deg ...")
        t0 = time.perf_counter()
        es_loss = lambda z: problem.forward(z, tau_b, train, train_keys)[0]  # noqa: E731
        z_es, es_rows = evolution_baseline(es_loss, z0, spec.iterations, spec.baseline_sigma,
                                           spec.baseline_seed, log, spec.batch)
        es_wall = time.perf_counter() - t0

    # 3. Same-objective comparison on the training batch: final soft temperature and hard.
    cands = {"before": z0, "gradient": z_grad} | ({"baseline": z_es} if z_es is not None else {})
    train_loss = {}
    for name, z in cands.items():
        soft = problem.forward(z, temps[-1], train, train_keys)[0]
        hard = problem.forward(z, 0.0, train, train_keys)[0]
        es_t = (None if not baseline else soft if math.isclose(tau_b, temps[-1])
                else problem.forward(z, tau_b, train, train_keys)[0])
        train_loss[name] = dict(final_temperature=_f(soft), hard=_f(hard), baseline_temperature=
                                _f(es_t) if es_t is not None else None)

    # 4. Honest evaluation: held-out pushes (another seed), hard controller.
    evals = {}
    if evaluation:
        log(f"evaluating (hard gate) on {spec.eval_n} held-out pushes (seed {spec.eval_seed}) "
            f"and a {len(spec.eval_impulse_ns)} x {len(spec.eval_azimuth_deg)} grid ...")
        eval_problem = problem if spec.eval_duration_s == spec.duration_s else TuneProblem(
            reparam, base, spec.loss, spec.eval_duration_s, False, spec.float64,
            compiler_options=compiler_options, quantise_targets=spec.quantise_targets)
        heldout = sample_pushes(spec, spec.eval_n, spec.eval_seed)
        evals = evaluate(eval_problem, cands, heldout, grid_pushes(spec), spec.batch,
                         spec.eval_seed)

    # 5. Outputs.
    params = {name: reparam.params_np(base, z) for name, z in cands.items()}
    for name, fname in (("before", "params_before.json"), ("gradient", "params_after.json"),
                        ("baseline", "params_baseline.json")):
        if name in params:
            (out / fname).write_text(json.dumps(params_json(params[name].validate()), indent=1))
    n_skipped = sum(r["skipped"] for r in history)
    record = dict(
        name=spec.name, spec=spec.raw, tuned=list(reparam.fields),
        ranges_user_units=reparam.user_ranges(), batch=spec.batch, duration_s=spec.duration_s,
        iterations=spec.iterations, float64=spec.float64, remat=spec.remat,
        temperatures_deg=(temps / DEG).tolist(), history=history,
        skipped_steps=[r["iteration"] for r in history if r["skipped"]], n_skipped=n_skipped,
        baseline=dict(method="(1+1)-ES, 1/5 rule", sigma0=spec.baseline_sigma,
                      gate_temperature_deg=spec.baseline_temperature_deg, rows=es_rows,
                      wall_s=round(es_wall, 2)),
        pushes_simulated=dict(gradient=spec.iterations * spec.batch,
                              baseline=len(es_rows) * spec.batch),
        params_user={n: reparam.user(z) for n, z in cands.items()},
        latents={n: np.asarray(z).tolist() for n, z in cands.items()},
        train_loss=train_loss, evaluation=evals,
        wall_s=dict(gradient=round(grad_wall, 2), first_iteration_incl_compile=compile_note,
                    baseline=round(es_wall, 2), total=round(time.perf_counter() - t_start, 2)),
        devices=[str(d) for d in jax.devices()])
    (out / "history.json").write_text(json.dumps(record, indent=1, default=_json_default))
    _plot(out, record)
    (out / "summary.md").write_text(summary_markdown(record))
    log(f"wrote {out}/summary.md")
    return record


def _json_default(x):
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    return str(x)


def _plot(out: Path, rec: dict) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    hist = rec["history"]
    it_pushes = [r["pushes_simulated"] for r in hist]
    fig, axes = plt.subplots(1, 2, figsize=(11, 5))
    ax = axes[0]
    ax.plot(it_pushes, [np.nan if r["loss"] is None else r["loss"] for r in hist], "o-",
            label="gradient (Adam): loss at the current gate temperature")
    skipped = [r for r in hist if r["skipped"]]
    if skipped:
        ax.plot([r["pushes_simulated"] for r in skipped], [0] * len(skipped), "rx", ms=9,
                label="skipped (non-finite gradient)")
    es = rec["baseline"]["rows"]
    if es:
        ax.plot([r["pushes_simulated"] for r in es],
                [np.nan if r["best_loss"] is None else r["best_loss"] for r in es], "s-",
                label=f"(1+1)-ES best loss (tau {rec['baseline']['gate_temperature_deg']:g} deg)")
    tl = rec["train_loss"]
    for name, style in (("before", "k:"), ("gradient", "C0--"), ("baseline", "C1--")):
        if name in tl and tl[name]["hard"] is not None:
            ax.axhline(tl[name]["hard"], ls=style[2:] or ":", color=style[:2] if style[0] == "C"
                       else "k", lw=0.8, label=f"{name}: hard-gate training loss")
    ax.set_xlabel("pushes simulated")
    ax.set_ylabel("loss")
    ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(0.0, -0.18), ncol=2)
    ax.grid(alpha=0.3)
    ax = axes[1]
    ax.semilogy([r["iteration"] + 1 for r in hist],
                [np.nan if not r["grad_norm"] or not math.isfinite(r["grad_norm"])
                 else max(r["grad_norm"], 1e-12) for r in hist], "o-", label="|grad| (latent)")
    ax.set_xlabel("iteration")
    ax.set_ylabel("gradient norm")
    ax2 = ax.twinx()
    ax2.plot([r["iteration"] + 1 for r in hist], rec["temperatures_deg"], "g--", lw=1,
             label="gate temperature")
    ax2.set_ylabel("gate temperature (deg)", color="g")
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    fig.suptitle(f"tkujax tune {rec['name']}: {rec['batch']} pushes x {rec['duration_s']} s",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(out / "loss_curve.png", dpi=90)
    plt.close(fig)

    ev = rec["evaluation"]
    if ev and any("grid_fell" in v for v in ev.values()):
        spec = parse_tune_spec(rec["spec"])
        J, A = np.meshgrid(spec.eval_impulse_ns, spec.eval_azimuth_deg, indexing="ij")
        azs = spec.eval_azimuth_deg
        fig, axes = plt.subplots(1, len(azs), figsize=(4.2 * len(azs), 3.4), squeeze=False)
        for i, a in enumerate(azs):
            ax = axes[0, i]
            sel = A.ravel() == a
            for name, mk in (("before", "k^-"), ("gradient", "C0o-"), ("baseline", "C1s-")):
                if name in ev and "grid_fell" in ev[name]:
                    fell = np.asarray(ev[name]["grid_fell"], float)[sel]
                    ax.plot(J.ravel()[sel], fell, mk, ms=4, label=name)
            ax.set_title(f"azimuth {a:g} deg (hard gate)", fontsize=9)
            ax.set_xlabel("impulse (N·s)")
            ax.set_ylabel("fell")
            ax.set_ylim(-0.1, 1.1)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(out / "evaluation.png", dpi=90)
        plt.close(fig)


def summary_markdown(rec: dict) -> str:
    hist = rec["history"]
    names = [n for n in ("before", "gradient", "baseline") if n in rec["params_user"]]
    lines = [f"# tkujax tune `{rec['name']}`", "",
             f"{rec['batch']} training pushes x {rec['duration_s']} s, {rec['iterations']} "
             f"iterations, float64 = {rec['float64']}, remat = {rec['remat']}; devices "
             f"{', '.join(rec['devices'])}. Gate temperature annealed "
             f"{rec['temperatures_deg'][0]:.2f} -> {rec['temperatures_deg'][-1]:.2f} deg. "
             f"Simulated pushes: gradient {rec['pushes_simulated']['gradient']} (each with a "
             f"backward pass), baseline {rec['pushes_simulated']['baseline']} (forward only). "
             f"Wall: gradient {rec['wall_s']['gradient']} s (first iteration incl. compile "
             f"{rec['wall_s']['first_iteration_incl_compile']} s), baseline "
             f"{rec['wall_s']['baseline']} s, total {rec['wall_s']['total']} s.", "",
             "## Parameters (user units)", "",
             "| parameter | range | " + " | ".join(names) + " |",
             "|---|---|" + "---|" * len(names)]
    for f in rec["tuned"]:
        lo, hi = rec["ranges_user_units"][f]
        unit = TUNABLE[f][3]
        lines.append(f"| {f} ({unit or '-'}) | [{lo:g}, {hi:g}] | "
                     + " | ".join(f"{rec['params_user'][n][f]:.4g}" for n in names) + " |")
    tl = rec["train_loss"]
    lines += ["", "## Loss on the training batch (same pushes for all)", "",
              "| parameters | soft (final temperature) | soft (baseline's temperature) | "
              "hard gate |", "|---|---|---|---|"]
    fmt = lambda v: "-" if v is None else f"{v:.4f}"  # noqa: E731
    for n in names:
        lines.append(f"| {n} | {fmt(tl[n]['final_temperature'])} | "
                     f"{fmt(tl[n]['baseline_temperature'])} | {fmt(tl[n]['hard'])} |")
    ev = rec["evaluation"]
    if ev:
        azs = sorted({a for v in ev.values() for a in v.get("max_impulse", {})}, key=float)
        lines += ["", "## Held-out evaluation (hard controller, gate_temperature = 0)", "",
                  "Held-out pushes: same distribution, another seed, never used for tuning. "
                  "Max recoverable impulse: largest grid impulse below which every grid push of "
                  "that azimuth was survived.", "",
                  "| parameters | held-out fall rate | mean recovery (s) of the recovered | "
                  "recovered | held-out loss (+- s.e.) | grid fall rate | " + " | ".join(f"max J @ {a} deg (N·s)" for a in azs)
                  + " |", "|---|---|---|---|---|---|" + "---|" * len(azs)]
        for n in names:
            v = ev.get(n, {})
            lines.append(
                f"| {n} | {_pct(v.get('heldout_fall_rate'))} | "
                f"{fmt(v.get('heldout_mean_recovery_s'))} | "
                f"{v.get('heldout_recovered', '-')}/{v.get('heldout_n', '-')} | "
                f"{_mean_se(v.get('heldout_push_loss'))} | {_pct(v.get('grid_fall_rate'))} | "
                + " | ".join(f"{v.get('max_impulse', {}).get(a, float('nan')):.2f}" for a in azs)
                + " |")
    gn = np.array([r["grad_norm"] for r in hist if r["finite"]], float)
    zero_frac = {}
    if hist and any(r["finite"] for r in hist):
        g = np.array([r["grad"] for r in hist if r["finite"]], float)
        zero_frac = {f: float(np.mean(np.abs(g[:, i]) < 1e-9)) for i, f in
                     enumerate(rec["tuned"])}
    lines += ["", "## Gradient diagnostics", "",
              f"Non-finite gradients: {rec['n_skipped']} of {len(hist)} iterations skipped "
              f"(iterations {rec['skipped_steps'] or 'none'}). Gradient norm (latent units): "
              + (f"median {np.median(gn):.3g}, min {gn.min():.3g}, max {gn.max():.3g}; clip at "
                 f"{rec['spec'].get('tune', {}).get('clip_norm', 1.0)}." if gn.size else "none")
              + " Share of iterations with an exactly-zero component: "
              + ", ".join(f"{f} {100 * v:.0f}%" for f, v in zero_frac.items()) + "."]
    lines += ["", "## Verdict", "", verdict(rec)]
    return "\n".join(lines) + "\n"


def _mean_se(x) -> str:
    if not x:
        return "-"
    x = np.asarray(x, float)
    se = np.std(x, ddof=1) / math.sqrt(x.size) if x.size > 1 else float("nan")
    return f"{x.mean():.4f} +- {se:.4f}"


def _paired(ev: dict, a: str, b: str) -> tuple[float, float]:
    """Mean and standard error of the per-push held-out loss difference a - b."""
    d = np.asarray(ev[a]["heldout_push_loss"]) - np.asarray(ev[b]["heldout_push_loss"])
    se = float(np.std(d, ddof=1) / math.sqrt(d.size)) if d.size > 1 else float("nan")
    return float(np.mean(d)), se


def _pct(v) -> str:
    return "-" if v is None else f"{100 * v:.1f}%"


def verdict(rec: dict) -> str:
    """One honest paragraph: did the gradient beat the baseline and the start point?"""
    tl, ev = rec["train_loss"], rec["evaluation"]
    if "baseline" not in tl:
        return "No baseline was run."
    g, b, s = (tl[n]["hard"] for n in ("gradient", "baseline", "before"))
    parts = [f"Hard-gate training loss: before {s:.4f}, gradient {g:.4f}, baseline {b:.4f}."]
    better_train = g is not None and b is not None and g < b
    if ev and "heldout_loss" in ev.get("gradient", {}):
        hg, hb, hs = (ev[n]["heldout_loss"] for n in ("gradient", "baseline", "before"))
        fg, fb, fs = (ev[n]["heldout_fall_rate"] for n in ("gradient", "baseline", "before"))
        parts.append(f"Held-out hard loss: before {hs:.4f}, gradient {hg:.4f}, baseline "
                     f"{hb:.4f}; held-out fall rate {_pct(fs)} / {_pct(fg)} / {_pct(fb)}.")
        better_held = hg < hb
        dm, dse = _paired(ev, "gradient", "baseline")
        parts.append(f"Paired per-push held-out loss difference gradient - baseline: "
                     f"{dm:+.4f} +- {dse:.4f} (s.e., n = {ev['gradient']['heldout_n']}).")
        if abs(dm) < 2 * dse:
            parts.append("That is within two standard errors: on this many held-out pushes the "
                         "two results are NOT distinguishable; the ordering stated next is not "
                         "significant.")
        if better_held and better_train:
            parts.append("The gradient result beats the gradient-free baseline on both the "
                         "training objective and the held-out pushes at equal simulated pushes.")
        elif better_held or better_train:
            parts.append("Mixed: the gradient result is better on "
                         + ("the held-out pushes" if better_held else "the training batch")
                         + " but not on " + ("the training batch" if better_held
                                             else "the held-out pushes") + ".")
        else:
            parts.append("The gradient result does NOT beat the gradient-free baseline.")
        gm, gse = _paired(ev, "gradient", "before")
        parts.append(f"Gradient - before (paired, held-out): {gm:+.4f} +- {gse:.4f}"
                     + (" (significant)." if gm < -2 * gse else " (not significant)."))
        if hg >= hs:
            parts.append("Gradient tuning did not improve on the starting (paper) parameters on "
                         "held-out pushes.")
    else:
        parts.append("The gradient result " + ("beats" if better_train else "does NOT beat")
                     + " the baseline on the training batch.")
    hist = rec["history"]
    n_fin = sum(r["finite"] for r in hist)
    parts.append(f"Diagnostics and caveats: {rec['n_skipped']} of {len(hist)} gradients were "
                 f"non-finite and skipped, {n_fin} applied; the recovery step's start is a "
                 "discrete event (the step weight crossing 1/2), so the gradient sees the step's "
                 "shape and length but not whether or when it is triggered, and contact "
                 "changes make MJX gradients noisy (see the gradient-norm panel of "
                 "loss_curve.png); the soft gate used during tuning is not the hard gate used "
                 "in the evaluation.")
    return " ".join(parts)


# ----------------------------------------------------------------------------------------------
# Benchmark hook (tkujax.bench)
# ----------------------------------------------------------------------------------------------

def benchmark_gradient_step(batch: int, duration_s: float, repeats: int = 3,
                            remat: bool = True, float64: bool = False) -> dict:
    """Time of one jitted value_and_grad of the tuning loss (all tunable parameters, sagittal
    pushes of 0.3-2.0 N s) at `batch` pushes x `duration_s`, median of `repeats` after a
    compile; peak device memory from memory_stats() where the backend reports it, else None."""
    data = {"tune": {"batch": batch, "duration_s": duration_s, "iterations": 1,
                     "params": list(TUNABLE), "remat": remat, "float64": float64},
            "push": {"impulse_ns": {"uniform": [0.3, 2.0]}, "azimuth_deg": [0.0, 180.0],
                     "azimuth_jitter_deg": 10.0, "onset_s": 0.3}}
    spec = parse_tune_spec(data)
    reparam, base = spec.reparam(), spec.base_params()
    problem = TuneProblem(reparam, base, spec.loss, duration_s, remat, float64)
    recs = sample_pushes(spec, batch, 0)
    keys = jax.random.split(jax.random.PRNGKey(0), batch)
    z = reparam.latent_of(base)
    tau = 1.0 * DEG
    t0 = time.perf_counter()
    problem.value_and_grad(z, tau, recs, keys)
    compile_s = time.perf_counter() - t0
    times = []
    for _ in range(max(repeats, 1)):
        t0 = time.perf_counter()
        _, _, g = problem.value_and_grad(z, tau, recs, keys)
        times.append(time.perf_counter() - t0)
    sec = float(np.median(times))
    try:
        stats = jax.devices()[0].memory_stats()
    except Exception:  # noqa: BLE001 - backends without memory stats
        stats = None
    peak = int(stats["peak_bytes_in_use"]) if stats and "peak_bytes_in_use" in stats else None
    return dict(batch=batch, duration_s=duration_s, seconds=sec, first_call_s=round(compile_s, 2),
                pushes_per_s=batch / sec, physics_steps_per_s=batch * problem.steps_per_push / sec,
                peak_device_bytes=peak, remat=remat, float64=float64,
                grad_finite=bool(np.all(np.isfinite(g))), n_params=reparam.size)
