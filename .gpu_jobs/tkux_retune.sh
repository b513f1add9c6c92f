#!/usr/bin/env bash
# Re-tune the recommended recovery policy on today's default robot (one GPU): one run of
# specs/tune/tune_policy_current.toml, sep-CMA-ES by default or the line search at the same
# wall clock, compile included. Then evaluate with .gpu_jobs/tkux_retune_eval.sh.
#
#   bash .gpu_jobs/tkux_retune.sh              # sep-CMA-ES  -> /tmp/retune, $OUT/retune_sepcma.tar.gz
#   bash .gpu_jobs/tkux_retune.sh linesearch   # line search -> the same study folder
#
# Run from the repository root (or anywhere: it changes to the folder above this script when
# the spec is not in the current one). Needs jax, mujoco and mujoco-mjx installed; tkujax is
# run from the source tree (PYTHONPATH), through `python3 -m tkujax.cli`.
#
# Time on one H200, estimated (the spec's header gives the sources): the run's clock is
# study.budget_s = 300 s with its compiles; outside it start-up and the 39 robots (~20-30 s),
# the control-off pass of the training batch (~30 s) and the evaluation (~25 s): ~370-410 s
# in all. Both methods back to back (~800 s) do not fit one 600 s call: one call per method.
# On one warm machine the second call adds its run to /tmp/retune, and study.md then compares
# the two; on a fresh machine the folder holds that run alone.
#
# Environment: OUT (where the tar goes; default /tmp/retune_out), PY (default python3),
# SPEC (default specs/tune/tune_policy_current.toml), BUDGET_S (overrides study.budget_s),
# TUNE_OUT (default /tmp/retune).
set -uo pipefail

METHOD=${1:-sepcma}
case "$METHOD" in sepcma|linesearch) ;; *) echo "method: sepcma or linesearch, got $METHOD" >&2; exit 2;; esac
SPEC=${SPEC:-specs/tune/tune_policy_current.toml}
if [ ! -f "$SPEC" ]; then cd "$(dirname "$0")/.." || exit 2; fi
ROOT=$(pwd)
PY=${PY:-python3}
OUT=${OUT:-/tmp/retune_out}
TUNE_OUT=${TUNE_OUT:-/tmp/retune}
LOGS=$TUNE_OUT/logs
export PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}"
export TKUJAX_CACHE_DIR=${TKUJAX_CACHE_DIR:-/tmp/retune_cache}
mkdir -p "$OUT" "$TUNE_OUT" "$LOGS" "$TKUJAX_CACHE_DIR"

T0=$(date +%s%N)
seconds_since() {   # seconds_since NANOSECONDS: one decimal
  local d=$(( ($(date +%s%N) - $1) / 100000000 ))
  printf '%d.%d' $((d / 10)) $((d % 10))
}
RC=0
step() {   # step NAME CMD...: run it, log its output, time it; a failure is kept in RC
  local name=$1; shift
  local s rc
  s=$(date +%s%N)
  echo "== $name: $*" | tee -a "$LOGS/commands.txt"
  "$@" 2>&1 | tee "$LOGS/$name.log"
  rc=${PIPESTATUS[0]}
  printf '%s\t%s\trc=%d\n' "$name" "$(seconds_since "$s")" "$rc" | tee -a "$LOGS/timings.tsv"
  if [ "$rc" -ne 0 ]; then RC=$rc; fi
}

{
  echo "date: $(date -u +%FT%TZ)"
  echo "commit: $(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo unknown)"
  nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
  "$PY" -c "import jax, mujoco; print('jax', jax.__version__, jax.devices()); print('mujoco', mujoco.__version__)"
} > "$LOGS/device_$METHOD.txt" 2>&1

budget=()
if [ -n "${BUDGET_S:-}" ]; then budget=(--budget-s "$BUDGET_S"); fi
step "tune_$METHOD" "$PY" -m tkujax.cli tune "$SPEC" --out "$TUNE_OUT" --only "method=$METHOD" \
  "${budget[@]}"

printf 'total\t%s\n' "$(seconds_since "$T0")" | tee -a "$LOGS/timings.tsv"
# Everything small comes back in one tar (no XLA cache, no records), the policy beside it.
tar czf "$OUT/retune_$METHOD.tar.gz" -C "$(dirname "$TUNE_OUT")" "$(basename "$TUNE_OUT")"
if [ -f "$TUNE_OUT/best_policy.json" ]; then cp "$TUNE_OUT/best_policy.json" "$OUT/best_policy.json"; fi
ls -la "$OUT"
exit "$RC"
