"""Gradient refinement of the calibration through MJX ("use the differentiable simulator").

CMA-ES (`run.py`, `tkujax calibrate`, over MuJoCo C) finds the basin of the paper's 8 fall
outcomes; this module polishes the continuous parameters inside it with `jax.grad` through the
MJX closed loop. What it can reach is limited by what in Tables 4-5 is differentiable:

- step lengths are (the swing ankle's displacement, through the Kalman angle at detection and
  the capture point): they are the loss's targets, relative error per "on" row;
- recovery times are tick-quantised (last 30 ms period outside the band): zero gradient, so
  they are reported, not fitted;
- fall outcomes are discrete: a soft hinge on the peak inclination keeps each row on its side
  (standing rows below 25 deg, the falling row above 45 deg), and an iteration counts only if
  the hard evaluation keeps the outcomes.

Parameters (multiplicative scales of the fitted model, projected onto the calibration's
plausible bounds, `params.PARAMS`, after each Adam step): the leg servos' stiffness and
damping, the ball's impulse, and a shift of the chest CoM (x). The foot geometry, the other
pinned parameter, changes collision geometry and stays with the gradient-free search.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sim import push as push_lib
from tkujax.sim.metrics import outcomes as rollout_outcomes
from tkujax.sim.push import Push
from tkujax.sim.randomize import randomize_model
from tkujax.sim.rollout_mjx import Episode, ProgramOptions, RolloutConfig, rollout
from tkujax.sim.setup import init
from tkujax.studies.calibrate import fit_vector as P
from tkujax.studies.paper import PAPER_TABLE, paper_cases

NAMES = ("leg_kp_scale", "leg_damping_scale", "impulse_scale", "chest_com_dx_cm")
NO_STEP_M = 0.005          # as tkujax paper: a smaller ankle displacement is "no step"
STAND_MAX_DEG, FALL_MIN_DEG = 25.0, 45.0


def bounds(model: ModelParams, contact: push_lib.BallContact) -> tuple[np.ndarray, np.ndarray]:
    """Per-parameter [lo, hi]: the calibration's plausible bounds (params.PARAMS) expressed as
    scales of the given model, and +-1 cm for the chest CoM shift (in cm: every parameter is
    of order 1, as Adam's per-parameter step assumes)."""
    b = {p.name: (p.lo, p.hi) for p in P.PARAMS}
    kp, damp = model.leg_servo.kp_nm_per_rad, model.leg_servo.damping_nms_per_rad
    lo = [b["leg_kp"][0] / kp, b["leg_damping"][0] / damp,
          b["impulse_factor"][0] / contact.impulse_factor, -1.0]
    hi = [b["leg_kp"][1] / kp, b["leg_damping"][1] / damp,
          b["impulse_factor"][1] / contact.impulse_factor, 1.0]
    return np.array(lo), np.array(hi)


def _targets():
    """Per paper case: (step target in m, signed the simulator's way, or NaN; must fall)."""
    step, fall = [], []
    for d, b, c in paper_cases():
        rec, cm = PAPER_TABLE[(d, b, c)]
        step.append(math.nan if c == "off" or cm is None else (1 if d == "back" else -1) * cm / 100)
        fall.append(rec is None)
    return np.array(step, np.float32), np.array(fall)


class Refiner:
    """The 8 paper rows as a differentiable function of theta (NAMES), compiled once."""

    def __init__(self, model: ModelParams | None = None,
                 contact: push_lib.BallContact | None = None,
                 params: ControllerParams | None = None,
                 config: RolloutConfig = RolloutConfig(program=ProgramOptions(remat=True)),
                 cases: list[int] | None = None):
        self.model_params = model or ModelParams()
        self.contact = contact or push_lib.BallContact()
        self.params = params or ControllerParams.paper(self.model_params)
        host, model, index, state = init(self.model_params)
        self.cases = list(range(8)) if cases is None else list(cases)
        all_cases = paper_cases()
        self.names = [all_cases[i] for i in self.cases]
        step, fall = _targets()
        self.step_target, self.must_fall = step[self.cases], fall[self.cases]
        self.enabled = np.array([1.0 if c == "on" else 0.0 for *_, c in self.names], np.float32)
        self.impulse = np.array([self.contact.impulse_ns(b, d) for d, b, _ in self.names],
                                np.float32)
        self.height = np.array([self.contact.contact_height_m(d) for d, _, _ in self.names],
                               np.float32)
        self.azimuth = np.radians([push_lib.DIRECTIONS[d] for d, _, _ in self.names]).astype(
            np.float32)
        self.lo, self.hi = bounds(self.model_params, self.contact)
        legs = np.asarray(index.leg_actuators)
        dofs = host.jnt_dofadr[host.actuator_trnid[legs, 0]]
        leg_mask = np.isin(np.arange(host.nu), legs)
        dof_mask = np.isin(np.arange(host.nv), dofs)

        def rows(theta):
            kp, damp, imp, dx = theta[0], theta[1], theta[2], theta[3] / 100.0
            m = randomize_model(model, index.chest_body, torso_com_dx_m=dx, kp_scale=kp,
                                damping_scale=damp, actuator_mask=leg_mask, dof_mask=dof_mask)

            def one(j, az, en, h):
                push = Push(j * imp, az, h,
                            jnp.float32(push_lib.DEFAULT_DURATION_S),
                            jnp.float32(push_lib.PAPER_ONSET_S))
                series = rollout(m, state, Episode(push, en, jax.random.PRNGKey(0), 0.0, 0.0),
                                 self.params, config, index)
                return rollout_outcomes(series, push.onset_s)

            return jax.vmap(one)(jnp.asarray(self.impulse), jnp.asarray(self.azimuth),
                                 jnp.asarray(self.enabled), jnp.asarray(self.height))

        def loss(theta):
            out = rows(theta)
            has_step = np.isfinite(self.step_target)
            target = jnp.asarray(np.where(has_step, self.step_target, 1.0))
            rel = jnp.where(has_step, (out.step_length_m - target) / target, 0.0)
            # A row that took no step (|step| < 5 mm: the ankle only jitters) counts its error
            # but passes no gradient: the jitter's derivative says nothing about the step.
            stepped = jnp.abs(out.step_length_m) >= NO_STEP_M
            rel = jnp.where(stepped, rel, jax.lax.stop_gradient(rel))
            peak = out.peak_incl_deg
            hinge = jnp.where(self.must_fall, jax.nn.relu(FALL_MIN_DEG - peak),
                              jax.nn.relu(peak - STAND_MAX_DEG)) / 10.0
            terms = jnp.where(jnp.isfinite(rel), rel, 0.0) ** 2 + jnp.where(
                jnp.isfinite(hinge), hinge, 0.0) ** 2
            return jnp.sum(terms), out

        self._vg = jax.jit(jax.value_and_grad(loss, has_aux=True))

    def value_and_grad(self, theta):
        (val, out), g = self._vg(jnp.asarray(theta, jnp.float32))
        return float(val), jax.tree_util.tree_map(np.asarray, out), np.asarray(g, float)

    def value(self, theta):
        """(loss, outcomes): the same compiled program as value_and_grad (one compile)."""
        val, out, _ = self.value_and_grad(theta)
        return val, out

    def start(self) -> np.ndarray:
        return np.array([1.0, 1.0, 1.0, 0.0])

    def user(self, theta) -> dict:
        """theta in the model's units: leg kp, leg damping, impulse factor, chest CoM shift."""
        s = self.model_params.leg_servo
        return dict(leg_kp=float(theta[0] * s.kp_nm_per_rad),
                    leg_damping=float(theta[1] * s.damping_nms_per_rad),
                    impulse_factor=float(theta[2] * self.contact.impulse_factor),
                    chest_com_dx_m=float(theta[3]) / 100.0)

    def outcomes_as_paper(self, out) -> int:
        return int(np.sum(np.asarray(out.fell, bool) == self.must_fall))


def refine(out_dir: str | Path, iterations: int = 10, lr: float = 0.01,
           refiner: Refiner | None = None, log=print) -> dict:
    """Adam on theta (projected onto the bounds, step `lr` per parameter); writes
    DIR/refine.json and returns it. The best iterate is the lowest loss that keeps every fall
    outcome the start had; a step that loses one is undone and the step halved."""
    if not 1 <= iterations <= 500:
        raise ValueError(f"iterations must be in [1, 500], got {iterations}")
    if not 0 < lr <= 1:
        raise ValueError(f"lr must be in (0, 1], got {lr}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    r = refiner or Refiner()
    theta = r.start()
    opt = optax.adam(1.0)
    state, scale = opt.init(jnp.asarray(theta)), lr
    history, best, t0, first = [], None, time.perf_counter(), None
    for it in range(iterations + 1):
        val, out, g = r.value_and_grad(theta)
        first = first if first is not None else time.perf_counter() - t0
        ok = r.outcomes_as_paper(out)
        row = dict(iteration=it, loss=val, grad=g.tolist(), params=r.user(theta),
                   theta=np.asarray(theta).tolist(), lr=scale, fall_outcomes_as_paper=ok,
                   step_cm=[round(100 * float(s), 3) for s in out.step_length_m],
                   recovery_s=[None if not np.isfinite(x) else round(float(x), 3)
                               for x in out.recovery_time_s],
                   wall_s=round(time.perf_counter() - t0, 1))
        history.append(row)
        log(f"refine {it}/{iterations}: loss {val:.4f}, outcomes {ok}/{len(r.cases)}, "
            f"steps {row['step_cm']} cm, {r.user(theta)}")
        kept = ok == history[0]["fall_outcomes_as_paper"]
        if kept and (best is None or val < best["loss"]):
            best = row
        if it == iterations:
            break
        if not kept or not np.all(np.isfinite(g)):
            # Backtrack: a step that changed a fall outcome (or a non-finite gradient) is
            # undone; Adam restarts from the best point with half the step.
            theta, scale = np.asarray(best["theta"]), scale / 2
            state = opt.init(jnp.asarray(theta))
            val, out, g = r.value_and_grad(theta)
        upd, state = opt.update(jnp.asarray(g), state)
        theta = np.clip(np.asarray(theta) + scale * np.asarray(upd), r.lo, r.hi)
    result = dict(names=list(NAMES), cases=[list(c) for c in r.names],
                  step_target_cm=[None if not np.isfinite(s) else round(100 * float(s), 2)
                                  for s in r.step_target],
                  bounds=dict(lo=r.lo.tolist(), hi=r.hi.tolist()), lr=lr,
                  first_call_s=round(first, 1), history=history, best=best,
                  device=str(jax.devices()[0]))
    (out_dir / "refine.json").write_text(json.dumps(result, indent=1))
    return result


def apply(model: ModelParams, contact: push_lib.BallContact, user: dict
          ) -> tuple[ModelParams, push_lib.BallContact]:
    """The refined (model, contact) from refine()'s user-unit parameters. The chest CoM shift
    has no ModelParams field (the CoM height fraction is the model's knob), so it must be 0."""
    if abs(user["chest_com_dx_m"]) > 1e-9:
        raise ValueError("apply: chest_com_dx_m != 0 has no ModelParams field")
    servo = dataclasses.replace(model.leg_servo, kp_nm_per_rad=user["leg_kp"],
                                damping_override_nms_per_rad=user["leg_damping"])
    return (dataclasses.replace(model, leg_servo=servo).validate(),
            dataclasses.replace(contact, impulse_factor=user["impulse_factor"]).validate())

