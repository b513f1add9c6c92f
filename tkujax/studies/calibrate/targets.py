"""The paper's measured targets (Tables 4-5, Sec. 4) and the loss of one simulated row."""

from __future__ import annotations

import math

# (direction, ball, control) -> (recovery time s or None = fell, step length cm or None = X)
PAPER_TABLE = {
    ("back", "baseball", "off"): (0.60, None), ("back", "baseball", "on"): (0.25, 1.36),
    ("back", "volleyball", "off"): (None, None), ("back", "volleyball", "on"): (0.25, 4.15),
    ("front", "baseball", "off"): (0.65, None), ("front", "baseball", "on"): (0.20, 1.09),
    ("front", "volleyball", "off"): (0.97, None), ("front", "volleyball", "on"): (0.37, 3.88),
}
ROWS = list(PAPER_TABLE)
TABLE4 = [r for r in ROWS if r[0] == "back"]
TABLE5 = [r for r in ROWS if r[0] == "front"]
STAND_LEAN_DEG = (6.0, 8.0)          # 7 deg +- 1 deg [paper Sec. 4], hard constraint

# acceptance tolerances of the paper-table calibration
STEP_TOL = 0.30                       # +-30 % of the paper's step length
REC_TOL = 0.50                        # +-50 % of the paper's no-control recovery time

W_FALL = 10.0                         # a wrong fall outcome
W_NO_STEP = 4.0                       # a step expected, none taken (~ a 60 % step error)
W_ON_REC = 0.25                       # weak: control-on recovery time vs paper (not a target)
W_ORDER = 2.0                         # control on must recover faster than off


def row_loss(key, sim: dict) -> tuple[float, dict]:
    """Loss of one simulated row against the paper.

    sim: fell (bool), rec (s, nan = not settled), step_cm (0 = none), peak_deg (true incl.
    deviation), phi_peak_deg (Kalman angle excursion past the relevant threshold, signed so that
    > 0 means crossed). Returns (loss, terms)."""
    rec_p, step_p = PAPER_TABLE[key]
    terms = {}
    if rec_p is None:                                   # the paper's robot fell
        # graded: the nearer to falling (peak tilt toward 45 deg) the smaller the penalty
        terms["fall"] = 0.0 if sim["fell"] else W_FALL * (
            0.5 + 0.5 * max(0.0, 1 - sim["peak_deg"] / 45.0))
        return sum(terms.values()), terms
    if sim["fell"]:
        terms["fall"] = W_FALL
        return sum(terms.values()), terms
    rec = sim["rec"]
    if key[2] == "off":
        terms["rec"] = 4.0 if not math.isfinite(rec) else (
            math.log(max(rec, 0.03) / rec_p) / math.log(1 + REC_TOL)) ** 2
    else:
        terms["rec"] = W_ON_REC * (2.0 if not math.isfinite(rec) else
                                   (math.log(max(rec, 0.03) / rec_p) / math.log(2.0)) ** 2)
    if step_p is not None:
        step = abs(sim["step_cm"])
        sign_ok = (sim["step_cm"] > 0) == (key[0] == "back")
        if step < 0.5 or not sign_ok:
            # graded by how far the Kalman angle stayed from the threshold (deg)
            terms["step"] = W_NO_STEP + 0.1 * max(0.0, -sim["phi_peak_deg"])
        else:
            terms["step"] = ((step - step_p) / (STEP_TOL * step_p)) ** 2
    return sum(terms.values()), terms


def table_loss(results: dict, rows=ROWS) -> tuple[float, dict]:
    """Sum of row losses over `rows` plus the on-faster-than-off ordering term."""
    total, per = 0.0, {}
    for key in rows:
        loss, terms = row_loss(key, results[key])
        per[key] = (loss, terms)
        total += loss
    for d, b, c in rows:
        if c != "on" or (d, b, "off") not in rows:
            continue
        on, off = results[(d, b, "on")], results[(d, b, "off")]
        if not on["fell"] and not off["fell"] and math.isfinite(off["rec"]):
            r_on = on["rec"] if math.isfinite(on["rec"]) else 9.0
            if r_on >= off["rec"]:
                total += W_ORDER * (1.0 + (r_on - off["rec"]) / max(off["rec"], 0.03))
    return total, per


def score(results: dict, rows=ROWS) -> dict:
    """The acceptance counters of the paper-table calibration on `rows`."""
    falls = sum((results[k]["fell"]) == (PAPER_TABLE[k][0] is None) for k in rows)
    steps_ok = steps_n = recs_ok = recs_n = order_ok = order_n = 0
    for k in rows:
        rec_p, step_p = PAPER_TABLE[k]
        s = results[k]
        if step_p is not None:
            steps_n += 1
            steps_ok += (not s["fell"]) and abs(abs(s["step_cm"]) - step_p) <= STEP_TOL * step_p \
                and (s["step_cm"] > 0) == (k[0] == "back")
        if rec_p is not None and k[2] == "off":
            recs_n += 1
            recs_ok += ((not s["fell"]) and math.isfinite(s["rec"])
                        and abs(s["rec"] - rec_p) <= REC_TOL * rec_p)
        if k[2] == "on" and (k[0], k[1], "off") in rows:
            off = results[(k[0], k[1], "off")]
            if not s["fell"] and not off["fell"]:
                order_n += 1
                order_ok += math.isfinite(s["rec"]) and (not math.isfinite(off["rec"])
                                                         or s["rec"] < off["rec"])
    return dict(falls=f"{falls}/{len(rows)}", steps=f"{steps_ok}/{steps_n}",
                recoveries=f"{recs_ok}/{recs_n}", on_faster=f"{order_ok}/{order_n}")
