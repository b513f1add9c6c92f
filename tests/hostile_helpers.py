"""Shared pieces of the hostile-input suites (tests/test_hostile_*.py): a tiny MuJoCo C spec,
running a command in-process and reading what it said, and the folder checks every case ends
with (nothing written, nothing mixed)."""

from __future__ import annotations

import json
from pathlib import Path

from tkujax.cli import main
from tkujax.sweeps import chunks

# 4 pushes of 0.3 s on MuJoCo C, 2 chunks: a second or two per run.
TINY = """
[sweep]
name = "hostile"
seed = 0
chunk_size = 2
duration_s = 0.3
control = ["off"]

[push.grid]
impulse_ns = [0.5]
azimuth_deg = [0, 180]
onset_s = [0.1]
height_m = [0.3, 0.36]
"""
N_TINY, CHUNKS_TINY = 4, 2


def run(capsys, *argv) -> tuple[int, str, str]:
    """(exit code, stdout, stderr) of `tkujax ARGV` run in this process."""
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:          # argparse's own errors
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


def refused(capsys, key: str, *argv, code: int = 2) -> str:
    """Run a command that must stop with `code` and one stderr line naming `key`; the line."""
    got, _, err = run(capsys, *argv)
    lines = [line for line in err.splitlines() if line.strip()]
    assert got == code, (got, err[-2000:])
    assert "Traceback" not in err, err[-2000:]
    assert len(lines) == 1, err
    assert key in lines[0], (key, lines[0])
    assert ".:" not in lines[0] and " .." not in lines[0], lines[0]
    return lines[0]


def nothing_written(out: Path) -> None:
    """No record and no temporary file in `out` (which may not exist)."""
    if not out.exists():
        return
    assert not list(out.glob("chunk_*.npz")), sorted(p.name for p in out.iterdir())
    assert not list(out.glob(".*.tmp"))


def folder_state(out: Path) -> dict:
    """{chunk file: sha256} and the manifest's chunk entries' sha256 of a sweep folder."""
    manifest = json.loads((out / chunks.MANIFEST).read_text())
    files = {p.name: chunks.sha256(p) for p in sorted(out.glob("chunk_*.npz"))}
    return dict(files=files, entries={k: v["sha256"] for k, v in manifest["chunks"].items()},
                spec_hash=manifest["spec_hash"])


def no_temporaries(out: Path) -> None:
    assert not list(out.glob(".*.tmp")), list(out.glob(".*.tmp"))
    assert not list(out.glob(f"{chunks.CLAIMS}/*")), list(out.glob(f"{chunks.CLAIMS}/*"))
