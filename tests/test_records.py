"""Records a researcher can trust: the diverged column, chunk integrity (sha256 + rows in the
manifest), claims for concurrent writers, SIGKILL fault injection, replay, pandas.

Everything runs the MuJoCo C backend on a 16-push spec (1 push per chunk, 1 s pushes), so the
module stays cheap: the expensive part is starting ~13 Python processes (imports, cached jit).
"""

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

from tkujax.sim import metrics
from tkujax.sim.records import Series
from tkujax.sweeps import chunks
from tkujax.analysis.maps import max_recoverable_impulse
from tkujax.control.params_files import load_controller_params_json as load_params_json
from tkujax.sweeps.sweep import load, run_sweep

ROOT = Path(__file__).resolve().parents[1]
SPEC = """
[sweep]
name = "records"
seed = 3
chunk_size = 1
duration_s = 1.0
[push.grid]
impulse_ns = [0.5, 2.2]
azimuth_deg = [0, 90, 180, 270]
onset_s = [0.3]
"""
N = 16


def _series(n: int = 40, **override) -> Series:
    t = np.arange(1, n + 1) * 0.03
    cols = dict(t=t, pitch=np.full(n, 0.12), roll=np.zeros(n), pitch_est=np.zeros(n),
                roll_est=np.zeros(n), zmp=np.zeros((n, 2)), fsr_total=np.full(n, 44.0),
                com=np.tile([0.0, 0.0, 0.25], (n, 1)), r_ankle=np.zeros((n, 3)),
                l_ankle=np.zeros((n, 3)), pelvis_z=np.full(n, 0.3),
                lowest_body_z=np.full(n, 0.1), gate=np.zeros(n), x_sup=np.zeros(n),
                y_sup=np.zeros(n), step_weight=np.zeros(n), reachable=np.ones(n))
    cols.update(override)
    return Series(**{k: jnp.asarray(v, jnp.float32) for k, v in cols.items()})


def test_diverged_and_nan_never_survives():
    ok = metrics.outcomes(_series(), 0.3)
    assert not bool(ok.diverged) and not bool(ok.fell)
    nan_z = np.full(40, 0.3)
    nan_z[20:] = np.nan
    bad = metrics.outcomes(_series(pelvis_z=nan_z), 0.3)
    assert bool(bad.diverged) and bool(bad.fell)        # NaN is never "survived"
    assert bool(metrics.fall_indicator(_series(pelvis_z=nan_z))[25])
    com = np.tile([0.0, 0.0, 0.25], (40, 1))
    com[30:, 0] = 1.0                                    # 1 m in one 30 ms period: 33 m/s
    assert bool(metrics.outcomes(_series(com=com), 0.3).diverged)
    com[30:, 0] = 0.03                                   # 1 m/s: a physical speed
    assert not bool(metrics.outcomes(_series(com=com), 0.3).diverged)


def test_maps_leave_diverged_records_out():
    rec = dict(control=np.ones(3, bool), azimuth_deg=np.zeros(3),
               impulse_ns=np.array([1.0, 2.0, 3.0]),
               fell=np.array([False, True, True]), diverged=np.array([False, True, False]))
    azs, jmax = max_recoverable_impulse(rec, True)
    assert jmax[0] == 1.0 and len(azs) == 1               # 2.0 (diverged) is no cell at all


def test_half_fall_impulse_interpolates_between_tested_impulses():
    """Fall fractions 0, 1/4, 3/4 at 1, 2, 3 N s from the front: 1/2 lies half way from 2 to 3;
    from behind nothing falls (inf); random records never count beside grid ones."""
    from tkujax.analysis.map_cells import half_fall_impulse

    j = np.repeat([1.0, 2.0, 3.0], 4)
    front = np.array([0, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 0], bool)
    rec = dict(control=np.ones(30, bool), azimuth_deg=np.r_[np.zeros(12), np.full(12, 180.0),
                                                               np.zeros(6)],
               impulse_ns=np.r_[j, j, np.full(6, 0.5)], fell=np.r_[front, np.zeros(12, bool),
                                                                    np.ones(6, bool)],
               from_grid=np.r_[np.ones(24, bool), np.zeros(6, bool)])
    azs, j50 = half_fall_impulse(rec, True)
    np.testing.assert_allclose(azs, [0.0, 180.0])
    assert j50[0] == pytest.approx(2.5) and j50[1] == np.inf


@pytest.mark.parametrize("value, match", [
    ('{"step_period": "x"}', r"step_period must be a number in \(0, 2\] s, got 'x'"),
    ('{"lateral_steps": true}', r"lateral_steps must be a number in \{0, 1\}"),
    ('{"eps_forward": null}', r"eps_forward must be a number in \[0, pi/2\) rad"),
    ('[1, 2]', r"expected a JSON object"),
])
def test_params_json_names_key_and_range(tmp_path, value, match):
    (tmp_path / "p.json").write_text(value)
    with pytest.raises(ValueError, match=match):
        load_params_json(tmp_path / "p.json")


# --- One reference run; every other run must reproduce it exactly ---

@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    base = tmp_path_factory.mktemp("records")
    spec = base / "records.toml"
    spec.write_text(SPEC)
    out = base / "ref"
    manifest = run_sweep(spec, out, quiet=True, backend="mujoco")
    assert manifest["complete"] and manifest["n_chunks"] == N and manifest["n_diverged"] == 0
    return spec, out, load(out)


def _same(a: dict, b: dict):
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)   # NaN == NaN here


def _env(**extra):
    env = dict(os.environ, PYTHONPATH=str(ROOT), **extra)
    env.pop("XLA_FLAGS", None)
    return env


def _writer(spec, out, slow_s: float) -> subprocess.Popen:
    code = ("import json, sys; from tkujax.cli import configure_runtime; configure_runtime(); "
            "from tkujax.sweeps.sweep import run_sweep; "
            "m = run_sweep(sys.argv[1], sys.argv[2], quiet=True, backend='mujoco'); "
            "print(json.dumps(dict(computed=m['chunks_computed_last_run'], "
            "complete=m['complete'])))")
    return subprocess.Popen([sys.executable, "-c", code, str(spec), str(out)],
                            env=_env(TKUJAX_TEST_SLOW_WRITE=str(slow_s)),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_manifest_records_sha256_and_rows(reference):
    _, out, rec = reference
    entries = json.loads((out / "manifest.json").read_text())["chunks"]
    assert sorted(entries) == [chunks.chunk_name(i) for i in range(N)]
    for name, e in entries.items():
        assert e["rows"] == 1 and e["sha256"] == chunks.sha256(out / name)
    np.testing.assert_array_equal(rec["push_id"], np.arange(N))
    assert rec["diverged"].dtype == bool and not rec["diverged"].any()


@pytest.mark.parametrize("damage", ["truncate", "flip_byte", "delete"])
def test_damaged_chunk_is_named_and_recomputed(reference, tmp_path, damage):
    _, ref, rec = reference
    out = tmp_path / "run"
    shutil.copytree(ref, out)
    bad = out / chunks.chunk_name(5)
    data = bad.read_bytes()
    if damage == "truncate":
        bad.write_bytes(data[:len(data) // 2])
    elif damage == "flip_byte":
        i = len(data) // 2
        bad.write_bytes(data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1:])
    else:
        bad.unlink()
    with pytest.raises(chunks.ChunkError, match="chunk_000005.npz"):
        load(out)
    manifest = run_sweep(reference[0], out, quiet=True, backend="mujoco")
    assert manifest["complete"] and manifest["chunks_computed_last_run"] == 1
    _same(load(out), rec)


def _claims_of(out: Path, pid: int) -> list[Path]:
    mine = []
    for claim in (out / chunks.CLAIMS).glob("*.claim"):
        try:
            if json.loads(claim.read_text())["pid"] == pid:
                mine.append(claim)
        except (OSError, ValueError, KeyError):
            pass
    return mine


def test_sigkill_loop_then_resume_gives_identical_records(reference, tmp_path):
    """>= 10 SIGKILLs, each followed by a resume; the end equals the reference. Odd kills land
    at random moments; even ones wait for the writer to be mid-write (its temporary file, or a
    renamed chunk not yet in the manifest: TKUJAX_TEST_SLOW_WRITE holds each for 0.3 s), so
    that the mid-write path is exercised whatever the machine's load."""
    spec, _, rec = reference
    out = tmp_path / "killed"
    rng = random.Random(14)
    kills = mid_write = 0

    def writing(pid: int) -> bool:
        entries = chunks.read_manifest(out).get("chunks", {})
        return bool(list(out.glob(f".chunk_*.npz.{pid}.tmp"))) or any(
            p.name not in entries for p in out.glob("chunk_*.npz"))

    for attempt in range(40):
        if kills >= 10:
            break
        proc = _writer(spec, out, slow_s=0.6)
        t0 = time.monotonic()       # wait until it works on a chunk (or gives up after 60 s)
        while (proc.poll() is None and time.monotonic() - t0 < 60
               and not _claims_of(out, proc.pid)):
            time.sleep(0.05)
        if attempt % 2 == 0:        # until it is mid-write (or 60 s)
            while proc.poll() is None and time.monotonic() - t0 < 60 and not writing(proc.pid):
                time.sleep(0.01)
        else:
            time.sleep(rng.uniform(0.0, 1.5))
        if proc.poll() is not None:          # it finished first: not a kill
            assert proc.returncode == 0, proc.stderr.read()[-3000:]
            break
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()                          # reap it: a zombie's pid still looks alive
        kills += 1
        mid_write += writing(proc.pid)
    assert kills >= 10, f"only {kills} kills landed before the sweep finished"
    assert mid_write >= 1, "no kill landed mid-write"
    final = _writer(spec, out, slow_s=0.0)
    stdout, stderr = final.communicate(timeout=600)
    assert final.returncode == 0, stderr[-3000:]
    assert json.loads(stdout.splitlines()[-1])["complete"]
    _same(load(out), rec)                    # nothing lost, nothing duplicated
    assert not list(out.glob(".*.tmp")) and not list((out / chunks.CLAIMS).glob("*"))


def test_two_concurrent_writers_split_the_chunks(reference, tmp_path):
    spec, _, rec = reference
    out = tmp_path / "shared"
    procs = [_writer(spec, out, slow_s=0.3) for _ in range(2)]
    results = [p.communicate(timeout=600) for p in procs]
    for p, (_, err) in zip(procs, results):
        assert p.returncode == 0, err[-3000:]
    computed = [json.loads(o.splitlines()[-1])["computed"] for o, _ in results]
    assert sum(computed) == N and min(computed) >= 1, computed   # no chunk written twice
    _same(load(out), rec)


def test_claims_live_and_stale(reference, tmp_path):
    spec, ref, rec = reference
    out = tmp_path / "claims"
    shutil.copytree(ref, out)
    (out / chunks.chunk_name(2)).unlink()
    claim = out / chunks.CLAIMS / "chunk_000002.claim"
    claim.parent.mkdir(exist_ok=True)
    me = chunks._me()
    live = subprocess.Popen(["sleep", "60"])
    try:
        claim.write_text(json.dumps(dict(me, pid=live.pid, start=chunks._proc_start(live.pid),
                                         time=time.time())))
        held = run_sweep(spec, out, quiet=True, backend="mujoco", wait_for_others_s=1.0)
        assert not held["complete"] and held["chunks_computed_last_run"] == 0   # respected
    finally:
        live.kill()
        live.wait()
    claim.write_text(json.dumps(dict(me, pid=live.pid, time=time.time())))   # now dead: stale
    other_host = dict(me, host="elsewhere", time=time.time() - 7 * 3600)      # too old: stale
    (out / chunks.CLAIMS / "chunk_000003.claim").write_text(json.dumps(other_host))
    (out / chunks.chunk_name(3)).unlink()
    done = run_sweep(spec, out, quiet=True, backend="mujoco")
    assert done["complete"] and done["chunks_computed_last_run"] == 2
    _same(load(out), rec)


def test_replay_reproduces_a_record(reference, tmp_path, capsys):
    from tkujax.cli import main
    from tkujax.sweeps.replay import replay

    _, out, rec = reference
    i = int(np.flatnonzero(rec["fell"])[0])
    result = replay(out, i)
    assert result["identical"] and result["same_outcome"] and result["stored"]["fell"]
    assert result["qpos"].shape[0] == round(1.0 / 0.03)
    with pytest.raises(ValueError, match=r"--index must be in \[0, 15\]"):
        replay(out, N)
    gif = tmp_path / "r.gif"
    assert main(["replay", str(out), "--index", str(i), "--out", str(gif)]) == 0
    text = capsys.readouterr()
    assert "replayed outcome equals the stored one" in text.out
    from tkujax import render
    if render.rendering_available()[0]:
        assert gif.stat().st_size > 10_000
    else:
        assert "rendering is unavailable" in text.err


def test_replay_of_an_older_manifest_fills_what_it_lacks_as_the_code_was(reference, tmp_path,
                                                                        capsys):
    """A manifest without fields added since (an older tkujax wrote it): the IMU low-pass takes
    the value from before it existed (none), not today's default, and the replay says which
    fields it filled, with what."""
    import shutil

    from tkujax.cli import main
    from tkujax.model import ModelParams
    from tkujax.sweeps.record_schema import added_fields, manifest_model_params
    from tkujax.sweeps.replay import replay

    _, out, rec = reference
    assert replay(out, 0)["fields_missing"] == {}
    old = tmp_path / "old"
    shutil.copytree(out, old)
    manifest = json.loads((old / chunks.MANIFEST).read_text())
    assert manifest["model_params"]["accel_lowpass_hz"] == ModelParams().accel_lowpass_hz > 0
    for name in added_fields("model_params"):
        del manifest["model_params"][name]
    del manifest["controller_params"]["stance_ankle_kp"]
    del manifest["schema_version"]               # as an older tkujax wrote it
    (old / chunks.MANIFEST).write_text(json.dumps(manifest))
    assert manifest_model_params(manifest).accel_lowpass_hz == 0.0
    i = int(np.flatnonzero(rec["control"])[0])
    result = replay(old, i)
    assert result["fields_missing"] == {"model_params.accel_lowpass_hz": 0.0,
                                        "model_params.gyro_lowpass_hz": 0.0,
                                        "controller_params.stance_ankle_kp": 0.0}
    assert not result["identical"]        # the sweep ran with today's 7.5 Hz low-pass
    assert main(["replay", str(old), "--index", str(i)]) in (0, 1)
    assert "its manifest lacks 3 field(s)" in capsys.readouterr().out


def test_a_new_sweep_records_the_schema_version(reference):
    """A new manifest names its record schema version and records every field it has."""
    from tkujax.sweeps.record_schema import (SCHEMA_KEY, SCHEMA_VERSION, fields_missing,
                                             fields_of)

    manifest = chunks.read_manifest(reference[1])
    assert manifest[SCHEMA_KEY] == SCHEMA_VERSION and fields_missing(manifest) == {}
    assert manifest["tree_passes"] == "compact"          # the sweeps' default, recorded
    for group in ("controller_params", "model_params"):
        assert set(manifest[group]) == set(fields_of(SCHEMA_VERSION, group))


def test_load_as_frame(reference):
    pd = pytest.importorskip("pandas")
    frame = load(reference[1], as_frame=True)
    assert isinstance(frame, pd.DataFrame) and len(frame) == N and "diverged" in frame


def test_as_frame_without_pandas_says_how(reference, monkeypatch):
    monkeypatch.setitem(sys.modules, "pandas", None)      # import pandas -> ImportError
    with pytest.raises(ImportError, match="pip install pandas"):
        load(reference[1], as_frame=True)
