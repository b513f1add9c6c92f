"""ControllerParams from JSON and from spec-style values, validated at the edge by
`ControllerParams.validate` (the one statement of the ranges); errors name the key and the
allowed range.

Spec-style keys are ControllerParams fields, or FIELD_deg for an angle field given in degrees.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from tkujax.control.controller_params import ControllerParams

DEG = math.pi / 180.0


def field_of(key: str) -> tuple[str, float]:
    """(ControllerParams field, factor to its SI unit) of a spec-style key."""
    return (key[:-4], DEG) if key.endswith("_deg") else (key, 1.0)


def controller_params_from(base: ControllerParams, overrides: dict) -> ControllerParams:
    """Apply spec-style overrides (`*_deg` keys in degrees) to `base` (values may be traced:
    nothing is checked here; check concrete values with `checked_value`)."""
    values = {}
    for k, v in overrides.items():
        if k.endswith("_deg"):
            values[k[:-4]] = v * DEG   # v may be traced: no math.radians
        else:
            values[k] = v
    return dataclasses.replace(base, **values)


def allowed_range(field: str) -> str:
    """The range ControllerParams.validate allows for `field`: the message validate gives for
    NaN there, which no range admits."""
    try:
        dataclasses.replace(ControllerParams(), **{field: math.nan}).validate()
    except ValueError as err:
        text = str(err)
        if " must be in " in text:
            return text.split(" must be in ", 1)[1].rsplit(", got", 1)[0]
    return "(a finite number)"


def _is_number(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def checked_value(where: str, key: str, value) -> float:
    """A concrete spec-style value, checked alone by ControllerParams.validate (the defaults
    hold the other fields). ValueError: "{where}: ..." naming the field and its range."""
    field, factor = field_of(key)
    if field not in {f.name for f in dataclasses.fields(ControllerParams)}:
        raise ValueError(f"{where}: {key!r} names no ControllerParams field")
    unit = " (given in deg)" if factor != 1.0 else ""
    if not _is_number(value):
        raise ValueError(f"{where}: expected a number, ControllerParams.{field} in "
                         f"{allowed_range(field)}{unit}, got {value!r}")
    try:
        dataclasses.replace(ControllerParams(), **{field: float(value) * factor}).validate()
    except ValueError as err:
        raise ValueError(f"{where}: {value!r}{' deg' if unit else ''} is out of range: "
                         f"{err}") from err
    return float(value)


def controller_params_from_dict(data, where: str,
                                base: ControllerParams | None = None) -> ControllerParams:
    """ControllerParams from {field: value} (SI units, radians; any subset, the others from
    `base`, default ControllerParams.paper()), validated. ValueError names where and the key."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a JSON object {{field: value}}, "
                         f"got {type(data).__name__}")
    fields = {f.name for f in dataclasses.fields(ControllerParams)}
    unknown = sorted(set(data) - fields)
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; allowed: {sorted(fields)}")
    values = {}
    for k, v in data.items():
        if not _is_number(v):
            raise ValueError(f"{where}: {k} must be a number in {allowed_range(k)}, got {v!r}")
        values[k] = float(v)
    try:
        return dataclasses.replace(base or ControllerParams.paper(), **values).validate()
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from err


# String notes a parameter file may carry besides the fields ("recommended_from": which set
# `tkujax tune` recommends, see tkujax.studies.tune.tune_command).
PARAMS_NOTE_KEYS = ("recommended_from",)


def without_notes(data):
    """A parameter file's content without its string notes (PARAMS_NOTE_KEYS: not parameters,
    `tkujax tune` writes them); anything but a dict unchanged."""
    if not isinstance(data, dict):
        return data
    return {k: v for k, v in data.items() if not (k in PARAMS_NOTE_KEYS and isinstance(v, str))}


def _read_json(path: Path):
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"--params {path}: cannot read JSON: {err}") from err
    return without_notes(data)


def is_policy(data) -> bool:
    """A policy file: {"controller": {field: value}, "schedule": {...}} (`save_policy_json`)."""
    return isinstance(data, dict) and "schedule" in data


# `--params recommended`: the recommended recovery policy shipped with the package (a copy of
# the dimension study's best policy, results/tune_dimension/best_policy.json).
RECOMMENDED_POLICY_NAME = "recommended"
RECOMMENDED_POLICY_PATH = Path(__file__).with_name("recommended_policy.json")


def _names_recommended(path: str | Path) -> bool:
    """`--params recommended` (and no file of that name here)."""
    return str(path) == RECOMMENDED_POLICY_NAME and not Path(path).exists()


def policy_file_path(path: str | Path) -> Path:
    """The file `load_policy_json(path)` reads: RECOMMENDED_POLICY_PATH for the name
    "recommended" (no file of that name here), else `path`."""
    return RECOMMENDED_POLICY_PATH if _names_recommended(path) else Path(path)


def load_controller_params_json(path: str | Path) -> ControllerParams:
    """ControllerParams from a JSON file {field: value} (SI units, radians), as `tkujax tune`
    and `tkujax calibrate` write it (`--params FILE.json`); string notes of PARAMS_NOTE_KEYS
    are ignored. A policy file (a scheduled controller) is refused: its schedule would be
    silently dropped; `load_policy_json` reads it."""
    if _names_recommended(path):
        raise ValueError("--params recommended: the recommended recovery policy is scheduled; "
                         "only `tkujax sweep` and `tkujax paper` run one (the recommended scalar "
                         "set is results/tune_recovery_ensemble/params_after.json)")
    path = Path(path)
    data = _read_json(path)
    if is_policy(data):
        raise ValueError(f"--params {path}: holds a scheduled policy (key 'schedule'); only "
                         f"`tkujax sweep` and `tkujax paper` run one")
    return controller_params_from_dict(data, f"--params {path}")


def load_policy_json(path: str | Path):
    """(ControllerParams, Schedule or None) from a parameter file or a policy file
    {"controller": {field: value}, "schedule": {...}} (`save_policy_json`; the study and
    `tkujax tune` write one for a scheduled policy). The name "recommended" (not a file) is
    the recommended recovery policy (`recommended_policy`). ValueError names the file and the
    key."""
    from tkujax.control.policy import schedule_from_dict

    path = policy_file_path(path)
    data = _read_json(path)
    if not is_policy(data):
        return controller_params_from_dict(data, f"--params {path}"), None
    unknown = sorted(set(data) - {"controller", "schedule"} - set(POLICY_NOTE_KEYS))
    if unknown:
        raise ValueError(f"--params {path}: unknown key(s) {unknown} in a policy file "
                         f"(allowed: controller, schedule, {', '.join(POLICY_NOTE_KEYS)})")
    params = controller_params_from_dict(data.get("controller"), f"--params {path}: controller")
    return params, schedule_from_dict(data["schedule"], f"--params {path}: schedule")


def recommended_policy():
    """The recommended recovery controller: (ControllerParams, Schedule), the paper's
    architecture with the recovery extensions, its step timing, gain, triggers and stance gains
    scheduled over 8 push-direction sectors of the filtered state (80 tuned parameters).
    Tuned by sep-CMA-ES in the dimension study (results/tune_dimension); on the held-out sets
    of results/recovery_eval it falls on 20.9 % / 21.3 % of the pushes against 23.4 % / 24.1 %
    for the scalar `ControllerParams.recommended()`, with no harmed cell
    (results/tune_dimension/recovery_eval_sectors8). Run it with
    `tkujax sweep SPEC --params recommended`, or pass both to `simulate`-level code that takes
    a schedule (`rollout(..., schedule=)`, `make_chunk_fn`'s 4th argument)."""
    return load_policy_json(RECOMMENDED_POLICY_PATH)


# Free-form notes a policy file may carry (where it came from).
POLICY_NOTE_KEYS = ("source", "recommended_from")


def save_policy_json(params: ControllerParams, schedule, path: str | Path,
                     source: str | None = None) -> Path:
    """Write a policy file: the full ControllerParams and the Schedule (None: the plain
    parameter file of `save_controller_params_json`)."""
    from tkujax.control.policy import schedule_to_dict

    if schedule is None:
        return save_controller_params_json(params, path)
    path = Path(path)
    payload = dict(controller=dataclasses.asdict(params), schedule=schedule_to_dict(schedule))
    if source:
        payload["source"] = source
    path.write_text(json.dumps(payload, indent=1, default=float) + "\n")
    return path


def save_controller_params_json(params: ControllerParams, path: str | Path) -> Path:
    path = Path(path)
    path.write_text(json.dumps(dataclasses.asdict(params), indent=1) + "\n")
    return path
