"""Tune specs: the TOML schema, validation, and the push batches drawn from it.

Robot ensembles (train on the training distribution, and on the robot ensemble):
  [randomize] ensemble = "PATH"        training pushes, and the held-out pushes of the training
                                       distribution, each run on one member drawn uniformly
  [evaluate.shift] ensemble = "PATH"   the shifted held-out set runs on the ensemble's members
The file is an ensemble of `tkujax calibrate` (tkujax.model.ensemble), read and validated here,
its path relative to the current directory; its sha256 is recorded with the tune's outputs
(`ensembles_record`). The other [randomize] / [evaluate.shift] keys apply on top of the member,
as in sweeps. [evaluate.shift] replaces [randomize] as a whole, the ensemble included: a shift
without its own ensemble key runs on the default robot.

Robot table (`robot_table`): when either key is given, every push record carries a robot_id
column (ROBOT_ID_COLUMN), the row of the problem's RobotSet: 0 = the default robot (the spec's
model), 1..n = the members of the training ensemble, then the members of the shift's ensemble
when it is another file. Record sets with no ensemble of their own (the grid, a shift without
one) carry robot_id 0. One compiled program thus runs every set. The member is drawn with the
set's seed after every other draw, so specs without an ensemble draw exactly the pushes they
drew before, and adding one changes no other column.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

import numpy as np

from tkujax.control.controller_params import ControllerParams
from tkujax.control.params_files import allowed_range, controller_params_from
from tkujax.model.model_params import ModelParams
from tkujax.dialects.sweep_spec import (CONTROLLER_FIELDS, ENSEMBLE_KEY, PUSH_FIELDS,
                                        RANDOMIZE_DEFAULTS, RANDOMIZE_FIELDS, ROBOT_ID_COLUMN,
                                        EnsembleRef, controller_value, parse_ensemble,
                                        parse_randomize)
from tkujax.studies.tune.limits import check_tune_limits
from tkujax.studies.tune.loss import LossConfig, parse_loss
from tkujax.studies.tune.parameterisations import DEFAULT_SCHEDULE, PolicyReparam
from tkujax.studies.tune.problem import RECORD_KEYS, TuneProblem
from tkujax.studies.tune.reparam import DEFAULT_TUNED, TUNABLE, Reparam, check_start
from tkujax.studies.tune.search import parse_gradient_options
from tkujax.studies.tune.searchers import METHODS
from tkujax.studies.tune.start_policy import check_start_policy, policy_start
from tkujax.studies.tune.tune_spec_tables import parse_compare, parse_study, policy_name
from tkujax.dialects.validation import (SpecError, boolean, integer, number, read_toml,
                                        robot_file_of, table, uniform, values)


@dataclasses.dataclass(frozen=True)
class TuneSpec:
    name: str
    seed: int
    iterations: int
    batch: int
    duration_s: float
    learning_rate: float
    clip_norm: float
    params: tuple[str, ...]
    ranges: dict[str, tuple[float, float]]
    float64: bool
    remat: bool
    quantise_targets: bool
    anneal: tuple[float, float, str]                 # start_deg, end_deg, schedule
    loss: LossConfig
    push: dict[str, Any]                             # field -> value | (lo, hi) | list
    azimuth_jitter_deg: float
    controller: dict[str, float]
    randomize: dict[str, Any]
    baseline_sigma: float
    baseline_seed: int
    baseline_temperature_deg: float
    eval_seed: int
    eval_n: int
    eval_impulse_ns: np.ndarray
    eval_azimuth_deg: np.ndarray
    eval_duration_s: float
    raw: dict
    method: str = "cma"                              # what `tkujax tune` runs (search.py)
    popsize: int = 9                                 # CMA-ES population (odd)
    compare: dict | None = None                      # [compare]: methods x seeds, one budget
    shift: dict | None = None                        # [evaluate.shift]: model/push shift
    # tune.policy (tkujax.studies.tune.parameterisations)
    policy: str = "scalars"
    schedule: tuple[str, ...] = DEFAULT_SCHEDULE     # tune.schedule: the scheduled fields
    sharpness: float = 4.0                           # tune.sharpness: sector softmax
    # Gradient options (module docstring of tkujax.studies.tune.problem / search); the
    # defaults leave every program as it was, except diagnose_every (gradient methods only).
    gradient_window_ticks: int | None = None         # truncated backpropagation windows
    timing_gradient: bool = False                    # with_timing_gradient in the loss
    bundle_sigma: float = 0.0                        # bundled gradients' noise (latent units)
    bundle_antithetic: bool = False
    diagnose_every: int = 10                         # gradient diagnostics; 0: off
    study: dict | None = None                        # [study]: policies x methods x seeds
    # [randomize] ensemble: the ensemble this spec's pushes draw their robot from (the shift's
    # after `shifted`); robot_table: the ensembles of the problem's robot table, in row order
    # (training, then the shift's if another file), the same for a spec and its `shifted`.
    ensemble: EnsembleRef | None = None
    robot_table: tuple[EnsembleRef, ...] = ()
    # [model]: ModelParams overrides of the default robot ({field: number}; {} = the embedded
    # default). A study that must stay on an earlier robot names it here.
    model: dict[str, float] = dataclasses.field(default_factory=dict)
    # Resolved once by parse_tune_spec: the [model] robot (None: the embedded default) and the
    # starting ControllerParams (the paper's with [controller] applied, validated).
    robot: ModelParams | None = dataclasses.field(default=None, compare=False, repr=False)
    start: ControllerParams | None = dataclasses.field(default=None, compare=False, repr=False)
    start_policy: str | None = None                  # tune.start_policy: the file, its Schedule
    start_schedule: Any = dataclasses.field(default=None, compare=False, repr=False)

    def model_params(self) -> ModelParams | None:
        """The [model] robot (None: the embedded default, ModelParams())."""
        return self.robot

    def reparam(self) -> Reparam:
        return Reparam.make(self.params, self.ranges)

    def policy_reparam(self, policy: str | None = None) -> PolicyReparam:
        """The latent layout of tune.policy (or of `policy`): scalars plus a schedule."""
        return PolicyReparam.make(self.reparam(), policy or self.policy, self.schedule,
                                  self.sharpness)

    def base_params(self) -> ControllerParams:
        """The starting ControllerParams (the paper's with [controller] applied)."""
        if self.start is None:
            return start_params(self.controller)
        return self.start


def start_params(controller: dict[str, float]) -> ControllerParams:
    """The paper's ControllerParams with the [controller] values applied, validated."""
    return controller_params_from(ControllerParams.paper(), controller).validate()


TUNE_FIELDS = {"name": str, "description": str, "seed": int, "iterations": int, "batch": int,
               "duration_s": (int, float), "learning_rate": (int, float),
               "clip_norm": (int, float), "params": list, "float64": bool, "remat": bool,
               "quantise_targets": bool,
               "anneal": dict, "loss": dict, "ranges": dict, "method": str,
               "popsize": int, "policy": str, "schedule": list, "sharpness": (int, float),
               "gradient_window_ticks": int, "timing_gradient": bool,
               "bundle_sigma": (int, float), "bundle_antithetic": bool, "diagnose_every": int,
               "start_policy": str}
TUNE_PUSH_FIELDS = set(PUSH_FIELDS) | {"azimuth_jitter_deg"}


def _parse_tune(data: dict) -> dict:
    """The [tune] table (without ranges, anneal and loss): TuneSpec fields by name."""
    tune = table("tune", data.get("tune", {}), TUNE_FIELDS)
    for k in ("name", "description"):
        if k in tune and not isinstance(tune[k], str):
            raise SpecError(f"tune.{k}: expected a string, got {tune[k]!r}")
    out = dict(
        name=tune.get("name", "tune"),
        seed=integer("tune.seed", tune.get("seed", 0), 0, 2**31 - 1),
        iterations=integer("tune.iterations", tune.get("iterations", 50), 1, 100_000),
        batch=integer("tune.batch", tune.get("batch", 64), 1, 1_048_576),
        duration_s=number("tune.duration_s", tune.get("duration_s", 1.5), 0.1, 30.0, "s"),
        learning_rate=number("tune.learning_rate", tune.get("learning_rate", 0.05), 1e-6, 10.0),
        clip_norm=number("tune.clip_norm", tune.get("clip_norm", 1.0), 1e-6, 1e6),
        float64=boolean("tune.float64", tune.get("float64", False)),
        remat=boolean("tune.remat", tune.get("remat", True)),
        quantise_targets=boolean("tune.quantise_targets", tune.get("quantise_targets", True)))
    params = tune.get("params", list(DEFAULT_TUNED))
    if (not isinstance(params, list) or not params or len(set(params)) != len(params)
            or any(p not in TUNABLE for p in params)):
        raise SpecError(f"tune.params: expected a non-empty list of distinct names from "
                        f"{sorted(TUNABLE)}, got {params!r}")
    out["params"] = tuple(params)
    out["ranges"] = _parse_ranges(tune)
    anneal = table("tune.anneal", tune.get("anneal", {}), {"start_deg", "end_deg", "schedule"})
    start = number("tune.anneal.start_deg", anneal.get("start_deg", 3.0), 1e-3, 30.0, "deg")
    end = number("tune.anneal.end_deg", anneal.get("end_deg", 0.5), 1e-3, start, "deg")
    schedule = anneal.get("schedule", "geometric")
    if schedule not in ("geometric", "linear"):
        raise SpecError(f"tune.anneal.schedule: expected 'geometric' or 'linear', got {schedule!r}")
    out["anneal"] = (start, end, schedule)
    out["loss"] = parse_loss(tune.get("loss", {}))
    out.update(parse_gradient_options(tune, out["batch"]))
    out["method"] = tune.get("method", "cma")
    if out["method"] not in METHODS + ("auto",):      # auto: tkujax.studies.tune.advice
        raise SpecError(f"tune.method: expected one of {list(METHODS) + ['auto']}, "
                        f"got {out['method']!r}")
    out["popsize"] = integer("tune.popsize", tune.get("popsize", 9), 3, 4096)
    if out["popsize"] % 2 == 0:
        raise SpecError(f"tune.popsize: expected an odd number, got {out['popsize']}")
    out["policy"] = policy_name("tune.policy", tune.get("policy", "scalars"))
    # Default: the fields of DEFAULT_SCHEDULE that are tuned (checked non-empty only when a
    # policy schedules, in parse_tune_spec).
    schedule = tune.get("schedule", [f for f in DEFAULT_SCHEDULE if f in params])
    if (not isinstance(schedule, list) or len(set(schedule)) != len(schedule)
            or any(f not in params for f in schedule)):
        raise SpecError(f"tune.schedule: expected a list of distinct names from "
                        f"tune.params {list(params)}, got {schedule!r}")
    if schedule:
        try:
            PolicyReparam.make(Reparam.make(params, out["ranges"]), "sectors2", schedule)
        except ValueError as e:
            raise SpecError(f"tune.schedule: {e}") from None
    out["schedule"] = tuple(schedule)
    out["sharpness"] = number("tune.sharpness", tune.get("sharpness", 4.0), 0.1, 100.0)
    return out


def _parse_ranges(tune: dict) -> dict[str, tuple[float, float]]:
    """tune.ranges: {field: (lo, hi)} in user units; each bound within the range
    ControllerParams.validate allows (positive on a log scale)."""
    ranges_raw = table("tune.ranges", tune.get("ranges", {}), {TUNABLE[f][0] for f in TUNABLE})
    by_key = {TUNABLE[f][0]: f for f in TUNABLE}
    ranges = {}
    for key, value in ranges_raw.items():
        f = by_key[key]
        log = TUNABLE[f][2]
        if not (isinstance(value, list) and len(value) == 2):
            raise SpecError(f"tune.ranges.{key}: expected [lo, hi] within ControllerParams."
                            f"{f} {allowed_range(f)}{' (> 0: log scale)' if log else ''}, "
                            f"got {value!r}")
        a = controller_value(f"tune.ranges.{key}[0]", key, value[0])
        b = controller_value(f"tune.ranges.{key}[1]", key, value[1])
        if log and a <= 0:
            raise SpecError(f"tune.ranges.{key}[0]: {a!r} must be > 0 (a log-scale parameter)")
        if not a < b:
            raise SpecError(f"tune.ranges.{key}: lower bound {a} must be below upper bound {b}")
        ranges[f] = (a, b)
    return ranges


def _parse_push(data: dict) -> tuple[dict, float]:
    """[push]: {field: value | (lo, hi) | list} and the azimuth jitter (deg)."""
    push_raw = table("push", data.get("push", {}), TUNE_PUSH_FIELDS)
    push = {}
    for k in PUSH_FIELDS:
        lo, hi, default, unit = PUSH_FIELDS[k]
        v = push_raw.get(k, default)
        key = f"push.{k}"
        if isinstance(v, dict):
            push[k] = uniform(key, v, lo, hi, unit)
        elif isinstance(v, list):
            push[k] = [float(x) for x in values(key, v, lo, hi, unit)]
        else:
            push[k] = number(key, v, lo, hi, unit)
    jitter = number("push.azimuth_jitter_deg", push_raw.get("azimuth_jitter_deg", 0.0),
                     0.0, 180.0, "deg")
    return push, jitter


def _parse_baseline(data: dict, seed: int, end_deg: float) -> dict:
    """[baseline]: the (1+1)-ES baseline's sigma, seed and gate temperature."""
    base = table("baseline", data.get("baseline", {}), {"method", "sigma", "seed",
                                                         "gate_temperature_deg"})
    if base.get("method", "es") != "es":
        raise SpecError(f"baseline.method: expected 'es' ((1+1) evolution strategy), "
                        f"got {base['method']!r}")
    return dict(
        baseline_sigma=number("baseline.sigma", base.get("sigma", 0.5), 1e-4, 10.0,
                               "(latent units)"),
        baseline_seed=integer("baseline.seed", base.get("seed", seed), 0, 2**31 - 1),
        baseline_temperature_deg=number("baseline.gate_temperature_deg",
                                         base.get("gate_temperature_deg", end_deg),
                                         0.0, 30.0, "deg"))


def _parse_evaluate(ev: dict, seed: int, batch: int, duration: float) -> dict:
    """[evaluate]: the held-out pushes (seed differs from tune.seed)."""
    eseed = integer("evaluate.seed", ev.get("seed", seed + 1), 0, 2**31 - 1)
    if eseed == seed:
        raise SpecError(f"evaluate.seed: must differ from tune.seed ({seed}): held-out pushes "
                        "are never used for tuning")
    return dict(
        eval_seed=eseed,
        eval_n=integer("evaluate.n", ev.get("n", 4 * batch), 0, 10_000_000),
        eval_impulse_ns=values("evaluate.impulse_ns",
                                ev.get("impulse_ns", {"start": 0.2, "stop": 2.4, "num": 12}),
                                *PUSH_FIELDS["impulse_ns"][:2], "N·s"),
        eval_azimuth_deg=values("evaluate.azimuth_deg", ev.get("azimuth_deg", [0.0, 180.0]),
                                 *PUSH_FIELDS["azimuth_deg"][:2], "deg"),
        eval_duration_s=number("evaluate.duration_s", ev.get("duration_s", duration), 0.1,
                                30.0, "s"))


def parse_tune_spec(data: dict) -> TuneSpec:
    """Validate a parsed tune TOML document (SpecError names the key and the allowed range)."""
    table("top level", data, {"tune", "push", "controller", "randomize", "baseline", "evaluate",
                               "compare", "study", "model", "robot"})
    robot_file_of(data)             # checked here, resolved by tkujax.studies.tune.robot_table
    tune = _parse_tune(data)
    push, jitter = _parse_push(data)
    ctrl_raw = table("controller", data.get("controller", {}), CONTROLLER_FIELDS)
    controller = {k: controller_value(f"controller.{k}", k, v) for k, v in ctrl_raw.items()}
    rand = table("randomize", data.get("randomize", {}), set(RANDOMIZE_FIELDS) | {ENSEMBLE_KEY})
    ensemble = parse_ensemble(rand[ENSEMBLE_KEY]) if ENSEMBLE_KEY in rand else None
    randomize = parse_randomize({"randomize": {k: v for k, v in rand.items()
                                               if k != ENSEMBLE_KEY}})
    baseline = _parse_baseline(data, tune["seed"], tune["anneal"][1])
    ev = table("evaluate", data.get("evaluate", {}), {"seed", "n", "impulse_ns", "azimuth_deg",
                                                      "duration_s", "shift"})
    evaluate = _parse_evaluate(ev, tune["seed"], tune["batch"], tune["duration_s"])
    compare = parse_compare(data["compare"], tune["batch"]) if "compare" in data else None
    shift = _parse_shift(ev["shift"]) if "shift" in ev else None
    study = parse_study(data["study"], tune["batch"]) if "study" in data else None
    check_tune_limits(tune, push, evaluate, dict(compare=compare, study=study))
    robots = tuple(e for e in (ensemble, (shift or {}).get("ensemble")) if e is not None)
    robots = tuple(e for i, e in enumerate(robots) if e not in robots[:i])   # by content
    if robots and tune["float64"]:
        raise SpecError("tune.float64: an ensemble ([randomize] or [evaluate.shift] ensemble) "
                        "runs in float32; set tune.float64 = false")
    model, robot = _parse_model(data.get("model", {}))
    given = data.get("tune", {}).get("start_policy")
    start, schedule = policy_start(given, controller)
    if model and robots:
        raise SpecError("[model]: an ensemble ([randomize] or [evaluate.shift] ensemble) gives "
                        "the robots; remove [model] or the ensemble")
    spec = TuneSpec(**tune, push=push, azimuth_jitter_deg=jitter, controller=controller,
                    randomize=randomize, **baseline, **evaluate, raw=data, compare=compare,
                    shift=shift, study=study, ensemble=ensemble, robot_table=robots, model=model,
                    robot=robot, start=start, start_policy=given, start_schedule=schedule)
    for key, policy in [("tune.policy", spec.policy)] + [
            (f"study.policies[{i}]", p) for i, p in enumerate((study or {}).get("policies", []))]:
        if policy != "scalars" and not spec.schedule:
            raise SpecError(f"tune.schedule: {key} = {policy!r} schedules fields, but none of "
                            f"tune.params is scheduled (set tune.schedule)")
    if robot_file_of(data) is None:     # a robot's start is checked once it is resolved
        check_start(spec)
    check_start_policy(spec)
    return spec


def _parse_model(given) -> tuple[dict[str, float], ModelParams | None]:
    """[model]: ({ModelParams field: number}, the robot they make, None for no overrides),
    validated (unknown keys and out-of-range values raise SpecError naming the key)."""
    if not isinstance(given, dict):
        raise SpecError(f"[model]: expected a table of model parameters, got {given!r}")
    for k, v in given.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise SpecError(f"model.{k}: expected a number, got {v!r}")
    try:
        robot = ModelParams.from_overrides(dict(given)) if given else None
    except ValueError as err:
        raise SpecError(f"[model]: {err}") from None
    return {k: float(v) for k, v in given.items()}, robot


def _parse_shift(raw) -> dict:
    """[evaluate.shift]: model variations, contact heights and robots never used in training
    (ensemble: an EnsembleRef, or absent: the default robot)."""
    sh = table("evaluate.shift", raw, set(RANDOMIZE_DEFAULTS) | {"height_m", ENSEMBLE_KEY})
    out = {"randomize": parse_randomize({"randomize": {k: v for k, v in sh.items()
                                                        if k not in ("height_m", ENSEMBLE_KEY)}})}
    if ENSEMBLE_KEY in sh:
        out[ENSEMBLE_KEY] = parse_ensemble(sh[ENSEMBLE_KEY], f"evaluate.shift.{ENSEMBLE_KEY}")
    if "height_m" in sh:
        lo, hi, _, unit = PUSH_FIELDS["height_m"]
        v = sh["height_m"]
        out["height_m"] = (uniform("evaluate.shift.height_m", v, lo, hi, unit)
                           if isinstance(v, dict) else number("evaluate.shift.height_m", v, lo,
                                                               hi, unit))
    return out


def shifted(spec: TuneSpec) -> TuneSpec | None:
    """The spec with [evaluate.shift] replacing its randomisation, its robots (the shift's
    ensemble, or the default robot) and its contact heights. Its robot table is the spec's."""
    if spec.shift is None:
        return None
    push = dict(spec.push)
    if "height_m" in spec.shift:
        push["height_m"] = spec.shift["height_m"]
    return dataclasses.replace(spec, push=push, randomize=spec.shift["randomize"],
                               ensemble=spec.shift.get(ENSEMBLE_KEY))


def robot_table(spec: TuneSpec, model_params: ModelParams | None = None
                ) -> tuple[ModelParams, ...] | None:
    """The robots of the spec's tuning problem, row by row (the robot_id of the records): row
    0 the default robot (`model_params`, None: the embedded default), then each ensemble of
    spec.robot_table's members. None when the spec names no ensemble (one robot, no robot_id
    column, the single-robot program)."""
    if not spec.robot_table:
        return None
    return (model_params or ModelParams(),) + tuple(m for e in spec.robot_table
                                                    for m in e.members)


def robot_offset(spec: TuneSpec, ensemble: EnsembleRef) -> int:
    """The row of `ensemble`'s member 0 in the spec's robot table."""
    row = 1
    for e in spec.robot_table:
        if e == ensemble:
            return row
        row += e.n
    raise ValueError(f"ensemble {ensemble.path} is not in the spec's robot table")


@functools.lru_cache(maxsize=4)
def _robot_set(models: tuple[ModelParams, ...]):
    from tkujax.sim.robots import robot_set
    return robot_set(models)


def tune_robots(spec: TuneSpec, model_params: ModelParams | None = None):
    """The RobotSet of `robot_table` (cached by content), or None without an ensemble; a member
    that is not of the default robot's structure is a SpecError naming the ensemble key."""
    models = robot_table(spec, model_params)
    if models is None:
        return None
    try:
        return _robot_set(models)
    except ValueError as err:
        keys = [k for k, e in ((f"randomize.{ENSEMBLE_KEY}", spec.ensemble),
                               (f"evaluate.shift.{ENSEMBLE_KEY}",
                                (spec.shift or {}).get(ENSEMBLE_KEY))) if e is not None]
        raise SpecError(f"{' / '.join(keys)}: the ensemble's robots and the default robot do "
                        f"not share one structure: {err}") from None


def make_problem(spec: TuneSpec, reparam=None, duration_s: float | None = None,
                 remat: bool | None = None, compiler_options: dict | None = None,
                 model_params: ModelParams | None = None) -> TuneProblem:
    """The spec's TuneProblem (its reparameterisation, start, loss, horizon, precision and,
    with an ensemble, its RobotSet): what `tkujax tune`, [compare] and [study] run."""
    model_params = model_params or spec.model_params()
    robots = tune_robots(spec, model_params)
    return TuneProblem(reparam if reparam is not None else spec.policy_reparam(),
                       spec.base_params(), spec.loss,
                       spec.duration_s if duration_s is None else duration_s,
                       spec.remat if remat is None else remat, spec.float64,
                       model_params=None if robots is not None else model_params,
                       compiler_options=compiler_options,
                       quantise_targets=spec.quantise_targets, robots=robots,
                       rollout_options=None if spec.gradient_window_ticks is None else
                       {"gradient_window_ticks": spec.gradient_window_ticks},
                       timing_gradient=spec.timing_gradient, bundle_sigma=spec.bundle_sigma)


def ensembles_record(spec: TuneSpec) -> dict:
    """{spec key: EnsembleRef.describe() (path, resolved path, sha256, n, ...) and its first
    row in the robot table}: what the tune's outputs record of its ensembles."""
    out = {}
    for key, e in ((f"randomize.{ENSEMBLE_KEY}", spec.ensemble),
                   (f"evaluate.shift.{ENSEMBLE_KEY}", (spec.shift or {}).get(ENSEMBLE_KEY))):
        if e is not None:
            out[key] = e.describe() | {"first_row": robot_offset(spec, e)}
    return out


def load_tune_spec(path: str | Path) -> TuneSpec:
    return parse_tune_spec(read_toml(path))


def sample_pushes(spec: TuneSpec, n: int, seed: int) -> dict[str, np.ndarray]:
    """n push records (RECORD_KEYS columns) from the spec's distribution, seeded."""
    rng = np.random.default_rng(seed)
    out = {}
    for k in PUSH_FIELDS:
        v = spec.push[k]
        if isinstance(v, tuple):
            out[k] = rng.uniform(v[0], v[1], n)
        elif isinstance(v, list):
            out[k] = np.resize(np.array(v, float), n)       # cycled: balanced directions
        else:
            out[k] = np.full(n, v)
    if spec.azimuth_jitter_deg > 0:
        out["azimuth_deg"] = out["azimuth_deg"] + rng.uniform(-spec.azimuth_jitter_deg,
                                                              spec.azimuth_jitter_deg, n)
    out = _with_randomize(out, spec, rng, n)
    if spec.robot_table:   # drawn last: the other columns are those drawn without it
        out[ROBOT_ID_COLUMN] = (np.zeros(n) if spec.ensemble is None else
                                robot_offset(spec, spec.ensemble)
                                + rng.integers(0, spec.ensemble.n, n).astype(float))
    return out


def grid_pushes(spec: TuneSpec) -> dict[str, np.ndarray]:
    """The evaluation grid: impulses x azimuths, other push fields at their mid values."""
    J, A = np.meshgrid(spec.eval_impulse_ns, spec.eval_azimuth_deg, indexing="ij")
    n = J.size
    out = dict(impulse_ns=J.ravel(), azimuth_deg=A.ravel())
    for k in ("height_m", "duration_s", "onset_s"):
        v = spec.push[k]
        mid = (0.5 * (v[0] + v[1]) if isinstance(v, tuple)
               else float(np.mean(v)) if isinstance(v, list) else v)
        out[k] = np.full(n, mid)
    # The grid uses the nominal model (no randomisation; the default robot) and no sensor noise.
    out = _with_randomize(out, None, None, n)
    if spec.robot_table:
        out[ROBOT_ID_COLUMN] = np.zeros(n)
    return out


def _with_randomize(out: dict, spec: TuneSpec | None, rng, n: int) -> dict[str, np.ndarray]:
    rand = spec.randomize if spec is not None else {}
    for k, default in RANDOMIZE_DEFAULTS.items():
        v = rand.get(k)
        if isinstance(v, tuple):
            out[k] = rng.uniform(v[0], v[1], n)
        elif v is not None:
            out[k] = np.full(n, v)
        else:
            out[k] = np.full(n, -1.0 if default is None else default)  # friction -1: model's
    return {k: np.asarray(out[k], float) for k in RECORD_KEYS}
