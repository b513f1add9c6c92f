"""Scheduled controller parameters: gains and thresholds that depend on the filtered state.

A `Schedule` (optional, `controller_step(..., schedule=...)`; None = the controller of
`ControllerParams` alone, whose program it leaves unchanged: a Python branch on None at trace
time) replaces some ControllerParams fields each control period by a value computed from what
the controller itself estimates: its filtered pitch deviation from the standing lean, its
filtered roll and the gyro rates. Never from the push's true azimuth, which a robot does not know.

Each scheduled field f is kept in its range [lo, hi] by the tuner's sigmoid map
(`tkujax.studies.tune.reparam.Reparam.values`) of a latent value

    z_f(state) = z_base_f + offset_f(state)

where z_base_f is the latent of the scalar value and offset_f the schedule's correction:

  sectors  offset = sum_s w_s(state) table[s, f]: one correction per push-direction sector,
           blended by softmax weights w_s = softmax(sharpness * cos(theta - c_s)) with the
           direction theta of the rate-aware capture point estimate (pitch deviation + rate *
           sqrt(h/g), lateral lean + rate * sqrt(h/g)), sector centres c_s = 2 pi s / S
           (s = 0: leaning forward, i.e. pushed from behind; counter-clockwise: toward +y). The
           cosine is taken against a smoothed norm sqrt(|v|^2 + eps^2), so it tends to 0 at rest
           (uniform weights) and the schedule stays differentiable everywhere.
  mlp      offset = tanh(x W1 + b1) W2 + b2, x = [pitch deviation / 0.1 rad, pitch rate / 1
           rad/s, roll / 0.1 rad, roll rate / 1 rad/s].
  mlpr     the same MLP with recovery inputs appended (`recovery_inputs`, from the controller's
           own state at the start of the period): x = [the four above, step weight (0 before
           the controller's own detection, 1 after), time since the current recovery step
           started (the detection for the first step, the re-trigger for a further one) / 0.5 s,
           clipped to [0, 1] s and 0 before detection, left and right support (1 - the CPG's
           commanded lift fraction of that foot: 1 on the ground, 0 at mid-swing)]. The
           controller reads no touch sensors (`Sensors` is the IMU alone), so the support is the
           gait's commanded phase, not a measured contact.

With table = 0 (sectors) or W2 = b2 = 0 (mlp) every offset is exactly 0.0, z_f = z_base_f
bit for bit, and the controller is exactly the unscheduled one with the scalar values.

Not schedulable (`UNSCHEDULABLE`): the Kalman filter's noises and accelerometer gate (the
filter runs before the state is known), the control period, the switches and the geometry.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.control.cpg import unit_oscillators
from tkujax.control.controller_params import (GEOMETRY_FIELDS, MODE_FIELDS, PHYSICAL_FIELDS,
                                              TIMING_FIELDS,
                                              ControllerParams)

# The period, the world, the robot's geometry and the switches, and the gains read before the
# state is known (the Kalman filter's noises, the accelerometer gate, the detection gate).
UNSCHEDULABLE = frozenset(TIMING_FIELDS + PHYSICAL_FIELDS + GEOMETRY_FIELDS + MODE_FIELDS + (
    "kalman_q", "kalman_r", "accel_gate", "gate_temperature"))
# Input scales of the MLP (rad, rad/s): pitch deviation, pitch rate, roll, roll rate.
MLP_INPUT_SCALE = (0.1, 1.0, 0.1, 1.0)
# Inputs of each MLP kind: the four IMU quantities; "mlpr" adds the four of `recovery_inputs`.
MLP_INPUTS = {"mlp": 4, "mlpr": 8}
RECOVERY_TIME_MAX_S = 1.0      # time since the step started: clipped to [0, this]
RECOVERY_TIME_SCALE_S = 0.5    # ... and divided by this
DIRECTION_EPS_RAD = 0.02


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Schedule:
    """kind: "sectors", "mlp" or "mlpr" (static). fields, lo, hi, log: the scheduled
    ControllerParams fields and their SI ranges (static; log: the sigmoid interpolates log10).
    sharpness: the sector softmax's inverse temperature (static). Data: z_base (F,); table
    (S, F) for "sectors"; w1 (I, H), b1 (H,), w2 (H, F), b2 (F,) for "mlp" (I = 4) and "mlpr"
    (I = 8) (None otherwise)."""

    z_base: jax.Array
    table: jax.Array | None = None
    w1: jax.Array | None = None
    b1: jax.Array | None = None
    w2: jax.Array | None = None
    b2: jax.Array | None = None
    kind: str = dataclasses.field(default="sectors", metadata=dict(static=True))
    fields: tuple[str, ...] = dataclasses.field(default=(), metadata=dict(static=True))
    lo: tuple[float, ...] = dataclasses.field(default=(), metadata=dict(static=True))
    hi: tuple[float, ...] = dataclasses.field(default=(), metadata=dict(static=True))
    log: tuple[bool, ...] = dataclasses.field(default=(), metadata=dict(static=True))
    sharpness: float = dataclasses.field(default=4.0, metadata=dict(static=True))


def sector_weights(v_pitch, v_lat, n_sectors: int, sharpness: float) -> jax.Array:
    """(..., S) softmax weights of the direction of (v_pitch, v_lat) against S sector centres."""
    norm = jnp.sqrt(v_pitch * v_pitch + v_lat * v_lat + DIRECTION_EPS_RAD ** 2)
    c = jnp.asarray([math.cos(2 * math.pi * s / n_sectors) for s in range(n_sectors)],
                    v_pitch.dtype)
    s = jnp.asarray([math.sin(2 * math.pi * s / n_sectors) for s in range(n_sectors)],
                    v_pitch.dtype)
    cos = (v_pitch[..., None] * c + v_lat[..., None] * s) / norm[..., None]
    return jax.nn.softmax(sharpness * cos, axis=-1)


def recovery_inputs(time_s, step_start_s, step_weight, swing_left,
                    params: ControllerParams) -> jax.Array:
    """(..., 4) recovery inputs of the "mlpr" schedule from the controller's state at the start
    of a period (`ControllerState`: time_s, step_start_s, step_weight, steps.swing_left):
    [step weight, clip(time_s - step_start_s, 0, RECOVERY_TIME_MAX_S) / RECOVERY_TIME_SCALE_S,
    left support, right support]. Before detection step_start_s is far in the future, so the
    time is 0 and both feet support. The support of the swing foot is 1 - the CPG's lift
    fraction (`cpg.unit_oscillators`, with params' step timing: a scheduled step period is not
    yet known when the schedule is evaluated). Non-finite entries read as 0."""
    dtype = jnp.result_type(jnp.asarray(time_s).dtype, float)
    age = jnp.asarray(time_s, dtype) - jnp.asarray(step_start_s, dtype)
    since = jnp.clip(age, 0.0, RECOVERY_TIME_MAX_S) / RECOVERY_TIME_SCALE_S
    lift = unit_oscillators(age, params)[2]
    left = jnp.asarray(swing_left, dtype)
    x = jnp.stack([jnp.broadcast_to(jnp.asarray(step_weight, dtype), age.shape), since,
                   1.0 - left * lift, 1.0 - (1.0 - left) * lift], -1)
    return jnp.where(jnp.isfinite(x), x, 0.0)


def schedule_offsets(schedule: Schedule, pitch_dev, pitch_rate, roll, roll_rate,
                     params: ControllerParams, recovery=None) -> jax.Array:
    """(F,) latent offsets of the scheduled fields in this state. recovery: the (..., 4)
    `recovery_inputs`, required by (and only read by) the "mlpr" kind."""
    dtype = jnp.result_type(pitch_dev.dtype, float)
    if schedule.kind == "sectors":
        tau = jnp.sqrt(params.com_height / params.gravity)      # 1 / omega of the LIP
        psi, psi_rate = -roll, -roll_rate                        # lateral lean toward +y
        w = sector_weights(pitch_dev + tau * pitch_rate, psi + tau * psi_rate,
                           schedule.table.shape[0], schedule.sharpness)
        return w @ schedule.table.astype(dtype)
    if schedule.kind == "mlp":
        x = jnp.stack([pitch_dev, pitch_rate, roll, roll_rate], -1) / jnp.asarray(
            MLP_INPUT_SCALE, dtype)
        h = jnp.tanh(x @ schedule.w1.astype(dtype) + schedule.b1.astype(dtype))
        return h @ schedule.w2.astype(dtype) + schedule.b2.astype(dtype)
    if schedule.kind == "mlpr":
        if recovery is None:
            raise ValueError("an 'mlpr' schedule needs the recovery inputs (recovery_inputs)")
        x = jnp.concatenate([jnp.stack([pitch_dev, pitch_rate, roll, roll_rate], -1)
                             / jnp.asarray(MLP_INPUT_SCALE, dtype),
                             jnp.asarray(recovery, dtype)], -1)
        h = jnp.tanh(x @ schedule.w1.astype(dtype) + schedule.b1.astype(dtype))
        return h @ schedule.w2.astype(dtype) + schedule.b2.astype(dtype)
    raise ValueError(f"Schedule.kind must be 'sectors', 'mlp' or 'mlpr', got {schedule.kind!r}")


def latent_to_values(z, lo, hi, log) -> jax.Array:
    """The tuner's bounded map (identical arithmetic to `Reparam.values`)."""
    z = jnp.asarray(z)
    dtype = jnp.result_type(z.dtype, float)
    blo = jnp.asarray([math.log10(v) if g else v for v, g in zip(lo, log)], dtype)
    bhi = jnp.asarray([math.log10(v) if g else v for v, g in zip(hi, log)], dtype)
    u = jax.nn.sigmoid(z.astype(dtype))
    x = blo * (1.0 - u) + bhi * u
    x = jnp.where(jnp.asarray(log), jnp.power(10.0, x), x)
    return jnp.clip(x, jnp.asarray(lo, dtype), jnp.asarray(hi, dtype))


def scheduled_params(schedule: Schedule, params: ControllerParams, pitch_dev, pitch_rate, roll,
                     roll_rate, recovery=None) -> ControllerParams:
    """params with the scheduled fields replaced by their values in this state.

    Written as value + (map(z_base + offset) - map(z_base)): mathematically map(z_base +
    offset), and with a zero offset the difference is exactly 0.0, so the field keeps the bits
    of params (which the tuner computed as map(z_base) in another fusion) while the gradient
    with respect to the offset and z_base is the map's. recovery: as `schedule_offsets`."""
    off = schedule_offsets(schedule, pitch_dev, pitch_rate, roll, roll_rate, params, recovery)
    z_base = schedule.z_base.astype(off.dtype)
    v = (latent_to_values(z_base + off, schedule.lo, schedule.hi, schedule.log)
         - latent_to_values(z_base, schedule.lo, schedule.hi, schedule.log))
    lo = jnp.asarray(schedule.lo, off.dtype)
    hi = jnp.asarray(schedule.hi, off.dtype)
    return dataclasses.replace(params, **{
        f: jnp.clip(jnp.asarray(getattr(params, f), off.dtype) + v[..., i], lo[i], hi[i])
        for i, f in enumerate(schedule.fields)})


# -- the policy file (`tkujax sweep --params FILE` with a "schedule" key) -------------------
SCHEDULE_ARRAYS = {"sectors": ("table",), "mlp": ("w1", "b1", "w2", "b2"),
                   "mlpr": ("w1", "b1", "w2", "b2")}
MLP_INPUT_NAMES = {"mlp": "pitch deviation, pitch rate, roll, roll rate",
                   "mlpr": "pitch deviation, pitch rate, roll, roll rate, step weight, time "
                           "since the step started, left support, right support"}


def schedule_to_dict(schedule: Schedule) -> dict:
    """JSON form of a Schedule: its static layout and its numbers (nested lists)."""
    d = dict(kind=schedule.kind, fields=list(schedule.fields), lo=list(schedule.lo),
             hi=list(schedule.hi), log=list(schedule.log), sharpness=schedule.sharpness,
             z_base=np.asarray(schedule.z_base, float).tolist())
    for name in SCHEDULE_ARRAYS[schedule.kind]:
        d[name] = np.asarray(getattr(schedule, name), float).tolist()
    return d


def schedule_from_dict(d, where: str) -> Schedule:
    """Schedule from its JSON form, validated: ValueError names where, the key and what is
    allowed (kind, schedulable fields, shapes consistent with the fields, finite numbers)."""
    if not isinstance(d, dict):
        raise ValueError(f"{where}: expected an object, got {type(d).__name__}")
    kind = d.get("kind")
    if kind not in SCHEDULE_ARRAYS:
        raise ValueError(f"{where}.kind: expected one of {sorted(SCHEDULE_ARRAYS)}, got {kind!r}")
    allowed = {"kind", "fields", "lo", "hi", "log", "sharpness", "z_base",
               *SCHEDULE_ARRAYS[kind]}
    unknown = sorted(set(d) - allowed)
    missing = sorted(allowed - set(d))
    if unknown or missing:
        raise ValueError(f"{where}: {'unknown key(s) ' + str(unknown) if unknown else ''}"
                         f"{'; ' if unknown and missing else ''}"
                         f"{'missing key(s) ' + str(missing) if missing else ''} "
                         f"(a {kind!r} schedule has {sorted(allowed)})")
    fields = d["fields"]
    names = {f.name for f in dataclasses.fields(ControllerParams)}
    if (not isinstance(fields, list) or not fields
            or not all(isinstance(f, str) for f in fields)):
        raise ValueError(f"{where}.fields: expected a non-empty list of field names, "
                         f"got {fields!r}")
    for f in fields:
        if f not in names or f in UNSCHEDULABLE:
            raise ValueError(f"{where}.fields: {f!r} cannot be scheduled (schedulable: "
                             f"{sorted(names - UNSCHEDULABLE)})")
    if len(set(fields)) != len(fields):
        raise ValueError(f"{where}.fields: expected distinct names, got {fields!r}")
    n_f = len(fields)

    def array(key, ndim, last=None):
        try:
            a = np.asarray(d[key], float)
        except (TypeError, ValueError):
            raise ValueError(f"{where}.{key}: expected numbers, got {d[key]!r:.80}") from None
        if a.ndim != ndim or (last is not None and a.shape[-1] != last) or not a.size:
            want = f"a {ndim}-d array" + (f", last axis {last}" if last is not None else "")
            raise ValueError(f"{where}.{key}: expected {want}, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{where}.{key}: every value must be finite")
        return a

    lo, hi, z_base = (array(k, 1, n_f) for k in ("lo", "hi", "z_base"))
    log = d["log"]
    if not isinstance(log, list) or len(log) != n_f or not all(isinstance(g, bool) for g in log):
        raise ValueError(f"{where}.log: expected {n_f} booleans, got {log!r}")
    if np.any(lo >= hi) or np.any(lo[np.asarray(log)] <= 0):
        raise ValueError(f"{where}: expected lo < hi (and lo > 0 where log), got lo {lo.tolist()}"
                         f", hi {hi.tolist()}")
    sharpness = d["sharpness"]
    if isinstance(sharpness, bool) or not isinstance(sharpness, (int, float)) or not (
            0 < sharpness <= 100):
        raise ValueError(f"{where}.sharpness: expected a number in (0, 100], got {sharpness!r}")
    arrays = {}
    if kind == "sectors":
        arrays["table"] = array("table", 2, n_f)
    else:
        w1 = array("w1", 2)
        width = w1.shape[1]
        n_in = MLP_INPUTS[kind]
        if w1.shape[0] != n_in:
            raise ValueError(f"{where}.w1: expected shape ({n_in}, H) (inputs: "
                             f"{MLP_INPUT_NAMES[kind]}), got {w1.shape}")
        arrays = dict(w1=w1, b1=array("b1", 1, width), w2=array("w2", 2, n_f),
                      b2=array("b2", 1, n_f))
        if arrays["w2"].shape[0] != width:
            raise ValueError(f"{where}.w2: expected shape ({width}, {n_f}), "
                             f"got {arrays['w2'].shape}")
    return Schedule(z_base=jnp.asarray(z_base, jnp.float32),
                    **{k: jnp.asarray(v, jnp.float32) for k, v in arrays.items()},
                    kind=kind, fields=tuple(fields), lo=tuple(float(v) for v in lo),
                    hi=tuple(float(v) for v in hi), log=tuple(log), sharpness=float(sharpness))
