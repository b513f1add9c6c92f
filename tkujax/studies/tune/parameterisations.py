"""Parameterisations of growing size for `tkujax tune` (`tune.policy`), one latent vector each.

  scalars      the tuned scalars of `tune.params` (Reparam): n = k.
  sectorsN     the scalars, plus one latent correction per push-direction sector (N sectors,
               2..16) for each of `tune.schedule` (F fields), blended by softmax weights of the
               controller's own estimate of the direction (`tkujax.control.policy`):
               n = k + N F.
  mlpH         the scalars, plus a one-hidden-layer tanh MLP (H units, 1..256; "mlp" = 8) from
               [pitch deviation, pitch rate, roll, roll rate] to the F latent corrections:
               n = k + 5 H + (H + 1) F.
  mlprH        mlpH with recovery inputs ("mlpr" = 8 units): the MLP also reads the controller's
               step weight, the time since its recovery step started and the CPG's left/right
               support (`tkujax.control.policy.recovery_inputs`): n = k + 9 H + (H + 1) F.

Latent layout: z = [scalar latents (k), schedule latents]. The schedule's latents are
corrections in latent units added to the scalar latents of the scheduled fields, so the value
stays in its tuning range whatever the correction. At the start (`latent_of`) every correction is
exactly 0 (sector table 0; MLP output layer 0, hidden layer a fixed seeded draw), which gives the
unscheduled controller with the scalar values bit for bit.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.control.policy import MLP_INPUTS, UNSCHEDULABLE, Schedule
from tkujax.studies.tune.reparam import Reparam

# Scheduled by default: the step's timing, target gain and triggers, and the stance gains.
DEFAULT_SCHEDULE = ("step_period", "cp_gain", "cp_trigger_forward_m", "cp_trigger_backward_m",
                    "cp_trigger_lateral_m", "stance_ankle_kp", "stance_hip_kp",
                    "stance_roll_kp")
POLICY_PATTERN = re.compile(r"^(scalars|sectors(\d+)|(mlpr?)(\d*))$")
MLP_MAX_WIDTH = 256        # mlp96: 16 scalars + 8 fields -> 1,272 parameters; mlpr96: 1,656
MLP_INIT_SEED = 0          # the hidden layer's fixed draw (the same start for every method)


def parse_policy(name: str) -> tuple[str, int]:
    """"scalars" -> ("scalars", 0); "sectors4" -> ("sectors", 4); "mlp" / "mlp16" ->
    ("mlp", 8 / 16); "mlpr" / "mlpr16" -> ("mlpr", 8 / 16). ValueError otherwise."""
    m = POLICY_PATTERN.match(name) if isinstance(name, str) else None
    if m is None:
        raise ValueError(f"expected 'scalars', 'sectorsN' (N in 2..16), 'mlp[H]' or 'mlpr[H]' "
                         f"(H in 1..{MLP_MAX_WIDTH}), got {name!r}")
    if m.group(1) == "scalars":
        return "scalars", 0
    if m.group(2) is not None:
        n = int(m.group(2))
        if not 2 <= n <= 16:
            raise ValueError(f"sectorsN: N must be in 2..16, got {n}")
        return "sectors", n
    kind = m.group(3)
    h = int(m.group(4)) if m.group(4) else 8
    if not 1 <= h <= MLP_MAX_WIDTH:
        raise ValueError(f"{kind}H: H must be in 1..{MLP_MAX_WIDTH}, got {h}")
    return kind, h


@dataclasses.dataclass(frozen=True)
class PolicyReparam:
    """Latent z <-> (ControllerParams, Schedule | None). Offers Reparam's interface on the
    scalar part (fields, user, params_np, user_ranges ...) so reports work unchanged; `size`
    and `latent_of` cover the whole vector."""

    scalars: Reparam
    policy: str = "scalars"
    schedule_fields: tuple[str, ...] = ()
    sharpness: float = 4.0

    @staticmethod
    def make(scalars: Reparam, policy: str = "scalars",
             schedule_fields=DEFAULT_SCHEDULE, sharpness: float = 4.0) -> PolicyReparam:
        kind, _ = parse_policy(policy)
        fields = () if kind == "scalars" else tuple(schedule_fields)
        for f in fields:
            if f in UNSCHEDULABLE:
                raise ValueError(f"cannot schedule {f!r} (not schedulable: "
                                 f"{sorted(UNSCHEDULABLE)})")
            if f not in scalars.fields:
                raise ValueError(f"scheduled field {f!r} must be tuned too (tune.params)")
        if kind != "scalars" and (not fields or len(set(fields)) != len(fields)):
            raise ValueError(f"expected distinct scheduled fields, got {fields!r}")
        return PolicyReparam(scalars, policy, fields, float(sharpness))

    # -- sizes and layout ----------------------------------------------------------------
    @property
    def kind(self) -> str:
        return parse_policy(self.policy)[0]

    @property
    def width(self) -> int:
        """Sectors (sectors) or hidden units (mlp, mlpr); 0 for scalars."""
        return parse_policy(self.policy)[1]

    @property
    def k(self) -> int:
        return self.scalars.size

    @property
    def schedule_size(self) -> int:
        F, n = len(self.schedule_fields), self.width
        if self.kind == "sectors":
            return n * F
        if self.kind in MLP_INPUTS:
            return MLP_INPUTS[self.kind] * n + n + n * F + F
        return 0

    @property
    def size(self) -> int:
        return self.k + self.schedule_size

    # -- Reparam's interface on the scalar part --------------------------------------------
    @property
    def fields(self) -> tuple[str, ...]:
        return self.scalars.fields

    @property
    def lo(self):
        return self.scalars.lo

    @property
    def hi(self):
        return self.scalars.hi

    @property
    def log(self):
        return self.scalars.log

    def values(self, z):
        return self.scalars.values(jnp.asarray(z)[:self.k])

    def values_np(self, z):
        return self.scalars.values_np(np.asarray(z, float)[:self.k])

    def params_np(self, base: ControllerParams, z) -> ControllerParams:
        """The scalar part only (a schedule has no ControllerParams form: see `schedule_np`)."""
        return self.scalars.params_np(base, np.asarray(z, float)[:self.k])

    def user(self, z) -> dict[str, float]:
        return self.scalars.user(np.asarray(z, float)[:self.k])

    def user_ranges(self):
        return self.scalars.user_ranges()

    # -- the whole vector ------------------------------------------------------------------
    def latent_of(self, params: ControllerParams) -> np.ndarray:
        """Start latent: the scalars of params, every schedule correction exactly 0."""
        return np.concatenate([self.scalars.latent_of(params), self.schedule_init()])

    def schedule_init(self) -> np.ndarray:
        F, n = len(self.schedule_fields), self.width
        if self.kind == "mlp":
            rng = np.random.default_rng(MLP_INIT_SEED)
            w1 = rng.normal(0.0, 1.0 / np.sqrt(4.0), (4, n))
            return np.concatenate([w1.ravel(), np.zeros(n), np.zeros(n * F), np.zeros(F)])
        if self.kind == "mlpr":
            n_in = MLP_INPUTS["mlpr"]
            w1 = np.random.default_rng(MLP_INIT_SEED).normal(0.0, 1.0 / np.sqrt(n_in), (n_in, n))
            return np.concatenate([w1.ravel(), np.zeros(n), np.zeros(n * F), np.zeros(F)])
        return np.zeros(self.schedule_size)

    def schedule(self, z) -> Schedule | None:
        """The Schedule of latent z (traced or not); None for scalars."""
        if self.kind == "scalars":
            return None
        z = jnp.asarray(z)
        idx = [self.fields.index(f) for f in self.schedule_fields]
        zs = z[:self.k]
        F, n = len(self.schedule_fields), self.width
        rest = z[self.k:]
        static = dict(kind=self.kind, fields=self.schedule_fields,
                      lo=tuple(self.scalars.lo[i] for i in idx),
                      hi=tuple(self.scalars.hi[i] for i in idx),
                      log=tuple(self.scalars.log[i] for i in idx), sharpness=self.sharpness)
        z_base = zs[jnp.asarray(idx)]
        if self.kind == "sectors":
            return Schedule(z_base=z_base, table=rest.reshape(n, F), **static)
        n_in = MLP_INPUTS[self.kind]
        o = 0
        w1 = rest[o:o + n_in * n].reshape(n_in, n)
        o += n_in * n
        b1 = rest[o:o + n]
        o += n
        w2 = rest[o:o + n * F].reshape(n, F)
        o += n * F
        b2 = rest[o:o + F]
        return Schedule(z_base=z_base, w1=w1, b1=b1, w2=w2, b2=b2, **static)

    def apply(self, base: ControllerParams, z) -> ControllerParams:
        """The scalar part applied to base (the schedule comes from `schedule(z)`)."""
        return self.scalars.apply(base, jnp.asarray(z)[:self.k])

    def split(self, base: ControllerParams, z) -> tuple[ControllerParams, Schedule | None]:
        return self.apply(base, z), self.schedule(z)

    def describe(self, z) -> dict:
        """JSON form of a latent: the policy, its layout and the numbers (policy.json)."""
        z = np.asarray(z, float)
        return dict(policy=self.policy, kind=self.kind, width=self.width, n_params=self.size,
                    scalar_fields=list(self.fields), schedule_fields=list(self.schedule_fields),
                    sharpness=self.sharpness, scalars_user=self.user(z),
                    latent=z.tolist())


def as_policy(reparam) -> PolicyReparam:
    return reparam if isinstance(reparam, PolicyReparam) else PolicyReparam.make(reparam)


def save_policy(reparam: PolicyReparam, base: ControllerParams, z, path, source: str = "") -> Path:
    """The controller of latent z as a file `tkujax sweep --params` runs: a plain parameter file
    for "scalars", else a policy file (the full ControllerParams and the Schedule)."""
    from tkujax.control.params_files import save_policy_json

    z = np.asarray(z, float)
    return save_policy_json(reparam.params_np(base, z).validate(), reparam.schedule(z), path,
                            source=source or None)

