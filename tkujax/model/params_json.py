"""ModelParams as JSON: the full dataclass (nested servos included), written by `tkujax
calibrate` (model_params.json) and read back by `--model FILE.json`, validated at the edge."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

from tkujax.model.model_params import ModelParams, ServoParams


def model_params_to_dict(mp: ModelParams) -> dict:
    return dataclasses.asdict(mp)


def model_params_from_dict(data: dict, where: str = "model params") -> ModelParams:
    """ModelParams from {field: value} (any subset; missing fields keep the defaults). Servo
    fields are objects {field: value} merged into the default servo. ValueError names the key."""
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a JSON object {{field: value}}, "
                         f"got {type(data).__name__}")
    base = ModelParams()
    fields = {f.name: f for f in dataclasses.fields(ModelParams)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {unknown}; allowed: {sorted(fields)}")
    values = {}
    for key, value in data.items():
        default = getattr(base, key)
        if isinstance(default, ServoParams):
            values[key] = _servo(value, default, f"{where}: {key}")
        elif isinstance(default, tuple):
            if not (isinstance(value, (list, tuple)) and all(_is_number(v) for v in value)):
                raise ValueError(f"{where}: {key} must be a list of numbers, got {value!r}")
            values[key] = tuple(float(v) for v in value)
        elif isinstance(default, int) and not isinstance(default, bool):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(f"{where}: {key} must be an integer, got {value!r}")
            values[key] = value
        else:
            if not _is_number(value):
                raise ValueError(f"{where}: {key} must be a finite number, got {value!r}")
            values[key] = float(value)
    try:
        return dataclasses.replace(base, **values).validate()
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from err


def _servo(value, default: ServoParams, where: str) -> ServoParams:
    if not isinstance(value, dict):
        raise ValueError(f"{where}: expected an object of ServoParams fields, got {value!r}")
    names = {f.name for f in dataclasses.fields(ServoParams)}
    unknown = sorted(set(value) - names)
    if unknown:
        raise ValueError(f"{where}: unknown servo field(s) {unknown}; allowed: {sorted(names)}")
    for k, v in value.items():
        ok = (v is None and k == "damping_override_nms_per_rad") or (_is_number(v) and v >= 0)
        if not ok:
            raise ValueError(f"{where}.{k} must be a non-negative finite number, got {v!r}")
    return dataclasses.replace(default, **{k: (None if v is None else float(v))
                                           for k, v in value.items()})


def _is_number(v) -> bool:
    return not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


def save_model_params_json(mp: ModelParams, path: str | Path) -> Path:
    path = Path(path)
    path.write_text(json.dumps(model_params_to_dict(mp), indent=1) + "\n")
    return path


def load_model_params_json(path: str | Path) -> ModelParams:
    """ModelParams from a JSON file (as `tkujax calibrate` writes); ValueError names the key."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"--model {path}: cannot read JSON: {err}") from err
    return model_params_from_dict(data, f"--model {path}")
