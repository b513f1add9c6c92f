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
from typing import NamedTuple

import numpy as np

from tkujax.sim import push as push_lib
from tkujax.studies.calibrate import fit_vector as P

CASES = [(d, b) for d in ("back", "front") for b in ("baseball", "volleyball")]


def simulate_cases(pushes, enabled, cparams, mparams):
    """The pushes on MuJoCo C (threads: TKUJAX_CAL_THREADS): (series, outcomes)."""
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


class Sample(NamedTuple):
    """One trial condition the paper leaves unknown: the hit phase after the controller tick
    (ms) and the ball's contact time (ms, the push's half-sine duration)."""

    phase_ms: float
    contact_ms: float = 1e3 * push_lib.DEFAULT_DURATION_S


def as_sample(s) -> Sample:
    """A Sample from a Sample, a (phase, contact) pair or a bare hit phase (ms)."""
    if isinstance(s, Sample):
        return s
    if isinstance(s, (tuple, list)):
        return Sample(float(s[0]), float(s[1]))
    return Sample(float(s))


def sample_key(s) -> str:
    """The archive's key of a sample: "PHASE" at the default contact time (the key of
    single-contact fits), "PHASE@CONTACTms" otherwise."""
    s = as_sample(s)
    if s.contact_ms == Sample(0.0).contact_ms:
        return f"{s.phase_ms:g}"
    return f"{s.phase_ms:g}@{s.contact_ms:g}ms"


def pushes_for(x, samples=(0.0,)) -> object:
    """The 4 ball cases (CASES order) per sample (a hit phase in ms, or a Sample):
    sample-major, 4 * len(samples) pushes."""
    v = P.complete(P.as_dict(x) if not isinstance(x, dict) else x)
    # push_height_m and impulse_factor are the hit from behind; the front hit is set relative
    # to it (params.py: front_height_offset_m, front_impulse_ratio; neutral: the same hit), and
    # BallContact keeps its contact on the chest (a box of (height, offset) can reach past it).
    contact = push_lib.BallContact(
        float(v["push_height_m"]), float(v["impulse_factor"]),
        float(v["front_height_offset_m"]), float(v["front_impulse_ratio"]))
    return push_lib.stack_pushes([
        contact.push(b, d, onset_s=hit_onset_s(s.phase_ms), duration_s=1e-3 * s.contact_ms)
        for s in map(as_sample, samples) for d, b in CASES])


def row_result(direction: str, fell: bool, step_m: float, rec_s: float, peak_deg: float,
               phi_max_deg: float, phi_min_deg: float, stand_deg: float, x_sup_m: float,
               cparams) -> dict:
    """One simulated paper row as the loss reads it (both backends build it here)."""
    # Kalman angle past the threshold on the push's side (> 0: crossed), deg
    if direction == "back":
        past = phi_max_deg - math.degrees(cparams.eps_forward)
    else:
        past = -math.degrees(cparams.eps_backward) - phi_min_deg
    return dict(fell=bool(fell), rec=float(rec_s),
                step_cm=0.0 if fell or abs(step_m) < 0.005 else 100 * float(step_m),
                peak_deg=float(peak_deg), phi_peak_deg=float(past),
                phi_max_deg=float(phi_max_deg), phi_min_deg=float(phi_min_deg),
                stand_deg=float(stand_deg), x_sup_cm=100 * float(x_sup_m))


def case_rows(series, out, control, cparams, offset: int = 0) -> dict:
    """The paper's rows {(direction, ball, control): row} of CASES from rollout `offset` on."""
    res = {}
    for j, (d, b) in enumerate(CASES):
        i = offset + j
        phi = np.degrees(np.asarray(series["pitch_est"][i], float))
        res[(d, b, control)] = row_result(
            d, out["fell"][i], out["step_length_m"][i], out["recovery_time_s"][i],
            out["peak_incl_deg"][i], phi.max(), phi.min(), out["standing_pitch_deg"][i],
            out["capture_point_m"][i], cparams)
    return res


def evaluate(x, readings=tuple(P.READINGS), hit_phase_ms: float = 0.0) -> dict:
    """{reading: {row key: sim dict}} for parameter vector (or dict) x, at one hit phase."""
    return evaluate_phases(x, readings, (hit_phase_ms,))[hit_phase_ms]


def evaluate_phases(x, readings=tuple(P.READINGS), hit_phases_ms=(0.0,)) -> dict:
    """{sample: {reading: {row key: sim dict}}} for parameter vector (or dict) x, keyed by the
    items of `hit_phases_ms` (hit phases in ms, or Samples with a contact time too)."""
    mp = P.model_params(x)
    keys = tuple(hit_phases_ms)
    pushes = pushes_for(x, keys)
    n = len(CASES) * len(keys)
    c0 = P.controller_params(x, next(iter(P.READINGS)), mp)
    s, o = simulate_cases(pushes, np.zeros(n, np.float32), c0, mp)
    off = [case_rows(s, o, "off", c0, len(CASES) * k) for k in range(len(keys))]
    out = {ph: {} for ph in keys}
    for r in readings:
        cp = P.controller_params(x, r, mp)
        s, o = simulate_cases(pushes, np.ones(n, np.float32), cp, mp)
        for k, ph in enumerate(keys):
            out[ph][r] = {**off[k], **case_rows(s, o, "on", cp, len(CASES) * k)}
    return out


def stand_penalty(res: dict) -> float:
    from tkujax.studies.calibrate.targets import STAND_LEAN_DEG
    lean = np.mean([v["stand_deg"] for v in res.values()])
    lo, hi = STAND_LEAN_DEG
    return 20.0 * (max(0.0, lo - lean) + max(0.0, lean - hi))
