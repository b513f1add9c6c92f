"""The [fpga] table of sweep specs and the fixed-point controller's checks: a sweep with
controller.arithmetic = "fixed" runs the FPGA twin (`tkujax.control.fixed`), configured by
[fpga] and gridded by [controller.grid.fpga]."""

from __future__ import annotations

import itertools
import math
import re
from typing import Any

import numpy as np

from tkujax.control.fixed.config import GROUP_INT_BITS, MAX_GROUP_WORD_BITS, FixedPointConfig
from tkujax.control.fixed.qformat import ROUNDING_MODES, QFormat
from tkujax.dialects.validation import SpecError, number, table

ARITHMETIC = ("float", "fixed")
# [fpga] keys -> FixedPointConfig fields: name: (lo, hi, unit). All integers except latency_frac
# (and rounding, a name: FPGA_ROUNDING). The frac-bit bound here is the loosest one; the word
# limit (1 + int + frac <= 26) is checked on the assembled FixedPointConfig.
FPGA_GROUPS = tuple(GROUP_INT_BITS)
FPGA_FIELDS = (
    {f"{g}_int_bits": (lo, hi, "bits") for g, (lo, hi) in GROUP_INT_BITS.items()}
    | {f"{g}_frac_bits": (1, MAX_GROUP_WORD_BITS - 1, "bits") for g in FPGA_GROUPS}
    | {"angle_state_frac_bits": (1, MAX_GROUP_WORD_BITS - 3, "bits (angle and state together)"),
       "coef_bits": (12, 31, "bits"), "cordic_iterations": (1, 30, "iterations"),
       "cordic_guard_bits": (0, 3, "bits"), "latency_ticks": (0, 100, "control periods"),
       "ik_guard_bits": (0, 8, "bits (extra fraction bits of the IK's lengths)"),
       "latency_frac": (0.0, 1.0, "(fraction of a control period; 1 excluded)"),
       "rounding": (0, len(ROUNDING_MODES) - 1, f"(one of {ROUNDING_MODES})")})
FPGA_COLUMN = "fpga_"   # record column prefix of a gridded [fpga] key


def check_fixed_controller(controller: dict, grid: dict) -> None:
    """arithmetic = "fixed": every [controller] value and [controller.grid] value of a field the
    fixed-point twin does not implement must be that field's default (`check_supported`)."""
    from tkujax.control.fixed.support import IMPLEMENTED_FIELDS, same_value
    from tkujax.control.controller_params import ControllerParams
    defaults = ControllerParams()
    items = [(f"controller.{k}", k, v) for k, v in controller.items()]
    items += [(f"controller.grid.{k}[{i}]", k, float(v)) for k, vals in grid.items()
              for i, v in enumerate(vals)]
    for key, k, v in items:
        field = k[:-4] if k.endswith("_deg") else k
        if field in IMPLEMENTED_FIELDS:
            continue
        si = v * (math.pi / 180.0) if k.endswith("_deg") else v
        default = getattr(defaults, field)
        if not same_value(si, default):
            shown = default * 180.0 / math.pi if k.endswith("_deg") else default
            raise SpecError(f"{key} = {v!r}: controller.arithmetic = \"fixed\" does not implement "
                            f"{field} (only its default {shown!r}); use arithmetic = \"float\"")


def fpga_value(key: str, name: str, value):
    """One [fpga] value: an int in range, latency_frac in [0, 1), rounding as its index."""
    lo, hi, unit = FPGA_FIELDS[name]
    if name == "rounding":
        if value not in ROUNDING_MODES:
            raise SpecError(f"{key}: expected one of {list(ROUNDING_MODES)}, got {value!r}")
        return ROUNDING_MODES.index(value)
    v = number(key, value, lo, hi, unit)
    if name == "latency_frac":
        if v >= 1.0:
            raise SpecError(f"{key}: {value!r} is out of range [0, 1) {unit}")
        return v
    if isinstance(value, float) and not value.is_integer():
        raise SpecError(f"{key}: expected an integer in [{lo}, {hi}] {unit}, got {value!r}")
    return int(v)


def fixed_point_config(values: dict) -> FixedPointConfig:
    """FixedPointConfig from [fpga] values (rounding by name or index); defaults elsewhere.

    straight_through is off: sweeps take no gradient, so the float shadow would only cost time.
    Raises SpecError naming the [fpga] key (e.g. a word over 26 bits)."""
    base = FixedPointConfig()
    fmt = {g: [getattr(base, g).int_bits, getattr(base, g).frac_bits] for g in FPGA_GROUPS}
    kw: dict[str, Any] = {"straight_through": False}
    for k, v in values.items():
        if k == "angle_state_frac_bits":
            fmt["angle"][1] = fmt["state"][1] = int(v)
        elif k.rsplit("_", 2)[0] in fmt and k.endswith(("_int_bits", "_frac_bits")):
            fmt[k.rsplit("_", 2)[0]][k.endswith("_frac_bits")] = int(v)
        elif k == "rounding":
            kw[k] = v if isinstance(v, str) else ROUNDING_MODES[int(v)]
        else:
            kw[k] = float(v) if k == "latency_frac" else int(v)
    try:
        return FixedPointConfig(**{g: QFormat(*f) for g, f in fmt.items()}, **kw)
    except ValueError as err:   # name the spec's key, not the dataclass field
        msg = re.sub(r"FixedPointConfig\.(\w+)\.(int_bits|frac_bits)", r"fpga.\1_\2", str(err))
        raise SpecError(msg.replace("FixedPointConfig.", "fpga.")) from None


def parse_fpga(data: dict, ctrl: dict, grid: dict):
    """(arithmetic, [fpga] values, [controller.grid] fpga.* arrays), every combination checked."""
    arithmetic = ctrl.get("arithmetic", "float")
    if arithmetic not in ARITHMETIC:
        raise SpecError(f"controller.arithmetic: expected one of {list(ARITHMETIC)}, "
                        f"got {arithmetic!r}")
    given_table = table("fpga", data.get("fpga", {}), FPGA_FIELDS)
    fpga = {k: fpga_value(f"fpga.{k}", k, v) for k, v in given_table.items()}
    grid = table("controller.grid.fpga", grid, FPGA_FIELDS)
    fpga_grid = {}
    for k, v in grid.items():
        items = v if isinstance(v, list) else [v]
        if not items:
            raise SpecError(f"controller.grid.fpga.{k}: empty list")
        fpga_grid[k] = np.array([fpga_value(f"controller.grid.fpga.{k}[{i}]", k, x)
                                 for i, x in enumerate(items)], float)
    both = sorted(set(fpga) & set(fpga_grid))
    if both:
        raise SpecError(f"fpga: {both} set both in [fpga] and in [controller.grid]")
    given = set(fpga) | set(fpga_grid)
    if "angle_state_frac_bits" in given and given & {"angle_frac_bits", "state_frac_bits"}:
        raise SpecError("fpga.angle_state_frac_bits sets angle_frac_bits and state_frac_bits: "
                        "give either it or them")
    if given and arithmetic != "fixed":
        raise SpecError("[fpga] settings need controller.arithmetic = \"fixed\"")
    if arithmetic == "fixed":   # every configuration the sweep will build, checked up front
        for combo in itertools.product(*fpga_grid.values()):
            fixed_point_config(fpga | dict(zip(fpga_grid, combo)))
    return arithmetic, fpga, fpga_grid
