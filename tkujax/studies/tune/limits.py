"""The limits of a tune spec, checked once it is parsed and before anything is simulated, as a
sweep's are (`tkujax.dialects.push_limits`): no push that a horizon cannot hold (the training
horizon tune.duration_s, nor the held-out one evaluate.duration_s: onset + pulse within each,
and time left after the onset), and no record set above MAX_RECORDS (one generation's
rollouts, popsize x batch; the evaluation grid; the held-out pushes).
"""

from __future__ import annotations

import numpy as np

from tkujax.dialects.push_limits import check_push_end, check_record_cap
from tkujax.dialects.validation import SpecError

# Time a tune's horizon keeps after its latest onset (the fall shows within it).
AFTER_ONSET_S = 0.03


def highest(value) -> float:
    """The largest value a push field of a tune spec takes: a (lo, hi) range, a list, a number."""
    return float(value[1] if isinstance(value, tuple) else np.max(np.atleast_1d(value)))


def check_tune_limits(tune: dict, push: dict, evaluate: dict, tables: dict | None = None
                      ) -> None:
    """SpecError naming the key and the limit (module doc). tune: the [tune] fields; push: the
    parsed [push]; evaluate: the [evaluate] fields (eval_*); tables: the parsed [compare] and
    [study] tables by name (their own popsize and eval_n)."""
    onset_hi, pulse_hi = highest(push["onset_s"]), highest(push["duration_s"])
    for key, horizon in (("tune.duration_s", tune["duration_s"]),
                         ("evaluate.duration_s", evaluate["eval_duration_s"])):
        if onset_hi + AFTER_ONSET_S >= horizon:
            raise SpecError(f"push.onset_s: onsets up to {onset_hi} s leave no time after the "
                            f"push within {key} = {horizon} s (allowed: onset < "
                            f"{key} - {AFTER_ONSET_S} s)")
        check_push_end(f"push.onset_s + push.duration_s (latest onset {onset_hi:.6g} s, longest "
                       f"pulse {pulse_hi:.6g} s)", onset_hi + pulse_hi, key, horizon)
    check_record_cap("tune.popsize x tune.batch", tune["popsize"] * tune["batch"],
                     "one generation's rollouts")
    check_record_cap("evaluate.impulse_ns x evaluate.azimuth_deg",
                     len(evaluate["eval_impulse_ns"]) * len(evaluate["eval_azimuth_deg"]),
                     "the evaluation grid")
    check_record_cap("evaluate.n", evaluate["eval_n"], "the held-out pushes")
    for name, table in (tables or {}).items():
        if table and "popsize" in table:
            check_record_cap(f"{name}.popsize x tune.batch", table["popsize"] * tune["batch"],
                             "one generation's rollouts")
        if table and "eval_n" in table:
            check_record_cap(f"{name}.eval_n", table["eval_n"], "the held-out pushes")
