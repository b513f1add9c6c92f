"""The differentiable tuning problem: one compiled loss and gradient per batch shape."""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.params import ControllerParams
from tkujax.sim.metrics import outcomes
from tkujax.sim.push import Push
from tkujax.sim.randomize import randomize_model
from tkujax.sim.rollout_mjx import RolloutConfig, rollout
from tkujax.sim.setup import init
from tkujax.studies.spec import RANDOMIZE_FIELDS
from tkujax.studies.tune.loss import LossConfig, push_loss
from tkujax.studies.tune.reparam import CPU_COMPILER_OPTIONS, DEG, EVAL_KEYS, Reparam


RECORD_KEYS = ("impulse_ns", "azimuth_deg", "height_m", "duration_s", "onset_s",
               *RANDOMIZE_FIELDS)


def _x64(enabled: bool):
    return jax.enable_x64(True) if enabled else contextlib.nullcontext()


class TuneProblem:
    """The differentiable loss of latents z over a batch of push records.

    All jitted functions are traced and called inside this problem's float64 context when
    `float64` is set (the MJX model and state are put on the device in float64 too).
    reparam: a Reparam (scalars) or a PolicyReparam (tkujax.studies.tune.policy: scalars plus
    a state-dependent schedule). `loss(z, temperature, batch, keys)` -> (loss, aux);
    `value_and_grad` and `forward` are its jitted gradient and forward-only versions (one
    compile each per batch size).
    """

    def __init__(self, reparam: Reparam, base: ControllerParams,
                 loss_cfg: LossConfig = LossConfig(),
                 duration_s: float = 1.2, remat: bool = True, float64: bool = False,
                 model_params=None, compiler_options: dict | None = None,
                 quantise_targets: bool = True, rollout_options: dict | None = None):
        self.reparam, self.base, self.loss_cfg = reparam, base, loss_cfg
        self.float64 = float64
        # rollout_options: further static RolloutConfig fields (unroll_ticks, unroll_substeps;
        # remat may be a RolloutConfig remat mode): `tkujax bench --grad-variants`.
        self.config = RolloutConfig(duration_s=duration_s, remat=remat,
                                    quantise_targets=quantise_targets,
                                    **(rollout_options or {}))
        host, self.model, self.index, self.state = init(model_params, float64=float64)
        self.dtype = jnp.float64 if float64 else jnp.float32
        self.n_ticks = int(round(duration_s / self.config.control_period_s))
        self.steps_per_push = int(round(duration_s / host.opt.timestep))
        if compiler_options is None and jax.default_backend() == "cpu":
            compiler_options = CPU_COMPILER_OPTIONS
        opts = compiler_options or None
        self._vg = jax.jit(jax.value_and_grad(self.loss, has_aux=True), compiler_options=opts)
        self._fwd = jax.jit(self.loss, compiler_options=opts)
        # Population methods (CMA-ES, zeroth-order gradients): every candidate of a generation
        # on the whole batch in ONE call (candidates x pushes rollouts), the loss only.
        self._pop = jax.jit(jax.vmap(lambda z, t, b, k: self.loss(z, t, b, k)[0],
                                     in_axes=(0, None, None, None)), compiler_options=opts)
        # The gradient per group of pushes (vmapped): the mean is the batch gradient, the
        # spread between groups estimates its variance (for the alpha-order mix).
        self._vg_groups = jax.jit(jax.vmap(jax.value_and_grad(
            lambda z, t, b, k: self.loss(z, t, b, k)[0]), in_axes=(None, None, 0, 0)),
            compiler_options=opts)

    def loss(self, z, temperature, batch: dict, keys):
        params = dataclasses.replace(self.reparam.apply(self.base, z),
                                     gate_temperature=temperature)
        # A PolicyReparam (tune.policy other than "scalars") also schedules some fields on the
        # filtered state; a plain Reparam has no schedule (the default program).
        schedule = self.reparam.schedule(z) if hasattr(self.reparam, "schedule") else None
        idx, cfg = self.index, self.loss_cfg

        def one(rec, key):
            push = Push(rec["impulse_ns"], rec["azimuth_deg"] * DEG, rec["height_m"],
                        rec["duration_s"], rec["onset_s"])
            model = randomize_model(self.model, idx.chest_body,
                                    mass_scale=rec["link_mass_scale"],
                                    torso_com_dx_m=rec["torso_com_offset_x_m"],
                                    friction=rec["floor_friction"],
                                    kp_scale=rec["servo_kp_scale"])
            series = rollout(model, self.state, push, params, 1.0, key, rec["gyro_noise_std"],
                             rec["accel_noise_std"], self.config, idx, schedule=schedule)
            out = outcomes(series, push.onset_s)
            return push_loss(series, push.onset_s, cfg), {k: out[k] for k in EVAL_KEYS}

        terms, outs = jax.vmap(one)(batch, keys)
        # A diverged push (numerical blow-up) is neither fell nor survived: it is left out of
        # the mean (its NaN would poison it) and reported in outcomes["diverged"].
        kept = ~outs["diverged"]
        total = jnp.sum(jnp.where(kept, terms["total"], 0.0)) / jnp.maximum(jnp.sum(kept), 1)
        return total, dict(terms=terms, outcomes=outs)

    def _args(self, z, temperature, batch, keys):
        cast = lambda x: jnp.asarray(x, self.dtype)  # noqa: E731
        return (cast(z), cast(temperature), {k: cast(batch[k]) for k in RECORD_KEYS}, keys)

    def value_and_grad(self, z, temperature, batch, keys):
        """(loss, aux, grad) as numpy (float64), computed in this problem's precision."""
        with _x64(self.float64):
            (loss, aux), g = self._vg(*self._args(z, temperature, batch, keys))
            return _np(loss), _np(aux), _np(g)

    def population(self, zs, temperature, batch, keys) -> np.ndarray:
        """(P,) mean losses of the P latents zs (P, k) on the same batch, one call."""
        with _x64(self.float64):
            cast = lambda x: jnp.asarray(x, self.dtype)  # noqa: E731
            out = self._pop(cast(zs), cast(temperature),
                            {k: cast(batch[k]) for k in RECORD_KEYS}, keys)
            return np.asarray(out, np.float64)

    def grouped_value_and_grad(self, z, temperature, batch, keys, groups: int):
        """(losses (G,), grads (G, k)) over `groups` equal groups of the batch (numpy)."""
        n = len(keys)
        if n % groups:
            raise ValueError(f"batch {n} must be a multiple of the gradient groups {groups}")
        with _x64(self.float64):
            z, t, b, k = self._args(z, temperature, batch, keys)
            split = lambda x: x.reshape((groups, n // groups) + x.shape[1:])  # noqa: E731
            loss, g = self._vg_groups(z, t, {c: split(v) for c, v in b.items()}, split(k))
            return np.asarray(loss, np.float64), np.asarray(g, np.float64)

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
            m = min(batch, n - lo)
            parts.append(jax.tree_util.tree_map(lambda x, m=m: x[:m], aux))
        return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *parts)


def _np(tree):
    return jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64)
                                  if np.issubdtype(np.asarray(x).dtype, np.floating)
                                  else np.asarray(x), tree)
