"""Early decisions with lane refill: repeatable, resumable, and agreeing with the full horizon
on the fall outcome (and on the recovery readings where they are defined)."""

import dataclasses
import json
import os
import socket
import time

import jax
import numpy as np
import pytest

from tkujax.control.controller_params import ControllerParams
from tkujax.sweeps import chunks
from tkujax.sweeps import early
from tkujax.sweeps.chunk_program import chunk_keys, make_chunk_fn, record_inputs, traced_params
from tkujax.sweeps.lane_stream import LaneStream
from tkujax.dialects.sweep_spec import SpecError, parse_spec
from tkujax.sweeps.sweep import load, run_sweep
from tkujax.sweeps.sweep_hash import spec_hash
from tkujax.model import ModelParams

# Impulses bracketing the fall boundary pushed from behind (0.6-1.0 N s) and from the front
# (2.6-3.0 N s), both directions each: 12 pushes, 2 chunks of 6 through 4 lanes (refills).
RAW = {"sweep": {"name": "early", "chunk_size": 6, "duration_s": 1.2, "control": ["on"],
                 "decisions": "early", "lanes": 4, "segment_ticks": 4},
       "push": {"grid": {"impulse_ns": [0.6, 0.8, 1.0, 2.6, 2.8, 3.0], "azimuth_deg": [0, 180],
                         "onset_s": [0.3]}}}


def _spec(**sweep):
    return parse_spec({**RAW, "sweep": {**RAW["sweep"], **sweep}})


def _assert_identical(a: dict, b: dict):
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)   # NaN equals NaN here


@pytest.fixture(scope="module")
def early_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("early")
    manifest = run_sweep(_spec(), out, quiet=True, backend="mjx")
    return out, manifest, load(out)


@pytest.mark.slow
def test_two_early_runs_are_identical(early_run, tmp_path):
    _, manifest, reference = early_run
    assert manifest["complete"] and manifest["decisions"] == "early" and manifest["lanes"] == 4
    assert "decided_s" in reference
    run_sweep(_spec(), tmp_path, quiet=True, backend="mjx")
    _assert_identical(load(tmp_path), reference)


@pytest.mark.slow
def test_exact_replay_of_an_early_record_is_bit_identical(early_run):
    """`replay(exact=True)` runs the record in the sweep's lanes (the others idle, from the
    stand, not the chunk's snapshot): every stored column, the ones an early record reads up
    to its fall decision and decided_s included, equals the stored bits."""
    from tkujax.sweeps.replay import replay

    out, _, reference = early_run
    for i in (int(np.flatnonzero(reference["fell"])[0]),
              int(np.flatnonzero(~reference["fell"])[-1])):
        result = replay(out, i, exact=True)
        assert result["identical"], result["differences"]
        assert {"decided_s", "peak_incl_deg", "fell"} <= set(result["replayed"])


@pytest.mark.slow
def test_interrupted_early_run_resumes_identically(early_run, tmp_path):
    _, _, reference = early_run
    first = run_sweep(_spec(), tmp_path, max_chunks=1, quiet=True, backend="mjx")
    assert not first["complete"]
    (tmp_path / ".chunk_000001.tmp.npz").write_bytes(b"partial write")   # a crash mid-write
    second = run_sweep(_spec(), tmp_path, quiet=True, backend="mjx")
    assert second["complete"] and second["chunks_computed_last_run"] == 1
    _assert_identical(load(tmp_path), reference)
    with pytest.raises(SpecError, match="holds another spec's sweep"):   # full is another sweep
        run_sweep(_spec(), tmp_path, quiet=True, backend="mjx", decisions="full")


@pytest.mark.slow
def test_early_decisions_agree_with_the_full_horizon(early_run):
    _, _, rec = early_run
    spec = _spec()
    recs = record_inputs(spec)
    inputs = {k: jax.numpy.asarray(recs[k].astype(np.float32)) for k in recs
              if k not in ("push_id", "from_grid")}
    params = traced_params(ControllerParams.paper())
    keys = np.concatenate([np.asarray(chunk_keys(spec.seed, i, 6)) for i in range(2)])
    fn = make_chunk_fn((), spec.duration_s, tree_passes=spec.tree_passes)
    full = jax.tree.map(np.asarray, fn(inputs, jax.numpy.asarray(keys), params))
    fell = rec["fell"].astype(bool)
    assert 0 < fell.sum() < len(fell)              # the set straddles the boundary
    np.testing.assert_array_equal(fell, full["fell"])
    np.testing.assert_array_equal(rec["diverged"], full["diverged"])
    assert (rec["decided_s"] <= spec.duration_s + 1e-6).all()
    assert (rec["decided_s"][fell] < spec.duration_s).all()     # falls are decided early
    up = ~fell
    for k in ("recovery_time_s", "capture_point_m", "capture_point_y_m"):
        np.testing.assert_allclose(rec[k], full[k], rtol=0, atol=1e-6, err_msg=k)
    for k in early.TRUNCATED_WHEN_FALLEN:          # defined where the push was survived
        # Another program: float rounding apart (a 74 deg lean differs by 0.007 deg).
        np.testing.assert_allclose(rec[k][up], full[k][up], rtol=1e-3, atol=2e-3, err_msg=k)


@pytest.mark.slow
def test_pre_push_snapshot_gives_the_same_records(early_run):
    _, _, rec = early_run
    spec = _spec()
    recs = record_inputs(spec)
    inputs = {k: recs[k][:6].astype(np.float32) for k in recs
              if k not in ("push_id", "from_grid")}
    group, k0 = early.snapshot_groups(inputs, steps=False)
    assert (group == 0).all() and list(k0) == [10]   # one setting, onset 0.3 s: tick 10
    fns = early.make_lane_fns((), spec.duration_s, tree_passes=spec.tree_passes,
                              segment_ticks=spec.decisions.segment_ticks)
    params = traced_params(ControllerParams.paper())
    fresh = early.run_lanes(fns, inputs, chunk_keys(spec.seed, 0, 6), params, None, 4,
                            snapshot=False)
    _assert_identical(fresh, {k: rec[k][:6] for k in fresh})


def _streamed(stream, fns, chunk, n_chunks):
    """({chunk: outcome columns}, stream stats): chunks 0..n_chunks-1 through `stream`."""
    out, todo = {}, list(range(n_chunks))

    def more(idle):
        return [stream.part(i, fns, *chunk(i)) for i in [todo.pop(0)]] if todo else []

    stream.run(more, lambda part: out.__setitem__(part.label, part.out))
    return out, stream.stats


@pytest.mark.slow
def test_refill_across_chunks_gives_the_records_of_one_chunk_at_a_time(tmp_path):
    # Chunks of 7 and 5 pushes through 3 lanes: the second chunk's snapshot lanes start beside
    # the first chunk's lanes (rows beyond the second's), and the first chunk drains into it.
    spec = _spec(chunk_size=7, lanes=3)
    recs = record_inputs(spec)
    inputs = {k: v for k, v in recs.items() if k not in ("push_id", "from_grid", "case_id")}
    fns = early.make_lane_fns((), spec.duration_s, tree_passes=spec.tree_passes,
                              segment_ticks=spec.decisions.segment_ticks)
    params = traced_params(ControllerParams.paper())

    def chunk(i):
        rows = slice(7 * i, 7 * i + 7)
        return ({k: v[rows] for k, v in inputs.items()},
                chunk_keys(spec.seed, i, 7)[:len(inputs["onset_s"][rows])])

    one = [early.run_lanes(fns, *chunk(i), params, None, 3) for i in range(2)]
    stats = {}
    for cross in (False, True):
        out, stats[cross] = _streamed(LaneStream(3, params, None, cross=cross), fns, chunk, 2)
        for i in range(2):
            _assert_identical(out[i], one[i])
    # Across chunks the lanes of a draining chunk took the next chunk's pushes.
    assert stats[True]["idle_lane_segments"] < stats[False]["idle_lane_segments"]
    assert stats[True]["segments"] < stats[False]["segments"]
    # The sweep streams across chunks too, and a run resumed after its first chunk gives the
    # same records.
    whole = {k: np.concatenate([o[k] for o in one]) for k in one[0]}
    run_sweep(spec, tmp_path / "all", quiet=True, backend="mjx")
    _assert_identical({k: v for k, v in load(tmp_path / "all").items() if k in whole}, whole)
    run_sweep(spec, tmp_path / "resumed", max_chunks=1, quiet=True, backend="mjx")
    assert run_sweep(spec, tmp_path / "resumed", quiet=True,
                     backend="mjx")["chunks_computed_last_run"] == 1
    _assert_identical(load(tmp_path / "resumed"), load(tmp_path / "all"))


def test_claims_skip_chunks_another_writer_holds(tmp_path):
    (tmp_path / chunks.CLAIMS).mkdir()
    other = os.getppid()                     # a live process on this host, not this one
    (tmp_path / chunks.CLAIMS / "chunk_000001.claim").write_text(json.dumps(dict(
        pid=other, host=socket.gethostname(), start=None,
        time=time.time())))
    claims = chunks.Claims(tmp_path, [0, 1, 2], 3, None, time.monotonic() + 0.1)
    assert [claims.next(wait=False), claims.next(wait=False), claims.next(wait=False)] == \
        [0, 2, None]
    assert claims.next() is None             # chunk 1 still held when the deadline passes
    limited = chunks.Claims(tmp_path, [0, 2], 3, 1, time.monotonic())
    assert [limited.next(), limited.next()] == [0, None]


def test_decisions_keys_validate_and_keep_old_hashes():
    raw = {k: v for k, v in RAW.items()}
    plain = parse_spec({**raw, "sweep": {k: v for k, v in RAW["sweep"].items()
                                         if k not in ("decisions", "lanes", "segment_ticks")}})
    assert plain.decisions.mode == "full" and not plain.decisions.early
    said_full = _spec(decisions="full")
    args = (ControllerParams.paper(), ModelParams())
    assert spec_hash(plain, *args) == spec_hash(said_full, *args) != spec_hash(_spec(), *args)
    assert spec_hash(_spec(), *args) != spec_hash(_spec(lanes=2), *args)
    assert dataclasses.replace(plain, decisions=_spec().decisions).decisions.early
    for key, value, match in [("decisions", "soon", r"sweep.decisions: expected one of"),
                              ("lanes", 7, r"sweep.lanes: 7 exceeds sweep.chunk_size 6"),
                              ("lanes", 0, r"sweep.lanes: expected an integer in \[1, "),
                              ("segment_ticks", 0, r"sweep.segment_ticks: expected an integer")]:
        with pytest.raises(SpecError, match=match):
            _spec(**{key: value})
