"""A whole generation of candidate robots on MJX in one compiled call: candidates x the paper's
8 rows x samples (hit phase, contact time) x readings of Algorithm 1.

Each candidate is its own robot (`tkujax.sim.robots`: compiled and settled by MuJoCo, only the
fields the fit moves vary), with its own controller parameters (the Kalman noises, the
pendulum lengths of its model, the reading). The 4 control-off rows do not depend on the reading
and run once per sample. The result per candidate has the form of `evaluate.evaluate_phases`,
so the loss and the report are shared with the CPU path.

One program serves every generation of a fit: the robots' varying fields are fixed once from
the bounds' corners, and the batch is padded to a whole number of `robots_per_call` robots.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from tkujax.sim import robots as robots_lib
from tkujax.sim.rollout_mjx import Episode, RolloutConfig, rollout
from tkujax.studies.calibrate import paper_rows as E
from tkujax.studies.calibrate import fit_vector as P

ROLLOUT = RolloutConfig(duration_s=2.4)         # as the C backend's paper rows


def _template() -> dict:
    """Robot 0 of every call: the base model's vector, so the base trees (and the static parts
    of the compiled program) never change between generations."""
    return P.as_dict(P.base_vector())


_LEAF_IDS: dict[tuple[str, ...], tuple[tuple[int, ...], tuple[int, ...]]] = {}


def _leaf_ids(names: tuple[str, ...]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The model and stand-state fields that the parameters `names` move: probed once at the
    bounds' corners and 8 random points inside them (a field the probe missed is added when a
    candidate moves it: `_evaluate_chunk`)."""
    if names not in _LEAF_IDS:
        base = _template()
        rng = np.random.default_rng(0)
        probes = [P.model_params(base)]
        for corner in [P.LO, P.HI] + [P.LO + rng.uniform(0, 1, len(P.LO)) * (P.HI - P.LO)
                                      for _ in range(8)]:
            x = dict(base)
            for n in names:
                x[n] = float(corner[P.NAMES.index(n)])
            try:
                probes.append(P.model_params(x))
            except ValueError:
                pass                                  # a corner the model refuses
        _LEAF_IDS[names] = robots_lib.varying_leaves(probes)
    return _LEAF_IDS[names]


@functools.lru_cache(maxsize=4)
def _program(ids: tuple[tuple[int, ...], tuple[int, ...]], config: RolloutConfig):
    """jit(vmap) of one paper-row rollout over (robot, push, enabled, controller-parameter row).

    The base trees, the robots' values and the parameter table are arguments (a new generation
    reuses the compiled program); `ids` (the varying fields) are static."""
    from tkujax.sim.metrics import outcomes
    from tkujax.sim.setup import model_index

    index = model_index(P.model_params(_template()))   # the same for every robot (robot_set)

    def one(base_model, base_state, values, table, robot_id, push, enabled, param_row):
        model = robots_lib.put_leaves(base_model, ids[0], values[0], robot_id)
        state = robots_lib.put_leaves(base_state, ids[1], values[1], robot_id)
        params = jax.tree_util.tree_map(lambda v: v[param_row], table)
        series = rollout(model, state, Episode(push, enabled, jax.random.PRNGKey(0)), params,
                         config=config, index=index)
        out = outcomes(series, push.onset_s)
        return dict(fell=out["fell"], step_length_m=out["step_length_m"],
                    recovery_time_s=out["recovery_time_s"], peak_incl_deg=out["peak_incl_deg"],
                    standing_pitch_deg=out["standing_pitch_deg"],
                    capture_point_m=out["capture_point_m"],
                    phi_max_deg=jnp.degrees(jnp.max(series["pitch_est"])),
                    phi_min_deg=jnp.degrees(jnp.min(series["pitch_est"])))

    return jax.jit(jax.vmap(one, in_axes=(None, None, None, None, 0, 0, 0, 0)))


def _stack_params(params: list):
    """A table of ControllerParams, one row per entry (float32 leaves)."""
    return jax.tree_util.tree_map(lambda *v: jnp.asarray(np.array(v, np.float32)), *params)


def evaluate_many(xs: list[dict], readings: tuple[str, ...], samples: tuple,
                  names: tuple[str, ...] = P.NAMES, robots_per_call: int = 32,
                  config: RolloutConfig = ROLLOUT) -> list:
    """[{sample: {reading: {row key: sim dict}}} or an Exception] per candidate of `xs`.

    names: the fitted parameters (their bounds fix the program's varying fields). A candidate
    the model refuses gets its exception in its place (a penalty for the search, not a crash).
    Robots go `robots_per_call` at a time, padded: one compiled program for a whole fit."""
    samples = tuple(E.as_sample(s) for s in samples)
    results: list = [None] * len(xs)
    mps = {}
    for i, x in enumerate(xs):
        try:
            mps[i] = P.model_params(x)
        except Exception as err:  # noqa: BLE001  (the model refused it)
            results[i] = err
    ok = list(mps)
    per = max(1, int(robots_per_call))
    for start in range(0, len(ok), per):
        chunk = ok[start:start + per]
        cx, cm = [xs[i] for i in chunk], [mps[i] for i in chunk]
        try:
            out = _evaluate_chunk(cx, cm, readings, samples, _leaf_ids(tuple(names)), per,
                                  config)
        except robots_lib.UnlistedFieldError:
            # a field the probe did not see move: vary it too from now on (one recompile)
            m_ids, s_ids = robots_lib.varying_leaves([P.model_params(_template())] + cm)
            old_m, old_s = _leaf_ids(tuple(names))
            _LEAF_IDS[tuple(names)] = (tuple(sorted(set(old_m) | set(m_ids))),
                                       tuple(sorted(set(old_s) | set(s_ids))))
            out = _evaluate_chunk(cx, cm, readings, samples, _leaf_ids(tuple(names)), per,
                                  config)
        for i, res in zip(chunk, out):
            results[i] = res
    return results


def _evaluate_chunk(xs, mps, readings, samples, ids, per, config) -> list:
    pad = per - len(xs)
    robots = robots_lib.robot_set([P.model_params(_template())] + mps + [mps[-1]] * pad,
                                  model_leaf_ids=ids[0], state_leaf_ids=ids[1])
    n_cases = len(E.CASES)
    n_push = n_cases * len(samples)
    pushes, enabled, table, param_row, robot_id, where = [], [], [], [], [], []
    cps = [{r: P.controller_params(x, r, mp) for r in readings} for x, mp in zip(xs, mps)]
    for j, (x, by_reading) in enumerate(list(zip(xs, cps)) + [(xs[-1], cps[-1])] * pad):
        ps = E.pushes_for(x, samples)                 # sample-major, CASES order
        settings = ([("off", 0.0, by_reading[readings[0]])]
                    + [(r, 1.0, by_reading[r]) for r in readings])
        for setting, on, cp in settings:
            pushes.append(ps)
            enabled += [on] * n_push
            param_row += [len(table)] * n_push
            table.append(cp)
            robot_id += [j + 1] * n_push              # robot 0 is the template
            where += [(j, setting, k // n_cases, k % n_cases) for k in range(n_push)]
    push = jax.tree_util.tree_map(lambda *v: jnp.concatenate(v), *pushes)
    out = _program(robots.structure, config)(
        robots.base_model, robots.base_state, robots.values(), _stack_params(table),
        jnp.asarray(robot_id, jnp.int32), push, jnp.asarray(enabled, jnp.float32),
        jnp.asarray(param_row, jnp.int32))
    out = {k: np.asarray(v) for k, v in out.items()}
    return _collect(out, where, xs, cps, readings, samples)


def _collect(out, where, xs, cps, readings, samples) -> list:
    res = [{s: {r: {} for r in readings} for s in samples} for _ in xs]
    off_rows = [{s: {} for s in samples} for _ in xs]
    for n, (j, setting, si, ci) in enumerate(where):
        if j >= len(xs):
            continue                                  # padding
        d, b = E.CASES[ci]
        cp = cps[j][readings[0] if setting == "off" else setting]
        row = E.row_result(d, out["fell"][n], out["step_length_m"][n],
                           out["recovery_time_s"][n], out["peak_incl_deg"][n],
                           out["phi_max_deg"][n], out["phi_min_deg"][n],
                           out["standing_pitch_deg"][n], out["capture_point_m"][n], cp)
        s = samples[si]
        if setting == "off":
            off_rows[j][s][(d, b, "off")] = row
        else:
            res[j][s][setting][(d, b, "on")] = row
    for j in range(len(xs)):
        for s in samples:
            for r in readings:
                res[j][s][r].update(off_rows[j][s])
    return res


def evaluator(names: tuple[str, ...] = P.NAMES, robots_per_call: int = 32):
    """An Evaluator (run.py's form: one candidate at a time) backed by the MJX batch; the
    calibration calls `evaluate_many` for whole generations."""
    def one(x, readings, samples):
        r = evaluate_many([x], tuple(readings), tuple(samples), names, robots_per_call)[0]
        if isinstance(r, Exception):
            raise r
        return r
    return one

