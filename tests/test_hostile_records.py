"""Records that nothing can mix, lose or misstate: concurrent writers of the same and of
different specs into one folder, inputs edited between runs, provenance across runs on other
backends, maps of an incomplete sweep, Ctrl-C mid-write. MuJoCo C, tiny grids, short horizons."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hostile_helpers import (CHUNKS_TINY, N_TINY, TINY, folder_state, no_temporaries, refused,
                             run)

from tkujax.sweeps import chunks
from tkujax.sweeps.sweep import load

ROOT = Path(__file__).resolve().parents[1]
OTHER = TINY.replace("impulse_ns = [0.5]", "impulse_ns = [0.6]")


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """TINY run once, uninterrupted: (spec, folder, records)."""
    base = tmp_path_factory.mktemp("hostile_ref")
    spec = base / "tiny.toml"
    spec.write_text(TINY)
    out = base / "ref"
    from tkujax.cli import main

    assert main(["sweep", str(spec), "--out", str(out), "--backend", "mujoco"]) == 0
    return spec, out, load(out)


def _same(a: dict, b: dict) -> None:
    assert sorted(a) == sorted(b)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def _env(**extra) -> dict:
    env = dict(os.environ, PYTHONPATH=str(ROOT), **extra)
    env.pop("XLA_FLAGS", None)
    return env


def _default_sigint() -> None:
    """Ctrl-C's default in the child, as at a terminal: a suite started in the background by a
    non-interactive shell inherits SIGINT ignored, and the Ctrl-C tests would send nothing."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _writer(spec: Path, out: Path, slow_s: float = 0.0) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tkujax.cli", "sweep", str(spec), "--out",
                             str(out), "--backend", "mujoco"],
                            env=_env(TKUJAX_TEST_SLOW_WRITE=str(slow_s)), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=_default_sigint)


# --- class 1: the check and the claim under one lock ---

def test_two_different_specs_at_once_one_is_refused(reference, tmp_path):
    spec_a, _, rec_a = reference
    spec_b = tmp_path / "other.toml"
    spec_b.write_text(OTHER)
    out = tmp_path / "shared"
    procs = [_writer(spec_a, out, 0.4), _writer(spec_b, out, 0.4)]
    results = [p.communicate(timeout=300) for p in procs]
    codes = [p.returncode for p in procs]
    assert sorted(codes) == [0, 2], [r[1][-2000:] for r in results]
    loser = results[codes.index(2)][1].strip().splitlines()
    assert len(loser) == 1 and str(out) in loser[0] and "another spec" in loser[0], loser
    manifest = chunks.read_manifest(out)
    assert manifest["complete"] and len(manifest["runs"]) == 1
    records = load(out)
    winner = codes.index(0)
    expected = {0: 0.5, 1: 0.6}[winner]
    assert np.all(records["impulse_ns"] == expected) and len(records["push_id"]) == N_TINY
    if winner == 0:
        _same(records, rec_a)
    no_temporaries(out)


def test_two_writers_of_one_spec_share_the_chunks(reference, tmp_path):
    spec, _, rec = reference
    out = tmp_path / "same"
    procs = [_writer(spec, out, 0.3) for _ in range(2)]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-2000:]
    manifest = chunks.read_manifest(out)
    assert manifest["complete"] and len(manifest["runs"]) == 2
    run_ids = {r["run_id"] for r in manifest["runs"]}
    assert {e["run_id"] for e in manifest["chunks"].values()} <= run_ids
    _same(load(out), rec)
    no_temporaries(out)


@pytest.mark.parametrize("trial", range(6))
def test_the_folder_claim_admits_one_spec_when_claims_race(tmp_path, trial):
    from tkujax.sweeps.sweep_folder import claim_folder

    out = tmp_path / "race"
    out.mkdir()
    barrier = threading.Barrier(2)
    results: dict[str, object] = {}

    def claim(name: str) -> None:
        barrier.wait()
        try:
            claim_folder(out, dict(spec_hash=name, name=name), {"spec": name},
                         dict(run_id=f"{name}-{trial}"))
            results[name] = "claimed"
        except ValueError as err:
            results[name] = str(err)

    threads = [threading.Thread(target=claim, args=(n,)) for n in ("a" * 16, "b" * 16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    won = [k for k, v in results.items() if v == "claimed"]
    assert len(won) == 1, results
    lost = [v for v in results.values() if v != "claimed"][0]
    assert str(out) in lost and "another spec" in lost and "the spec" in lost
    assert chunks.read_manifest(out)["spec_hash"] == won[0]


# --- class 2: every input by content; a resume with a changed input is refused ---

def _ensemble(path: Path, loss: float) -> Path:
    data = json.loads((ROOT / "results/calibration/expected/ensemble.json").read_text())
    data["members"] = data["members"][:2]
    data["members"][1]["loss"] = loss
    data["default_member"] = 0
    path.write_text(json.dumps(data))
    return path


EDITS = {
    # case: (first run's extra options, edit(tmp_path, spec) -> extra options, named input)
    "spec_impulse": ([], lambda d, s: (s.write_text(OTHER), [])[1], "the spec"),
    "spec_seed": ([], lambda d, s: (s.write_text(TINY.replace("seed = 0", "seed = 1")), [])[1],
                  "the spec"),
    "params_given": ([], lambda d, s: (d.joinpath("p.json").write_text('{"cp_gain": 1.1}'),
                                       ["--params", d / "p.json"])[1],
                     "the controller parameters"),
    "params_edited": (["--params", "P"], lambda d, s: (
        d.joinpath("p.json").write_text('{"cp_gain": 1.2}'), ["--params", d / "p.json"])[1],
        "the controller parameters"),
    "model_edited": (["--model", "M"], lambda d, s: (
        d.joinpath("m.json").write_text('{"floor_friction": 0.9}'), ["--model", d / "m.json"])[1],
        "the model"),
    "ensemble_edited": (["ENSEMBLE"], lambda d, s: (_ensemble(d / "ens.json", 0.123), [])[1],
                        "the ensemble file"),
}


def _first_options(tmp_path: Path, spec: Path, options: list) -> list:
    out = []
    for o in options:
        if o == "P":
            (tmp_path / "p.json").write_text('{"cp_gain": 1.1}')
            o = tmp_path / "p.json"
        elif o == "M":
            (tmp_path / "m.json").write_text('{"floor_friction": 1.0}')
            o = tmp_path / "m.json"
        elif o == "ENSEMBLE":
            _ensemble(tmp_path / "ens.json", 0.0)
            spec.write_text(TINY + f'\n[randomize]\nensemble = "{tmp_path / "ens.json"}"\n')
            continue
        out.append(o)
    return out


@pytest.mark.parametrize("case", list(EDITS))
def test_a_resume_with_an_edited_input_is_refused_naming_it(capsys, tmp_path, case):
    first, edit, named = EDITS[case]
    spec = tmp_path / "spec.toml"
    spec.write_text(TINY)
    out = tmp_path / "out"
    options = _first_options(tmp_path, spec, first)
    code, _, err = run(capsys, "sweep", spec, "--out", out, "--backend", "mujoco",
                       "--max-chunks", "1", *options)
    assert code == 0, err
    before = folder_state(out)
    again = edit(tmp_path, spec)
    line = refused(capsys, named, "sweep", spec, "--out", out, "--backend", "mujoco",
                   *(again or options))
    assert str(out) in line
    assert folder_state(out) == before          # nothing written, nothing lost


def test_a_robot_identity_covers_included_files_and_meshes(tmp_path):
    import shutil

    from tkujax.robot.robot_setup import file_digest
    from tkujax.sweeps.sweep_hash import changed_inputs

    src = ROOT.parent / "shared" / "models" / "robotis_op3"
    if not src.is_dir():
        pytest.skip("the OP3 model (shared/models/robotis_op3) is not on this machine")
    model = tmp_path / "robotis_op3"
    shutil.copytree(src, model)
    robot = tmp_path / "op3.toml"
    for beside in (ROOT / "specs/robots").glob("*.json"):   # files the robot file names
        shutil.copy(beside, tmp_path / beside.name)
    text = (ROOT / "specs/robots/op3.toml").read_text()
    robot.write_text(text.replace("${TKUJAX_MENAGERIE:-../../../shared/models}", str(tmp_path)))
    digests = [file_digest(robot)]
    mesh = model / "assets" / "body.stl"
    mesh.write_bytes(mesh.read_bytes() + b"\0")
    digests.append(file_digest(robot))
    included = model / "op3.xml"
    included.write_text(included.read_text().replace("<compiler", "<!-- edited -->\n<compiler"))
    digests.append(file_digest(robot))
    assert len(set(digests)) == 3
    assert changed_inputs({"robot": digests[0][:16]}, {"robot": digests[1][:16]}) == [
        "the robot file (--robot or [robot] file; with its model, included files and meshes)"]


# --- class 5: provenance per chunk, a run history never rewritten ---

def test_provenance_is_per_chunk_and_history_is_kept(capsys, reference, tmp_path):
    spec, _, rec = reference
    out = tmp_path / "prov"
    base = ("sweep", spec, "--out", out)
    assert run(capsys, *base, "--backend", "mujoco", "--max-chunks", "1")[0] == 0
    first = chunks.read_manifest(out)
    assert run(capsys, *base, "--backend", "mujoco")[0] == 0
    code, said, err = run(capsys, *base, "--backend", "mjx")    # nothing left: no compile
    assert code == 0 and "(mjx backend)" in said, err
    m = chunks.read_manifest(out)
    assert m["backend"] == "mujoco" and m["git_commit"] == first["git_commit"]
    assert [r["backend"] for r in m["runs"]] == ["mujoco", "mujoco", "mjx"]
    assert m["runs"][0] == first["runs"][0] | {k: m["runs"][0][k] for k in
                                               ("chunks_computed", "wall_s")}
    assert m["runs"][0]["chunks_computed"] == 1 and m["runs"][2]["chunks_computed"] == 0
    entries = [m["chunks"][chunks.chunk_name(i)] for i in range(CHUNKS_TINY)]
    assert [e["run_id"] for e in entries] == [r["run_id"] for r in m["runs"][:2]]
    assert all(e["backend"] == "mujoco" and e["device"] and e["git_commit"] == m["git_commit"]
               for e in entries)
    _same(load(out), rec)

    from tkujax.sweeps.replay import replay

    m["backend"] = "mjx"       # a top level naming another backend: the chunk's entry rules
    (out / chunks.MANIFEST).write_text(json.dumps(m))
    result = replay(out, 3)
    assert result["backend"] == "mujoco" and result["identical"]


def test_a_manifest_before_the_run_history_keeps_its_provenance(capsys, reference, tmp_path):
    import shutil

    spec, ref, _ = reference
    out = tmp_path / "old"
    shutil.copytree(ref, out)
    m = chunks.read_manifest(out)
    old = {k: v for k, v in m.items() if k not in ("runs", "inputs")} | {
        "backend": "mjx", "devices": ["cuda:0"], "git_commit": "0" * 40}
    (out / chunks.MANIFEST).write_text(json.dumps(old))
    assert run(capsys, "sweep", spec, "--out", out, "--backend", "mujoco")[0] == 0
    m = chunks.read_manifest(out)
    assert (m["backend"], m["devices"], m["git_commit"]) == ("mjx", ["cuda:0"], "0" * 40)
    assert m["runs"][0]["run_id"] == "before-run-history" and m["runs"][0]["backend"] == "mjx"
    assert m["runs"][1]["backend"] == "mujoco"


# --- class 4: maps of an incomplete sweep ---

def test_a_map_of_an_incomplete_sweep_is_refused_or_marked(capsys, reference, tmp_path):
    spec, _, _ = reference
    out = tmp_path / "partial"
    assert run(capsys, "sweep", spec, "--out", out, "--backend", "mujoco",
               "--max-chunks", "1")[0] == 0
    line = refused(capsys, "incomplete: 1 of 2 chunks", "map", out)
    assert "--allow-incomplete" in line and not (out / "maps").exists()
    code, said, err = run(capsys, "map", out, "--allow-incomplete")
    assert code == 0, err
    summary = (out / "maps" / "summary.md").read_text()
    assert summary.startswith("**incomplete: 1 of 2 chunks**")
    assert json.loads((out / "maps" / "summary.json").read_text())["incomplete"] == \
        "incomplete: 1 of 2 chunks"


# --- class 7: no re-hash of every chunk at the end of a run ---

def test_a_noop_rerun_hashes_each_chunk_once(capsys, monkeypatch, reference):
    spec, ref, _ = reference
    calls = []
    real = chunks.sha256
    monkeypatch.setattr(chunks, "sha256", lambda p: calls.append(Path(p).name) or real(p))
    chunks.forget_verified()
    import shutil

    out = ref.parent / "noop"
    shutil.copytree(ref, out, dirs_exist_ok=True)
    assert run(capsys, "sweep", spec, "--out", out, "--backend", "mujoco")[0] == 0
    assert sorted(calls) == [chunks.chunk_name(i) for i in range(CHUNKS_TINY)]


def test_a_changed_chunk_is_still_seen_after_it_was_verified(reference, tmp_path):
    import shutil

    _, ref, _ = reference
    out = tmp_path / "changed"
    shutil.copytree(ref, out)
    assert chunks.done_chunks(out, CHUNKS_TINY) == set(range(CHUNKS_TINY))
    bad = out / chunks.chunk_name(1)
    data = bytearray(bad.read_bytes())
    data[len(data) // 2] ^= 0xFF
    time.sleep(0.01)
    bad.write_bytes(bytes(data))
    assert chunks.done_chunks(out, CHUNKS_TINY) == {0}


# --- class 9: Ctrl-C ---

@pytest.mark.parametrize("moment", ["mid_write", "after_claim"])
def test_ctrl_c_says_how_to_resume_and_leaves_no_temporary(reference, tmp_path, moment):
    spec, _, rec = reference
    out = tmp_path / "interrupted"
    proc = _writer(spec, out, slow_s=2.0)
    t0 = time.monotonic()
    pattern = ".chunk_*.tmp" if moment == "mid_write" else f"{chunks.CLAIMS}/*.claim"
    while proc.poll() is None and time.monotonic() - t0 < 120 and not list(out.glob(pattern)):
        time.sleep(0.02)
    assert proc.poll() is None, proc.communicate()[1][-2000:]
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert err.strip().splitlines()[-1] == ("tkujax sweep: interrupted; rerun the same command "
                                           "to resume")
    assert "Traceback" not in err
    no_temporaries(out)
    from tkujax.sweeps.sweep import run_sweep

    assert run_sweep(spec, out, quiet=True, backend="mujoco")["complete"]
    _same(load(out), rec)
