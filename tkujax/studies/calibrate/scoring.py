"""Scoring one calibration candidate: its simulated rows against the paper's Tables 4-5, the
loss per objective and reading, and the paper-outcome criterion (`criterion_shortfall`)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from tkujax.studies.calibrate import paper_rows as E
from tkujax.studies.calibrate import targets as T

OBJECTIVE_ROWS = {"ALL": T.ROWS, "T4": T.TABLE4}
CRITERION_P = 0.8                     # the paper's outcome in >= 80 % of the trials
FAILED_LOSS = 1e3                     # an invalid candidate (the model refused it): a penalty

# evaluator(x: dict, readings, hit_phases_ms) -> {phase: {reading: {row key: sim dict}}}
Evaluator = Callable[[dict, tuple, tuple], dict]


def row_key(k) -> str:
    return "/".join(k)


def phase_key(ph) -> str:
    """The archive key of a sample (a hit phase in ms, or an evaluate.Sample)."""
    return E.sample_key(ph)


def expected_rows(res: dict, samples, reading: str) -> dict:
    """Per paper row, over the samples (hit phase x contact time, each one trial the paper
    could have run): the probability of the paper's fall outcome, and, over the trials that
    stand, the mean step (cm) and the fraction stepping the paper's way."""
    out = {}
    for key, (rec_p, step_p) in T.PAPER_TABLE.items():
        rows = [res[s][reading][key] for s in samples]
        p_ok = float(np.mean([r["fell"] == (rec_p is None) for r in rows]))
        stood = [r for r in rows if not r["fell"]]
        e = dict(p_paper=p_ok)
        if step_p is not None and stood:
            sign = 1.0 if key[0] == "back" else -1.0
            e.update(step_mean_cm=float(np.mean([r["step_cm"] for r in stood])),
                     p_step_paper_way=float(np.mean([sign * r["step_cm"] >= 0.5
                                                      for r in stood])),
                     p_step_wrong_way=float(np.mean([sign * r["step_cm"] <= -0.5
                                                      for r in stood])))
        out[row_key(key)] = e
    return out


def criterion_shortfall(expected: dict, rows) -> float:
    """The calibration's acceptance as a penalty (sum over `rows`): per row, how far the probability
    of the paper's fall outcome is below 0.8; for the rows where the paper steps, the
    probability of standing and stepping (>= 5 mm) *against* the paper's way (every step must
    go the paper's way; a missing step is the table loss's business)."""
    total = 0.0
    for key in rows:
        e = expected[row_key(key)]
        total += max(0.0, CRITERION_P - e["p_paper"])
        if T.PAPER_TABLE[key][1] is not None:
            total += e["p_paper"] * e.get("p_step_wrong_way", 0.0)
    return total


def score(x: dict, readings, hit_phases_ms, evaluator: Evaluator | None = None,
          results: dict | Exception | None = None, criterion_weight: float = 0.0) -> dict:
    """Simulate candidate x (all names) and score it: the archive record.

    hit_phases_ms: the samples (hit phases in ms, or evaluate.Sample with a contact time).
    loss[objective][reading] = mean over samples of (stand-lean penalty + table loss): the
    expected loss of a trial at an unknown hit phase and contact time; plus criterion_weight x
    criterion_shortfall (0: none). results: the evaluation, already made (a batched backend);
    None: made here with `evaluator`."""
    evaluator = evaluator or E.evaluate_phases
    samples = tuple(hit_phases_ms)
    try:
        if isinstance(results, Exception):
            raise results
        res = results if results is not None else evaluator(x, tuple(readings), samples)
    except Exception as err:  # noqa: BLE001  (an invalid model: a penalty, not a crash)
        return dict(x=x, error=repr(err),
                    loss={o: {r: FAILED_LOSS for r in readings} for o in OBJECTIVE_ROWS})
    loss = {o: {r: 0.0 for r in readings} for o in OBJECTIVE_ROWS}
    pens = []
    for ph in samples:
        pen = E.stand_penalty(res[ph][readings[0]])
        pens.append(pen)
        for o, rows in OBJECTIVE_ROWS.items():
            for r in readings:
                loss[o][r] += (pen + T.table_loss(res[ph][r], rows)[0]) / len(samples)
    expected = {r: expected_rows(res, samples, r) for r in readings}
    if criterion_weight:
        for o, rows in OBJECTIVE_ROWS.items():
            for r in readings:
                loss[o][r] += criterion_weight * criterion_shortfall(expected[r], rows)
    return dict(x=x, loss=loss, stand_penalty=float(np.mean(pens)), expected=expected,
                rows={phase_key(ph): {r: {row_key(k): compact_row(v)
                                           for k, v in res[ph][r].items()}
                                       for r in readings} for ph in samples})


def compact_row(row: dict) -> dict:
    """A row with its floats at 5 significant digits (the archive holds every sample's rows)."""
    return {k: (float(f"{v:.5g}") if isinstance(v, float) else v) for k, v in row.items()}
