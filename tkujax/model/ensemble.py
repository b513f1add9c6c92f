"""An ensemble of plausible robots: the calibration's candidates whose expected fit to the paper
is within a stated tolerance of the best (`tkujax calibrate`, results/calibration/ensemble.json).

The file (JSON):
  {"version": 1, "objective": ..., "reading": ..., "tolerance": ..., "best_loss": ...,
   "default_member": k,                 # the member chosen as the default robot
   "members": [{"id": 0, "loss": ..., "x": {fitted and held parameter values},
                "model_params": {ModelParams as JSON (tkujax.model.params_json)}, ...}, ...]}
Sweeps draw one member per push (`[randomize] ensemble = "PATH"`); only each member's
model_params are used there (the controller and the pushes are the sweep's).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from tkujax.model.params_json import model_params_from_dict, model_params_to_dict
from tkujax.model.model_params import ModelParams

VERSION = 1


@dataclasses.dataclass(frozen=True)
class Ensemble:
    members: tuple[ModelParams, ...]
    default_member: int
    raw: dict = dataclasses.field(compare=False, repr=False)

    @property
    def n(self) -> int:
        return len(self.members)


def save_ensemble(path: str | Path, members: list[dict], default_member: int, **meta) -> Path:
    """Write `members` (dicts with at least "model_params": ModelParams) as an ensemble file."""
    path = Path(path)
    out = []
    for k, m in enumerate(members):
        m = dict(m)
        mp = m["model_params"]
        m["model_params"] = model_params_to_dict(mp) if isinstance(mp, ModelParams) else mp
        out.append({"id": k, **{key: v for key, v in m.items() if key != "id"}})
    if not 0 <= default_member < len(out):
        raise ValueError(f"default_member {default_member} is not a member index "
                         f"(0..{len(out) - 1})")
    data = {"version": VERSION, **meta, "default_member": int(default_member), "members": out}
    path.write_text(json.dumps(data, indent=1, default=float) + "\n")
    return path


def load_ensemble(path: str | Path) -> Ensemble:
    """Read and validate an ensemble file; errors name the file and the bad key."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"ensemble file {path} does not exist") from None
    except json.JSONDecodeError as err:
        raise ValueError(f"ensemble file {path}: not JSON ({err})") from None
    if not isinstance(data, dict) or data.get("version") != VERSION:
        raise ValueError(f"{path}: expected an ensemble file of version {VERSION} "
                         f"(a JSON object with 'version': {VERSION}), got version "
                         f"{data.get('version') if isinstance(data, dict) else data!r}")
    members = data.get("members")
    if not isinstance(members, list) or not members:
        raise ValueError(f"{path}: 'members' must be a non-empty list")
    mps = []
    for k, m in enumerate(members):
        if not isinstance(m, dict) or "model_params" not in m:
            raise ValueError(f"{path}: members[{k}] has no 'model_params'")
        mps.append(model_params_from_dict(m["model_params"], f"{path}: members[{k}].model_params"))
    default = data.get("default_member", 0)
    if isinstance(default, bool) or not isinstance(default, int) or not 0 <= default < len(mps):
        raise ValueError(f"{path}: default_member must be a member index in [0, {len(mps) - 1}], "
                         f"got {default!r}")
    return Ensemble(tuple(mps), default, data)
