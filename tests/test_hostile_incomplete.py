"""Analyses of unfinished work: every reader of a sweep folder (map, compare, capture, export,
view, and the library's load) refuses an incomplete sweep, naming the folder and "incomplete:
k of n chunks", or with --allow-incomplete reads it marked as such; one rule decides
(`tkujax.sweeps.sweep_state`), judged from the chunk files, not the manifest's flag. MuJoCo C,
the tiny spec of tests/hostile_helpers.py, one of its two chunks."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from hostile_helpers import CHUNKS_TINY, TINY, refused, run

import tkujax
from tkujax.sweeps import chunks
from tkujax.studies.capture.region import analyse
from tkujax.sweeps.sweep_state import IncompleteSweep, require_complete, sweep_state

MARK = f"incomplete: 1 of {CHUNKS_TINY} chunks"


@pytest.fixture(scope="module")
def partial(tmp_path_factory):
    """(spec, a folder with 1 of 2 chunks, the same sweep complete)."""
    from tkujax.cli import main

    base = tmp_path_factory.mktemp("incomplete")
    spec = base / "tiny.toml"
    spec.write_text(TINY)
    whole, part = base / "whole", base / "part"
    assert main(["sweep", str(spec), "--out", str(whole), "--backend", "mujoco"]) == 0
    assert main(["sweep", str(spec), "--out", str(part), "--backend", "mujoco",
                 "--max-chunks", "1"]) == 0
    return spec, part, whole


def test_one_rule_counts_the_chunk_files_not_the_flag(partial, tmp_path):
    _, part, whole = partial
    assert sweep_state(whole).complete and sweep_state(whole).mark == ""
    state = sweep_state(part)
    assert (state.complete, state.chunks_done, state.n_chunks) == (False, 1, CHUNKS_TINY)
    # A chunk lost after the run: the manifest still says complete, the rule does not.
    lost = tmp_path / "lost"
    shutil.copytree(whole, lost)
    (lost / chunks.chunk_name(1)).unlink()
    assert json.loads((lost / chunks.MANIFEST).read_text())["complete"] is True
    with pytest.raises(IncompleteSweep, match=f"{lost} is an incomplete sweep \\({MARK}\\)"):
        require_complete(lost, reader="tkujax map")
    assert require_complete(lost, allow_incomplete=True).mark == MARK


def test_load_says_whether_the_sweep_is_complete(partial, tmp_path):
    _, part, whole = partial
    rec = tkujax.load(part)
    assert rec.complete is False and rec.state.mark == MARK and len(rec["fell"]) == 2
    assert tkujax.load(whole).complete is True
    frame = pytest.importorskip("pandas") and tkujax.load(part, as_frame=True)
    assert frame.attrs["complete"] is False and frame.attrs["chunks_done"] == 1


def test_map_compare_export_view_refuse_an_incomplete_sweep(capsys, partial, tmp_path):
    _, part, whole = partial
    line = refused(capsys, MARK, "map", part)
    assert str(part) in line and "--allow-incomplete" in line
    assert not (part / "maps").exists()
    line = refused(capsys, MARK, "compare", whole, part, "--out", tmp_path / "cmp")
    assert str(part) in line and not (tmp_path / "cmp").exists()
    target = tmp_path / "part.parquet"
    line = refused(capsys, MARK, "export", part, "--out", target)
    assert str(part) in line and not target.exists()
    refused(capsys, MARK, "view", part, "--serve-s", "0")
    with pytest.raises(IncompleteSweep, match=MARK):
        analyse(part)                             # capture's analysis of a folder
    assert not (part / "capture").exists()


def test_compare_and_export_read_it_marked_when_allowed(capsys, partial, tmp_path):
    _, part, _ = partial
    code, _, err = run(capsys, "compare", f"{part}:off", f"{part}:off", "--out",
                       tmp_path / "cmp", "--allow-incomplete", "--min-pushes", "1")
    assert code == 0, err
    verdict = json.loads((tmp_path / "cmp" / "verdict.json").read_text())
    assert set(verdict["incomplete"].values()) == {MARK}
    assert MARK in (tmp_path / "cmp" / "summary.md").read_text()
    target = tmp_path / "part.parquet"
    assert run(capsys, "export", part, "--out", target, "--allow-incomplete")[0] == 0
    back = tkujax.load(target)
    assert back.complete is False and back.state.mark == MARK
    np.testing.assert_array_equal(back["push_id"], tkujax.load(part)["push_id"])


def test_capture_analyses_an_incomplete_step_sweep_only_marked(capsys, monkeypatch, tmp_path):
    """A [step] sweep stopped after one chunk: capture says so and writes no analysis; with
    --allow-incomplete its outputs carry the mark, every figure included."""
    from tkujax.studies.capture import figures

    marked = []
    real = figures.mark_figure
    monkeypatch.setattr(figures, "mark_figure", lambda fig, m: marked.append(m) or real(fig, m))
    spec = tmp_path / "step.toml"
    spec.write_text(TINY.replace('name = "hostile"', 'name = "hostile_step"')
                    + "\n[step.grid]\nx_m = [0.0]\ny_m = [0.0]\n")
    out = tmp_path / "cap"
    mark = "incomplete: 1 of 4 chunks"      # 4 pushes x (the grid's step and no step)
    args = ["capture", spec, "--out", out, "--optimise", "0", "--max-chunks", "1",
            "--backend", "mujoco"]
    code, said, err = run(capsys, *args)
    assert code == 0, err
    assert mark in said and "--allow-incomplete" in said and not (out / "capture").exists()
    code, said, err = run(capsys, *args, "--allow-incomplete")   # resumes one more chunk
    assert code == 0, err
    mark = "incomplete: 2 of 4 chunks"
    assert (out / "capture" / "summary.md").read_text().startswith(f"**{mark}**")
    assert json.loads((out / "capture" / "regions.json").read_text())["incomplete"] == mark
    assert marked == [mark] * len(list((out / "capture").glob("*.png"))) and marked
