"""One candidate parameter vector -> the paper's 8 rows, for every reading of Algorithm 1.

MuJoCo C physics (tkujax.backend_mujoco), noise-free, the JAX controller. The 4 control-off
rows do not depend on the reading and run once; the 4 control-on rows run once per reading.
"""

from __future__ import annotations

import math

import numpy as np

from tkujax.sim import push as push_lib
from tkujax.studies.calibrate import params as P
from tkujax.studies.calibrate.targets import PAPER_TABLE, ROWS

CASES = [(d, b) for d in ("back", "front") for b in ("baseball", "volleyball")]


def _simulate(pushes, enabled, cparams, mparams):
    from tkujax.sim.rollout_mujoco import simulate_mujoco
    import os
    threads = os.environ.get("TKUJAX_CAL_THREADS")   # 1 per worker in a parallel search
    return simulate_mujoco(pushes, enabled, cparams, model_params=mparams,
                           n_threads=int(threads) if threads else None)


def pushes_for(x) -> object:
    v = P.as_dict(x) if not isinstance(x, dict) else x
    return push_lib.stack_pushes([
        push_lib.make_push(v["impulse_factor"] * push_lib.ball_momentum_ns(b),
                           push_lib.DIRECTIONS[d], height_m=float(v["push_height_m"]))
        for d, b in CASES])


def _rows(series, out, control, cparams) -> dict:
    res = {}
    for i, (d, b) in enumerate(CASES):
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


def evaluate(x, readings=tuple(P.READINGS)) -> dict:
    """{reading: {row key: sim dict}} for parameter vector (or dict) x."""
    mp = P.model_params(x)
    pushes = pushes_for(x)
    n = len(CASES)
    c0 = P.controller_params(x, next(iter(P.READINGS)), mp)
    s, o = _simulate(pushes, np.zeros(n, np.float32), c0, mp)
    off = _rows(s, o, "off", c0)
    out = {}
    for r in readings:
        cp = P.controller_params(x, r, mp)
        s, o = _simulate(pushes, np.ones(n, np.float32), cp, mp)
        out[r] = {**off, **_rows(s, o, "on", cp)}
    return out


def stand_penalty(res: dict) -> float:
    from tkujax.studies.calibrate.targets import STAND_LEAN_DEG
    lean = np.mean([v["stand_deg"] for v in res.values()])
    lo, hi = STAND_LEAN_DEG
    return 20.0 * (max(0.0, lo - lean) + max(0.0, lean - hi))
