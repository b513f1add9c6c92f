"""Property-based tests of the spec parsers (hypothesis): whatever document a TOML file can
hold, a parser returns a spec or raises SpecError with one line that names the key; a sweep spec
it accepts has no more records than the limit, counted exactly, and no push its horizon cannot
hold."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tkujax.dialects.sweep_spec import (MAX_RECORDS, PHASE_KEY, PUSH_FIELDS, SpecError, expand,
                                        parse_spec, record_count)
from tkujax.dialects.validation import number, uniform, values

SETTINGS = settings(max_examples=150, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])

scalars = st.one_of(
    st.integers(min_value=-(1 << 70), max_value=1 << 70), st.floats(allow_nan=True),
    st.booleans(), st.text(max_size=6), st.sampled_from([0, 1, 2, 0.3, 0.5, 1.5]))
ranges = st.fixed_dictionaries(
    {"start": scalars, "stop": scalars, "num": st.one_of(st.integers(-2, 40), scalars)},
    optional={"endpoint": st.one_of(st.booleans(), scalars)})
leaf = st.one_of(scalars, st.lists(scalars, max_size=4), ranges,
                 st.fixed_dictionaries({"uniform": st.lists(scalars, max_size=3)}))


def _table(keys) -> st.SearchStrategy:
    known = st.dictionaries(st.sampled_from(keys), leaf, max_size=len(keys))
    return st.one_of(known, st.dictionaries(st.text(max_size=4), leaf, max_size=2), scalars)


SWEEP_KEYS = ["name", "seed", "chunk_size", "duration_s", "control", "description",
              "tree_passes", "decisions", "lanes", "segment_ticks"]
PUSH_KEYS = list(PUSH_FIELDS) + [PHASE_KEY, "n"]
documents = st.fixed_dictionaries({}, optional={
    "sweep": _table(SWEEP_KEYS),
    "push": st.fixed_dictionaries({}, optional={"grid": _table(PUSH_KEYS),
                                                "random": _table(PUSH_KEYS)}),
    "controller": _table(["step_period", "cp_gain", "eps_forward_deg", "accel_gate",
                          "arithmetic", "control_period"]),
    "randomize": _table(["link_mass_scale", "floor_friction", "gyro_noise_std"]),
    "step": st.fixed_dictionaries({}, optional={"grid": _table(["x_m", "y_m", "steps"]),
                                                "reference": scalars}),
    "robot": _table(["file"]),
})


def _one_line_naming_a_key(err: Exception) -> None:
    text = str(err)
    assert isinstance(err, SpecError), repr(err)
    assert "\n" not in text and ".:" not in text and " .." not in text, text
    assert ":" in text, text                           # "KEY: what is wrong"


@SETTINGS
@given(documents)
def test_a_sweep_spec_parses_or_names_its_key(doc):
    try:
        spec = parse_spec(doc)
    except SpecError as err:
        _one_line_naming_a_key(err)
        return
    assert 1 <= record_count(spec) <= MAX_RECORDS


valid_axis = st.lists(st.floats(0.1, 0.9), min_size=1, max_size=3)


@st.composite
def small_specs(draw) -> dict:
    """Valid sweep documents of a few records (grid, random part, controller and step grids)."""
    horizon = draw(st.sampled_from([1.0, 1.5]))
    doc = {"sweep": {"seed": draw(st.integers(0, (1 << 32) - 1)), "chunk_size": 3,
                     "duration_s": horizon,
                     "control": draw(st.sampled_from([["off"], ["on"], ["off", "on"]]))},
           "push": {}}
    if draw(st.booleans()):
        doc["push"]["grid"] = {"impulse_ns": draw(valid_axis), "onset_s": draw(valid_axis)}
        if draw(st.booleans()):
            doc["push"]["grid"][PHASE_KEY] = draw(st.lists(st.floats(0.0, 0.99), min_size=1,
                                                            max_size=2))
    doc["push"]["random"] = {"n": draw(st.integers(0 if doc["push"] else 1, 4)),
                             "onset_s": {"uniform": [0.2, 0.5]}}
    if draw(st.booleans()):
        doc["controller"] = {"grid": {"cp_gain": draw(st.lists(st.floats(0.5, 1.5),
                                                               min_size=1, max_size=2))}}
    if draw(st.booleans()):
        doc["step"] = {"reference": draw(st.booleans()),
                       "grid": {"x_m": [0.0, 0.05], "steps": draw(st.sampled_from(
                           [[1.0], [2.0], [1.0, 2.0]])), "x2_m": [0.0, 0.02]}}
    return doc


@SETTINGS
@given(small_specs())
def test_the_record_count_is_exact_and_every_push_fits_its_horizon(doc):
    spec = parse_spec(doc)
    recs = expand(spec)
    assert record_count(spec) == len(recs["push_id"])
    ends = recs["onset_s"] + recs["duration_s"]
    assert np.all(ends <= spec.duration_s + 1e-9)


@SETTINGS
@given(st.floats(0.05, 2.0), st.floats(0.002, 0.5))
def test_a_push_ending_on_the_horizon_is_accepted_and_one_past_it_refused(onset, pulse):
    horizon = onset + pulse
    if not 0.1 <= horizon <= 30.0:
        return
    doc = {"sweep": {"duration_s": horizon, "control": ["off"]},
           "push": {"grid": {"onset_s": [onset], "duration_s": [pulse]}}}
    parse_spec(doc)
    doc["push"]["grid"]["duration_s"] = [min(0.5, pulse * (1 + 1e-6) + 1e-6)]
    if onset + doc["push"]["grid"]["duration_s"][0] > horizon + 1e-9:
        with pytest.raises(SpecError, match="push.grid.duration_s"):
            parse_spec(doc)


@SETTINGS
@given(leaf, st.floats(-10, 10), st.floats(0, 10))
def test_values_are_in_range_or_named(value, lo, width):
    hi = lo + width
    try:
        out = values("k.v", value, lo, hi)
    except SpecError as err:
        _one_line_naming_a_key(err)
        assert str(err).startswith("k.v")
        return
    assert out.size >= 1 and np.all(np.isfinite(out)) and np.all((out >= lo) & (out <= hi))


@SETTINGS
@given(leaf)
def test_numbers_and_uniforms_are_finite_or_named(value):
    for check in (lambda: number("k.n", value, -1.0, 1.0), lambda: uniform("k.u", value, 0, 1)):
        try:
            got = check()
        except SpecError as err:
            assert str(err).startswith(("k.n", "k.u")) and "\n" not in str(err)
            continue
        assert all(math.isfinite(x) for x in np.atleast_1d(got))


def _dialect(name: str):
    if name == "tune":
        from tkujax.studies.tune.tune_spec import parse_tune_spec
        return parse_tune_spec
    if name == "calibrate":
        from tkujax.studies.calibrate.calibrate_spec import parse_calibrate_spec
        return parse_calibrate_spec
    from tkujax.studies.converge import parse_spec as parse_converge
    return parse_converge


@pytest.mark.parametrize("dialect", ["tune", "calibrate", "converge"])
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                   HealthCheck.function_scoped_fixture])
@given(doc=st.dictionaries(st.sampled_from(["tune", "search", "evaluate", "baseline", "push",
                                            "sweep", "converge", "calibrate", "targets"]),
                           _table(["seed", "batch", "iterations", "method", "n", "impulse_ns",
                                   "duration_s", "budget_s"]), max_size=3))
def test_other_dialects_parse_or_raise_spec_error(dialect, doc):
    try:
        _dialect(dialect)(doc)
    except SpecError as err:
        assert "\n" not in str(err)
