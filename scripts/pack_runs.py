"""Pack a tuning study's per-run files (DIR/runs/*.json) into one gzip'd JSON-lines file
(DIR/runs.jsonl.gz, one run per line with its file name under "run"), or unpack it back, so
that a committed study keeps every run at a fifth of the size and a rerun can still resume
from the files `tkujax tune` writes (a rerun skips the runs whose file exists).

    python scripts/pack_runs.py results/gradients_paper            # runs/ -> runs.jsonl.gz
    python scripts/pack_runs.py results/gradients_paper --unpack   # runs.jsonl.gz -> runs/
"""

from __future__ import annotations

import argparse
import gzip
import json
from pathlib import Path

PACKED = "runs.jsonl.gz"


def pack(study: Path) -> Path:
    """Write study/runs.jsonl.gz from study/runs/*.json (sorted by name) and remove runs/."""
    files = sorted((study / "runs").glob("*.json"))
    if not files:
        raise SystemExit(f"{study / 'runs'}: no *.json run files to pack")
    out = study / PACKED
    with gzip.GzipFile(out, "wb", mtime=0) as fh:     # mtime 0: the same bytes for the same runs
        for f in files:
            row = {"run": f.stem, **json.loads(f.read_text())}
            fh.write((json.dumps(row, separators=(",", ":")) + "\n").encode())
    for f in files:
        f.unlink()
    (study / "runs").rmdir()
    return out


def unpack(study: Path) -> Path:
    """Write study/runs/<run>.json for each line of study/runs.jsonl.gz."""
    runs = study / "runs"
    runs.mkdir(exist_ok=True)
    with gzip.open(study / PACKED, "rt") as fh:
        for line in fh:
            row = json.loads(line)
            name = row.pop("run")
            (runs / f"{name}.json").write_text(json.dumps(row, indent=1))
    return runs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("study", type=Path, help="a study folder (tkujax tune --out)")
    ap.add_argument("--unpack", action="store_true", help="runs.jsonl.gz -> runs/*.json")
    args = ap.parse_args()
    print(unpack(args.study) if args.unpack else pack(args.study))


if __name__ == "__main__":
    main()
