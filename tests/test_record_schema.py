"""The sweep manifest's record schema (tkujax.sweeps.record_schema): one table of the fields
each schema version records, the value a field takes in a manifest that predates it, the spec
hash of older sweeps, and the version a new manifest records."""

import dataclasses
import json
from pathlib import Path

import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.model import ModelParams
from tkujax.sweeps.record_schema import (ADDED_FIELDS, FIRST_FIELDS, GROUPS, SCHEMA_KEY,
                                         SCHEMA_VERSION, UNVERSIONED, fields_missing, fields_of,
                                         filled_fields, hashed_fields, manifest_version)
from tkujax.sweeps.record_schema import manifest_spec
from tkujax.sweeps.sweep_hash import spec_hash

RESULTS = Path(__file__).resolve().parents[1] / "results"


@pytest.mark.parametrize("group", sorted(GROUPS))
def test_the_newest_version_names_every_field_of_todays_classes(group):
    """A field added to ControllerParams, ModelParams or FixedPointConfig needs a row in
    ADDED_FIELDS (its value-before keeps older sweeps' hashes and replays)."""
    today = {f.name for f in dataclasses.fields(GROUPS[group])}
    assert set(fields_of(SCHEMA_VERSION, group)) == today
    assert len(fields_of(SCHEMA_VERSION, group)) == len(today)        # no field twice
    assert set(fields_of(UNVERSIONED, group)) == set(FIRST_FIELDS[group])


def test_added_fields_are_rows_of_known_groups_and_versions():
    assert all(f.group in GROUPS and UNVERSIONED < f.since <= SCHEMA_VERSION
               for f in ADDED_FIELDS)
    assert len({(f.group, f.name) for f in ADDED_FIELDS}) == len(ADDED_FIELDS)


def test_an_added_field_enters_the_hash_only_when_set():
    p = dataclasses.asdict(ControllerParams.paper())
    assert "max_steps" not in hashed_fields("controller_params", p)
    assert hashed_fields("controller_params", p | {"max_steps": 2.0})["max_steps"] == 2.0
    m = dataclasses.asdict(ModelParams()) | {"accel_lowpass_hz": 7.5, "gyro_lowpass_hz": 0.0}
    assert hashed_fields("model_params", m).keys() == m.keys() - {"gyro_lowpass_hz"}
    f = {"ik_guard_bits": 4}                   # the fixed-point defaults enter in full
    assert hashed_fields("fixed_point_defaults", f) == f


def test_tree_passes_of_a_spec_enter_the_hash_and_an_older_manifest_ran_mjx():
    from tkujax.dialects.sweep_spec import SpecError, parse_spec

    raw = {"sweep": {"name": "t"}, "push": {"grid": {"impulse_ns": [1.0]}}}
    compact = parse_spec(raw)
    assert compact.tree_passes == "compact"
    mjx = parse_spec({**raw, "sweep": {"name": "t", "tree_passes": "mjx"}})
    args = (ControllerParams.paper(), ModelParams())
    assert spec_hash(compact, *args) != spec_hash(mjx, *args)
    # "mjx" adds nothing to the hash but the raw key: the same as a manifest without the key.
    assert spec_hash(manifest_spec({"spec": raw}), *args) == spec_hash(
        dataclasses.replace(compact, tree_passes="mjx"), *args)
    assert manifest_spec({"spec": raw}).tree_passes == "mjx"
    assert manifest_spec({"spec": raw, "tree_passes": "compact"}).tree_passes == "compact"
    with pytest.raises(SpecError, match=r"sweep.tree_passes: expected one of \['compact', "
                                        r"'mjx'\], got 'fast'"):
        parse_spec({**raw, "sweep": {"tree_passes": "fast"}})


def test_manifest_versions():
    assert manifest_version({}) == UNVERSIONED
    assert manifest_version({SCHEMA_KEY: SCHEMA_VERSION}) == SCHEMA_VERSION
    for bad in (SCHEMA_VERSION + 1, 0, "2", True):
        with pytest.raises(ValueError, match=rf"schema_version must be an integer in "
                                             rf"\[1, {SCHEMA_VERSION}\].*got {bad!r}"):
            manifest_version({SCHEMA_KEY: bad})


def test_an_unversioned_manifest_is_filled_a_versioned_one_must_be_whole():
    recorded = {k: v for k, v in dataclasses.asdict(ControllerParams()).items()
                if k != "stance_limit"}
    assert filled_fields({"controller_params": recorded}, "controller_params") == {
        "stance_limit": 0.3}
    assert fields_missing({"controller_params": recorded}) == {
        "controller_params.stance_limit": 0.3}
    with pytest.raises(ValueError, match=r"controller_params lacks \['stance_limit'\]"):
        filled_fields({SCHEMA_KEY: SCHEMA_VERSION, "controller_params": recorded},
                      "controller_params")


def test_committed_sweeps_are_unversioned_and_keep_their_hash_through_the_table():
    """Every committed sweep manifest predates the schema version; the ones whose records are
    today's (not `shares_robot_draws` from before the IMU low-pass) reproduce their hash from
    the parameters the table fills in."""
    from tkujax.sweeps.record_schema import manifest_controller_params, manifest_model_params
    from tkujax.sweeps.sweep_hash import shares_robot_draws

    manifests = sorted(RESULTS.glob("*/manifest.json")) + sorted(
        RESULTS.glob("sweeps/*/manifest.json"))
    assert manifests
    for path in manifests:
        m = json.loads(path.read_text())
        assert manifest_version(m) == UNVERSIONED, path
        spec = manifest_spec(m)
        if spec.arithmetic == "fixed" or (shares_robot_draws(spec)
                                          and "accel_lowpass_hz" not in m["model_params"]):
            continue
        params = manifest_controller_params(m, str(path))
        model = manifest_model_params(m) or ModelParams()
        assert spec_hash(spec, params, model) == m["spec_hash"], path
