"""One candidate parameter vector -> the paper's 8 rows, for every reading of Algorithm 1, at
one or several hit phases.

MuJoCo C physics (tkujax.sim.rollout_mujoco), noise-free, the JAX controller. The 4 control-off
rows do not depend on the reading and run once; the 4 control-on rows run once per reading.
A hit phase (ms) moves the push onset that far after the controller tick at the paper's 0.75 s:
the paper does not give it, and the Kalman trigger depends on it (results/calibration/FINDINGS.md),
so a fit can average its loss over several phases. All phases go into one batch per reading.
"""

from __future__ import annotations

import math

import numpy as np

from tkujax.sim import push as push_lib
from tkujax.studies.calibrate import params as P

CASES = [(d, b) for d in ("back", "front") for b in ("baseball", "volleyball")]


def _simulate(pushes, enabled, cparams, mparams):
    from tkujax.sim.rollout_mujoco import simulate_mujoco
    import os
    threads = os.environ.get("TKUJAX_CAL_THREADS")   # 1 per worker in a parallel search
    return simulate_mujoco(pushes, enabled, cparams, model_params=mparams,
                           n_threads=int(threads) if threads else None)


def hit_onset_s(hit_phase_ms: float) -> float:
    """Push onset (s): `hit_phase_ms` after the controller tick at the paper's 0.75 s."""
    if not 0.0 <= hit_phase_ms < 1e3 * push_lib.CONTROL_PERIOD_S:
        raise ValueError(f"hit_phase_ms must be in [0, {1e3 * push_lib.CONTROL_PERIOD_S:g}) ms, "
                         f"got {hit_phase_ms!r}")
    return float(push_lib.onset_from_phase(push_lib.PAPER_ONSET_S,
                                           1e-3 * hit_phase_ms / push_lib.CONTROL_PERIOD_S))


def pushes_for(x, hit_phases_ms=(0.0,)) -> object:
    """The 4 ball cases (CASES order) at each hit phase: phase-major, 4 * len(phases) pushes."""
    v = P.as_dict(x) if not isinstance(x, dict) else x
    return push_lib.stack_pushes([
        push_lib.make_push(v["impulse_factor"] * push_lib.ball_momentum_ns(b),
                           push_lib.DIRECTIONS[d], height_m=float(v["push_height_m"]),
                           onset_s=hit_onset_s(ph))
        for ph in hit_phases_ms for d, b in CASES])


def _rows(series, out, control, cparams, offset: int = 0) -> dict:
    res = {}
    for j, (d, b) in enumerate(CASES):
        i = offset + j
        fell = bool(out["fell"][i])
        step = float(out["step_length_m"][i])
        phi = np.degrees(np.asarray(series["pitch_est"][i], float))
        # Kalman angle past the threshold on the push's side (> 0: crossed), deg
        if d == "back":
            past = phi.max() - math.degrees(cparams.eps_forward)
        else:
            past = -math.degrees(cparams.eps_backward) - phi.min()
        res[(d, b, control)] = dict(
            fell=fell, rec=float(out["recovery_time_s"][i]),
            step_cm=0.0 if fell or abs(step) < 0.005 else 100 * step,
            peak_deg=float(out["peak_incl_deg"][i]), phi_peak_deg=float(past),
            phi_max_deg=float(phi.max()), phi_min_deg=float(phi.min()),
            stand_deg=float(out["standing_pitch_deg"][i]),
            x_sup_cm=100 * float(out["capture_point_m"][i]))
    return res


def evaluate(x, readings=tuple(P.READINGS), hit_phase_ms: float = 0.0) -> dict:
    """{reading: {row key: sim dict}} for parameter vector (or dict) x, at one hit phase."""
    return evaluate_phases(x, readings, (hit_phase_ms,))[hit_phase_ms]


def evaluate_phases(x, readings=tuple(P.READINGS), hit_phases_ms=(0.0,)) -> dict:
    """{hit phase ms: {reading: {row key: sim dict}}} for parameter vector (or dict) x."""
    mp = P.model_params(x)
    phases = tuple(float(ph) for ph in hit_phases_ms)
    pushes = pushes_for(x, phases)
    n = len(CASES) * len(phases)
    c0 = P.controller_params(x, next(iter(P.READINGS)), mp)
    s, o = _simulate(pushes, np.zeros(n, np.float32), c0, mp)
    off = [_rows(s, o, "off", c0, len(CASES) * k) for k in range(len(phases))]
    out = {ph: {} for ph in phases}
    for r in readings:
        cp = P.controller_params(x, r, mp)
        s, o = _simulate(pushes, np.ones(n, np.float32), cp, mp)
        for k, ph in enumerate(phases):
            out[ph][r] = {**off[k], **_rows(s, o, "on", cp, len(CASES) * k)}
    return out


def stand_penalty(res: dict) -> float:
    from tkujax.studies.calibrate.targets import STAND_LEAN_DEG
    lean = np.mean([v["stand_deg"] for v in res.values()])
    lo, hi = STAND_LEAN_DEG
    return 20.0 * (max(0.0, lo - lean) + max(0.0, lean - hi))
