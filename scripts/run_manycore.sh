#!/usr/bin/env bash
# The full calibration on a many-core machine (e.g. the 16-core device host; the search uses
# the MuJoCo C backend, so it needs CPU cores, not the GPU). Self-contained: writes under $OUT
# (default ./out), never into the spec. Run from the repository root with the project's venv
# active. Rerunning it into the same $OUT resumes from $OUT/calibration/archive.jsonl.
#   OUT=/some/dir bash scripts/run_manycore.sh [budget_s] [workers]
set -euo pipefail
OUT=${OUT:-./out}
BUDGET=${1:-540}
WORKERS=${2:-$(( $(nproc) - 1 ))}
mkdir -p "$OUT/calibration"
export TKUJAX_CAL_THREADS=1
python -m tkujax.cli calibrate specs/calibrate/calibrate.toml --out "$OUT/calibration" \
    --budget-s "$BUDGET" --workers "$WORKERS"
