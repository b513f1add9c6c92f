"""A sweep resumed on another machine, whose robot geometry comes out a last bit different
(tkujax.sweeps.sweep_folder.params_as_held): it goes on with the parameters it ran with; a real
change of a parameter is still refused."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.dialects.sweep_spec import SpecError
from tkujax.sweeps.sweep import run_sweep
from tkujax.sweeps.sweep_folder import PARAMS_REL_TOL

TINY = Path(__file__).resolve().parents[1] / "specs" / "sweep" / "tiny.toml"


def _nudged(params: ControllerParams, field: str, ulps: int) -> ControllerParams:
    value = getattr(params, field)
    for _ in range(ulps):
        value = float(np.nextafter(value, 1.0))
    return dataclasses.replace(params, **{field: value})


def test_a_resume_with_last_bit_geometry_goes_on_with_the_kept_parameters(tmp_path):
    first_params = ControllerParams.paper()
    first = run_sweep(TINY, tmp_path, params=first_params, max_chunks=1, quiet=True,
                      backend="mujoco")
    assert not first["complete"]
    other_machine = _nudged(first_params, "hip_offset_y", 2)
    assert other_machine != first_params
    second = run_sweep(TINY, tmp_path, params=other_machine, quiet=True, backend="mujoco")
    assert second["complete"] and second["spec_hash"] == first["spec_hash"]
    kept = json.loads((tmp_path / "manifest.json").read_text())["controller_params"]
    assert kept["hip_offset_y"] == first_params.hip_offset_y     # not the resuming run's


def test_a_changed_parameter_is_still_refused(tmp_path):
    first_params = ControllerParams.paper()
    run_sweep(TINY, tmp_path, params=first_params, max_chunks=1, quiet=True, backend="mujoco")
    value = first_params.hip_offset_y * (1.0 + 100 * PARAMS_REL_TOL)
    changed = dataclasses.replace(first_params, hip_offset_y=value)
    with pytest.raises(SpecError, match="the controller parameters"):
        run_sweep(TINY, tmp_path, params=changed, quiet=True, backend="mujoco")
