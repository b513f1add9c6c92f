"""What the fixed-point twin implements, and a refusal of everything else.

The twin (`controller_step_fx`) reads the ControllerParams fields of `IMPLEMENTED_FIELDS` (the
coefficient registers of `coefficients.py` are built from them). Every other field is an
option of the float controller the twin does not have: with any value other than
`ControllerParams()`'s default, a fixed-point run would compare two different controllers.
`check_supported` refuses it, at the edges (spec parsing with arithmetic = "fixed", the fpga
study, sweeps and rollouts with `RolloutConfig.fixed`), never inside jit.

The rule iterates over `dataclasses.fields(ControllerParams)`: a field added later is refused
as soon as it is set away from its default, until it is implemented here and added to
`IMPLEMENTED_FIELDS`. Options refused today: accel_gate (robust Kalman R) and
gate_temperature (the twin's gate is the hard one of Algorithm 1; a soft gate acts only on
the straight-through gradient path of `controller_step_fx` called directly, never on the
values). cp_excess and cp_update_window are implemented (controller_fx.py).
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from tkujax.control.controller_params import ControllerParams

# Fields the fixed-point datapath reads (coefficients.py: every register is derived from these).
IMPLEMENTED_FIELDS = frozenset({
    "control_period", "step_period", "double_support_ratio", "lift_height",
    "eps_forward", "eps_backward", "standing_lean", "cp_angle_offset", "cp_gain",
    "cp_excess", "cp_update_window",
    "lateral_steps", "eps_lateral", "gravity", "kalman_q", "kalman_r",
    "hip_offset_y", "hip_to_ankle_z", "thigh_length", "calf_length", "leg_length", "com_height",
})


def same_value(value, default) -> bool:
    """value equals default (relative 1e-12: a degree -> radian conversion may differ by an
    ulp). Traced values cannot be checked: TypeError (call it outside jit)."""
    if isinstance(value, jax.core.Tracer):
        raise TypeError("check_supported needs concrete parameter values (call it outside jit)")
    try:
        a, b = np.asarray(value, float), float(default)
    except (TypeError, ValueError):      # a non-numeric option: plain equality
        return bool(value == default)
    return bool(np.all(np.isclose(a, b, rtol=1e-12, atol=0.0)))


def unsupported(params: ControllerParams) -> list[tuple[str, object, object]]:
    """(field, value, default) of every field outside IMPLEMENTED_FIELDS set away from its
    `ControllerParams()` default, in field order."""
    out = []
    for f in dataclasses.fields(params):
        if f.name in IMPLEMENTED_FIELDS:
            continue
        value = getattr(params, f.name)
        ref = _default(f)
        if ref is None or not same_value(value, ref):
            out.append((f.name, value, ref))
    return out


def _default(f: dataclasses.Field):
    """The field's declared default (what `ControllerParams()` holds); None without one."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def refusal(name: str, value, default) -> str:
    """The one-line message for one unsupported option."""
    v = float(np.asarray(value)) if np.ndim(value) == 0 else value
    return (f"ControllerParams.{name} = {v!r} is not implemented by arithmetic = \"fixed\" "
            f"(the fixed-point twin supports only its default {default!r}); "
            f"use arithmetic = \"float\" or reset it")


def check_supported(params: ControllerParams) -> ControllerParams:
    """Raise ValueError (one line, naming the option and its value) if `params` sets an option
    the fixed-point twin does not implement; returns params."""
    bad = unsupported(params)
    if bad:
        raise ValueError(refusal(*bad[0]))
    return params
