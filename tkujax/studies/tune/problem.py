"""The differentiable tuning problem: one compiled loss and gradient per batch shape.

Robots: a problem built with a RobotSet (`tkujax.sim.robots`) runs each push on the robot of
its record's robot_id column (ROBOT_ID_COLUMN, a row of the set: a traced index picks that
robot's model and settled stand inside the one compiled program), then applies the push's own
mass / CoM / friction / kp randomisation on top, as `tkujax sweep` does with [randomize]
ensemble. The tuner's convention (`tkujax.studies.tune.tune_spec.robot_table`): row 0 is the default
robot (the spec's model), rows 1..n the members of the training ensemble, then the members of
the shifted set's ensemble when it is another file. Without a RobotSet the records have no
robot_id and the program is the single-robot one (a Python branch at trace time).

"Harm nowhere" (LossConfig.w_harm > 0): each push's loss counts (1 + w_harm) times when control
off survives it. That does not depend on the tuned parameters, so it is computed once per batch
by a forward pass with control disabled (`with_off_survived`) and enters the loss as a column
(OFF_SURVIVED) of the batch: the loss stays one compiled function of (z, temperature, batch,
keys).

Gradient options (each off by default, the program then unchanged):
  timing_gradient   the controller runs with `with_timing_gradient` (a straight-through
                    interpolated step start: step timing gets a gradient; forward values equal).
                    Only inside the loss: `reparam.params_np` stays a plain ControllerParams.
  bundle_sigma > 0  bundled (randomised-smoothing) gradients in `grouped_value_and_grad`: push
                    i runs at z + bundle_sigma * noise_i (noise (n, k) given by the caller,
                    `tkujax.gradients.bundled.bundle_noise`), so the gradient is that of
                    the loss smoothed by a Gaussian of width bundle_sigma.
  rollout_options   e.g. {"gradient_window_ticks": K}: truncated backpropagation windows.
"""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.controller import with_timing_gradient
from tkujax.control.controller_params import ControllerParams
from tkujax.sim.metrics import outcomes
from tkujax.sim.push import Push
from tkujax.sim.randomize import randomize_model
from tkujax.sim.robots import RobotSet, put_leaves
from tkujax.sim.rollout_mjx import Episode, ProgramOptions, RolloutConfig, rollout
from tkujax.sim.robot import as_robot
from tkujax.dialects.sweep_spec import RANDOMIZE_FIELDS, ROBOT_ID_COLUMN
from tkujax.studies.tune.loss import OFF_SURVIVED, LossConfig, harm_weighted_mean, push_loss
from tkujax.studies.tune.reparam import CPU_COMPILER_OPTIONS, DEG, EVAL_KEYS, Reparam


RECORD_KEYS = ("impulse_ns", "azimuth_deg", "height_m", "duration_s", "onset_s",
               *RANDOMIZE_FIELDS)


def x64(enabled: bool):
    return jax.enable_x64(True) if enabled else contextlib.nullcontext()



# What tune.remat = true checkpoints: each physics substep. Against a checkpoint per control
# tick, on one H100 at 1,024 pushes x 1.5 s (results/bench/README.md): the gradient
# step 2.98 s vs 4.63 s, peak memory 1.55 vs 2.93 GB, the cold compile 103 s vs 124 s; the
# gradient is the same function (checkpointing changes what is stored, not the values).
TUNE_REMAT = "substep"
# The tuner's physics steps run tkujax.sim.tree_passes (RolloutConfig.tree_passes="compact"):
# MJX's kinematics, com_vel and rne with MJX's formulas, equal to float rounding, in a program
# that XLA compiles in about half the time. On one H200 at batch 256 x 1.5 s the gradient's cold
# compile took 41.0 s against 76.9 s with MJX's passes, and its step at 1,024 ran 2.32 s
# against 2.65 s (results/bench/README.md). A tuner loss so differs from a sweep's
# by rounding, not by model.
TUNE_TREE_PASSES = "compact"


class TuneProblem:
    """The differentiable loss of latents z over a batch of push records.

    All jitted functions are traced and called inside this problem's float64 context when
    `float64` is set (the MJX model and state are put on the device in float64 too).
    reparam: a Reparam (scalars) or a PolicyReparam (tkujax.studies.tune.parameterisations: scalars
    plus
    a state-dependent schedule). `loss(z, temperature, batch, keys)` -> (loss, aux);
    `value_and_grad` and `forward` are its jitted gradient and forward-only versions (one
    compile each per batch size).

    robots: None (one robot: `model_params`, None = the default robot), or a RobotSet whose
    row r is the robot of the pushes with robot_id r (a batch column then; the tuner's table,
    `tkujax.studies.tune.tune_spec.robot_table`, has the default robot in row 0 and the ensembles'
    members in rows 1..n). Float32 only. The push's randomisation applies on top of its robot.
    loss_cfg.w_harm > 0: the batch also needs OFF_SURVIVED (added by the methods below when it
    lacks it: one control-off forward pass; pass a batch that has it to avoid recomputing it,
    as `run_search` does). aux["terms"]["weighted"] is then each push's weighted loss.
    """

    def __init__(self, reparam: Reparam, base: ControllerParams,
                 loss_cfg: LossConfig = LossConfig(),
                 duration_s: float = 1.2, remat: bool = True, float64: bool = False,
                 model_params=None, compiler_options: dict | None = None,
                 quantise_targets: bool = True, rollout_options: dict | None = None,
                 robots: RobotSet | None = None, timing_gradient: bool = False,
                 bundle_sigma: float = 0.0):
        self.reparam, self.base, self.loss_cfg = reparam, base, loss_cfg
        self.float64 = float64
        self.timing_gradient, self.bundle_sigma = bool(timing_gradient), float(bundle_sigma)
        if not (np.isfinite(self.bundle_sigma) and self.bundle_sigma >= 0):
            raise ValueError(f"TuneProblem: bundle_sigma must be >= 0, got {bundle_sigma!r}")
        # rollout_options: further static RolloutConfig fields (unroll_ticks, unroll_substeps,
        # tree_passes; remat may be a RolloutConfig remat mode): `tkujax bench --grad-variants`.
        # remat=True (tune.remat) checkpoints each physics substep (TUNE_REMAT).
        self.config = RolloutConfig(duration_s=duration_s, quantise_targets=quantise_targets,
                                    program=ProgramOptions(**{
                                        "remat": TUNE_REMAT if remat is True else remat,
                                        "tree_passes": TUNE_TREE_PASSES,
                                        **(rollout_options or {})}))
        self.robots = robots
        if robots is None:
            host, self.model, self.index, self.state = as_robot(model_params).sim_setup(
                float64=float64)
            self._robot_values = None
            timestep = host.opt.timestep
        else:
            if model_params is not None:
                raise ValueError("TuneProblem: pass either model_params or robots (row 0 of "
                                 "the RobotSet is the default robot), not both")
            if float64:
                raise ValueError("TuneProblem: a RobotSet runs in float32 (float64=False)")
            self.model, self.index, self.state = (robots.base_model, robots.index,
                                                  robots.base_state)
            # Arguments of the jitted functions below (not constants baked into them).
            self._robot_values = robots.values()
            timestep = float(robots.base_model.opt.timestep)
        self.dtype = jnp.float64 if float64 else jnp.float32
        self.n_ticks = int(round(duration_s / self.config.control_period_s))
        self.steps_per_push = int(round(duration_s / timestep))
        if compiler_options is None and jax.default_backend() == "cpu":
            compiler_options = CPU_COMPILER_OPTIONS
        opts = compiler_options or None
        # Every jitted function takes the robots' values as its last argument (None without
        # robots: no leaves, the single-robot program).
        self._vg = jax.jit(jax.value_and_grad(self._loss, has_aux=True), compiler_options=opts)
        self._fwd = jax.jit(self._loss, compiler_options=opts)
        # Population methods (CMA-ES, zeroth-order gradients): every candidate of a generation
        # on the whole batch in ONE call (candidates x pushes rollouts), the loss only.
        self._pop = jax.jit(jax.vmap(lambda z, t, b, k, rv: self._loss(z, t, b, k, rv)[0],
                                     in_axes=(0, None, None, None, None)), compiler_options=opts)
        # The gradient per group of pushes (vmapped): the mean is the batch gradient, the
        # spread between groups estimates its variance (for the alpha-order mix).
        self._vg_groups = jax.jit(jax.vmap(jax.value_and_grad(
            lambda z, t, b, k, rv: self._loss(z, t, b, k, rv)[0]),
            in_axes=(None, None, 0, 0, None)), compiler_options=opts)
        # Bundled: the same with each push's noise (groups, n / groups, k), in_axes 0.
        self._vg_groups_bundled = jax.jit(jax.vmap(jax.value_and_grad(
            lambda z, t, b, k, rv, e: self._loss(z, t, b, k, rv, e)[0]),
            in_axes=(None, None, 0, 0, None, 0)), compiler_options=opts)
        # Control off (w_harm): compiled on first use only.
        self._off = jax.jit(jax.vmap(self._off_one, in_axes=(0, 0, None)),
                            compiler_options=opts)

    @property
    def needs_off(self) -> bool:
        """Whether the loss reads the OFF_SURVIVED column (LossConfig.w_harm > 0)."""
        return bool(self.loss_cfg.w_harm)

    @property
    def input_keys(self) -> tuple[str, ...]:
        """The batch columns the loss reads: RECORD_KEYS, plus ROBOT_ID_COLUMN with robots and
        OFF_SURVIVED with w_harm > 0."""
        return (RECORD_KEYS + ((ROBOT_ID_COLUMN,) if self.robots is not None else ())
                + ((OFF_SURVIVED,) if self.needs_off else ()))

    def _model_state(self, rec, robot_values):
        """The push's robot (its robot_id row of the RobotSet when there is one), with the
        push's randomisation on top."""
        model, state = self.model, self.state
        if robot_values is not None:
            rid = rec[ROBOT_ID_COLUMN].astype(jnp.int32)
            model = put_leaves(model, self.robots.model_leaf_ids, robot_values[0], rid)
            state = put_leaves(state, self.robots.state_leaf_ids, robot_values[1], rid)
        model = randomize_model(model, self.index.chest_body,
                                mass_scale=rec["link_mass_scale"],
                                torso_com_dx_m=rec["torso_com_offset_x_m"],
                                friction=rec["floor_friction"],
                                kp_scale=rec["servo_kp_scale"])
        return model, state

    def loss(self, z, temperature, batch: dict, keys):
        """(mean loss, aux) of latents z on the batch (columns `input_keys`); the robots' values
        enter as constants here (the jitted methods pass them as arguments)."""
        return self._loss(z, temperature, batch, keys, self._robot_values)

    def _params(self, z, temperature):
        """(ControllerParams, schedule or None) of latents z: the base moved by the reparam,
        at the gate temperature, with the timing gradient when asked for."""
        params = dataclasses.replace(self.reparam.apply(self.base, z),
                                     gate_temperature=temperature)
        if self.timing_gradient:
            params = with_timing_gradient(params)
        # A PolicyReparam (tune.policy other than "scalars") also schedules some fields on the
        # filtered state; a plain Reparam has no schedule (the default program).
        schedule = self.reparam.schedule(z) if hasattr(self.reparam, "schedule") else None
        return params, schedule

    def _loss(self, z, temperature, batch: dict, keys, robot_values, noise=None):
        """noise None: every push at z; noise (n, k): push i at z + bundle_sigma * noise_i
        (a Python branch at trace time)."""
        idx, cfg = self.index, self.loss_cfg

        def one(rec, key, zi):
            params, schedule = self._params(zi, temperature)
            push = Push(rec["impulse_ns"], rec["azimuth_deg"] * DEG, rec["height_m"],
                        rec["duration_s"], rec["onset_s"])
            model, state = self._model_state(rec, robot_values)
            series = rollout(model, state, Episode(push, 1.0, key, rec["gyro_noise_std"],
                             rec["accel_noise_std"]), params, self.config, idx, schedule=schedule)
            out = outcomes(series, push.onset_s)
            return push_loss(series, push.onset_s, cfg), {k: out[k] for k in EVAL_KEYS}

        if noise is None:     # z closed over: the program it always was
            terms, outs = jax.vmap(lambda rec, key: one(rec, key, z))(batch, keys)
        else:
            terms, outs = jax.vmap(one)(batch, keys, z + self.bundle_sigma * noise)
        # A diverged push (numerical blow-up) is neither fell nor survived: it is left out of
        # the mean (its NaN would poison it) and reported in outcomes["diverged"].
        kept = ~outs["diverged"]
        if self.needs_off:   # static: w_harm = 0 compiles the plain mean
            off = batch[OFF_SURVIVED]
            terms = dict(terms, weighted=(1.0 + cfg.w_harm * off) * terms["total"])
            total = harm_weighted_mean(terms["total"], kept, off, cfg.w_harm)
        else:
            total = harm_weighted_mean(terms["total"], kept)
        return total, dict(terms=terms, outcomes=outs)

    def _off_one(self, rec, key, robot_values):
        """One push with control OFF (the robot holds its stand): fell / diverged."""
        push = Push(rec["impulse_ns"], rec["azimuth_deg"] * DEG, rec["height_m"],
                    rec["duration_s"], rec["onset_s"])
        model, state = self._model_state(rec, robot_values)
        config = dataclasses.replace(self.config, program=dataclasses.replace(
            self.config.program, remat=False))   # forward only
        series = rollout(model, state, Episode(push, 0.0, key, rec["gyro_noise_std"],
                         rec["accel_noise_std"]), self.base, config, self.index)
        out = outcomes(series, push.onset_s)
        return {k: out[k] for k in ("fell", "diverged")}

    def control_off(self, records: dict, keys, batch: int | None = None) -> dict:
        """{fell, diverged} (numpy bool, per record) of the records with control OFF, in chunks
        of `batch` (default: all at once). Independent of the tuned parameters."""
        n = len(records["impulse_ns"])
        batch = batch or n
        cols = [k for k in self.input_keys if k != OFF_SURVIVED]
        parts = []
        with x64(self.float64):
            for lo in range(0, n, batch):
                sel = np.resize(np.arange(lo, min(lo + batch, n)), batch)
                chunk = {k: jnp.asarray(np.asarray(records[k])[sel], self.dtype) for k in cols}
                out = self._off(chunk, keys[sel], self._robot_values)
                m = min(batch, n - lo)
                parts.append({k: np.asarray(v)[:m].astype(bool) for k, v in out.items()})
        return {k: np.concatenate([p[k] for p in parts]) for k in ("fell", "diverged")}

    def with_off_survived(self, records: dict, keys, batch: int | None = None) -> dict:
        """The records with their OFF_SURVIVED column (1.0 where control off neither falls nor
        diverges) when the loss needs it and they lack it; otherwise the records unchanged."""
        if not self.needs_off or OFF_SURVIVED in records:
            return records
        return dict(records, **{OFF_SURVIVED: off_survived(self.control_off(records, keys,
                                                                             batch))})

    def cast_args(self, z, temperature, batch, keys):
        """(z, temperature, batch, keys) cast to this problem's precision; the batch reduced to
        `input_keys` (a missing column is named). The jitted methods also take the robots'
        values, `self._robot_values`, as a last argument."""
        missing = [k for k in self.input_keys if k not in batch]
        if missing:
            raise ValueError(f"TuneProblem: the batch lacks the column(s) {missing}"
                             + (f" ({ROBOT_ID_COLUMN}: the row of the problem's RobotSet)"
                                if ROBOT_ID_COLUMN in missing else "")
                             + (f" ({OFF_SURVIVED}: `with_off_survived`)"
                                if OFF_SURVIVED in missing else ""))
        cast = lambda x: jnp.asarray(x, self.dtype)  # noqa: E731
        return (cast(z), cast(temperature), {k: cast(batch[k]) for k in self.input_keys}, keys)

    def lower_value_and_grad(self, z, temperature, batch, keys):
        """The gradient program lowered for these arguments (`jax.stages.Lowered`), and the
        arguments its compiled executable takes: what `tkujax bench` times."""
        args = (*self.cast_args(z, temperature, batch, keys), self._robot_values)
        return self._vg.lower(*args), args

    def value_and_grad(self, z, temperature, batch, keys):
        """(loss, aux, grad) as numpy (float64), computed in this problem's precision."""
        batch = self.with_off_survived(batch, keys)
        with x64(self.float64):
            (loss, aux), g = self._vg(*self.cast_args(z, temperature, batch, keys),
                                      self._robot_values)
            return to_numpy(loss), to_numpy(aux), to_numpy(g)

    def population(self, zs, temperature, batch, keys) -> np.ndarray:
        """(P,) mean losses of the P latents zs (P, k) on the same batch, one call."""
        batch = self.with_off_survived(batch, keys)
        with x64(self.float64):
            out = self._pop(*self.cast_args(zs, temperature, batch, keys), self._robot_values)
            return np.asarray(out, np.float64)

    def grouped_value_and_grad(self, z, temperature, batch, keys, groups: int, noise=None):
        """(losses (G,), grads (G, k)) over `groups` equal groups of the batch (numpy).
        noise (n, k): bundled gradients, push i at z + bundle_sigma * noise_i (bundle_sigma >
        0 only: noise with bundle_sigma = 0 is an error); None: every push at z."""
        n = len(keys)
        if n % groups:
            raise ValueError(f"batch {n} must be a multiple of the gradient groups {groups}")
        if noise is not None and not self.bundle_sigma:
            raise ValueError("TuneProblem.grouped_value_and_grad: noise given, but "
                             "bundle_sigma = 0")
        batch = self.with_off_survived(batch, keys)
        with x64(self.float64):
            z, t, b, k = self.cast_args(z, temperature, batch, keys)
            split = lambda x: x.reshape((groups, n // groups) + x.shape[1:])  # noqa: E731
            args = (z, t, {c: split(v) for c, v in b.items()}, split(k), self._robot_values)
            if noise is None:
                loss, g = self._vg_groups(*args)
            else:
                loss, g = self._vg_groups_bundled(*args, split(jnp.asarray(noise, self.dtype)))
            return np.asarray(loss, np.float64), np.asarray(g, np.float64)

    def forward(self, z, temperature, batch, keys):
        batch = self.with_off_survived(batch, keys)
        with x64(self.float64):
            loss, aux = self._fwd(*self.cast_args(z, temperature, batch, keys), self._robot_values)
            return to_numpy(loss), to_numpy(aux)

    def forward_padded(self, z, temperature, records: dict, keys, batch: int) -> dict:
        """Forward over any number of records in chunks of `batch` (one compiled shape).
        Returns the per-push aux (terms and outcomes) for the records, numpy. The control-off
        column (w_harm > 0) is computed once here when the records lack it
        (`with_off_survived`: pass records that have it to share it between calls)."""
        n = len(records["impulse_ns"])
        records = self.with_off_survived(records, keys, batch)
        parts = []
        for lo in range(0, n, batch):
            sel = np.resize(np.arange(lo, min(lo + batch, n)), batch)
            chunk = {k: np.asarray(records[k])[sel] for k in self.input_keys}
            _, aux = self.forward(z, temperature, chunk, keys[sel])
            m = min(batch, n - lo)
            parts.append(jax.tree_util.tree_map(lambda x, m=m: x[:m], aux))
        return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs), *parts)


def off_survived(off: dict) -> np.ndarray:
    """The OFF_SURVIVED column of `control_off`'s result: 1.0 where control off neither falls
    nor diverges, 0.0 elsewhere."""
    return (~off["fell"] & ~off["diverged"]).astype(float)


def to_numpy(tree):
    return jax.tree_util.tree_map(lambda x: np.asarray(x, np.float64)
                                  if np.issubdtype(np.asarray(x).dtype, np.floating)
                                  else np.asarray(x), tree)
