#!/usr/bin/env bash
# Evaluate a re-tuned policy on the project's held-out sets (one GPU), paired with the shipped
# recommended policy and control off: specs/sweep/recovery_eval.toml (the default robot,
# randomised as in tuning) and specs/sweep/recovery_eval_shift.toml (a shifted robot), 19,600
# pushes each, 0.1-3.0 N s, every direction and hit phase.
#
#   bash .gpu_jobs/tkux_retune_eval.sh [POLICY.json]     # default /tmp/retune/best_policy.json
#
# Per set: one sweep with `--params recommended` (the shipped policy; its control-off records
# are the reference: results/recovery_eval and results/tune_dimension commit only summaries,
# not the records, so the comparison needs them again) and one with the new policy, then
# `tkujax compare` with the bands of results/recovery_eval (4 sectors x impulse edges
# 0.1,0.6,1.0,1.4,1.8,2.2,3.0 N s x 3 phase bands, and the phases pooled; >= 100 pushes;
# harmed when worse than control off by > 2 points), a second compare against the shipped
# policy itself, the 50 %-fall impulse per azimuth (scripts/j50_by_direction.py), and
# headline.json / headline.md: fall rates, ratio to control off, harmed cells, J50 from behind,
# against the targets (<= 0.5x control off, no harmed cell, J50 from behind >= 2.0 N s).
# Every sweep runs control off and on: the sets' specs say so, and compare pairs runs of one
# spec only.
#
# Time on one H200, estimated: a sweep is 39,200 rollouts x 2.0 s, ~10 s at the H200's
# ~3,800 rollouts/s of 2.0 s at batch 16,384 (docs/performance.md: 5,050 pushes/s of 1.5 s),
# plus start-up (~10 s) and its compile (~30-40 s cold; the four sweeps share one program, the
# schedule's numbers being inputs, so three of them read it from the XLA cache, ~10 s):
# ~4 x 30-60 s; the compares and J50s ~60 s on the host. About 200-300 s in all (the spec's
# header: "~1 min a run" on an H100). It does not fit after the tune in one 600 s call.
#
# The policy: /tmp/retune/best_policy.json when this runs on the machine that tuned (still
# warm); otherwise put the tune's best_policy.json in the working tree and pass its path.
# Environment: OUT (default /tmp/retune_out), PY (default python3), SPEC_DIR (default
# specs/sweep), SETS (default "recovery_eval recovery_eval_shift"), EVAL_OUT (default
# /tmp/retune_eval), RUNS (the records; default /tmp/retune_eval_runs), MIN_PUSHES (default
# 100, as results/recovery_eval).
set -uo pipefail

POLICY=${1:-/tmp/retune/best_policy.json}
SPEC_DIR=${SPEC_DIR:-specs/sweep}
if [ ! -d "$SPEC_DIR" ]; then cd "$(dirname "$0")/.." || exit 2; fi
ROOT=$(pwd)
PY=${PY:-python3}
OUT=${OUT:-/tmp/retune_out}
EVAL_OUT=${EVAL_OUT:-/tmp/retune_eval}
SETS=${SETS:-recovery_eval recovery_eval_shift}
MIN_PUSHES=${MIN_PUSHES:-100}
EDGES=0.1,0.6,1.0,1.4,1.8,2.2,3.0
RUNS=${RUNS:-/tmp/retune_eval_runs}     # the sweeps' records: not packed
LOGS=$EVAL_OUT/logs
export PYTHONPATH="$ROOT${PYTHONPATH:+:$PYTHONPATH}"
export TKUJAX_CACHE_DIR=${TKUJAX_CACHE_DIR:-/tmp/retune_cache}
if [ ! -f "$POLICY" ]; then echo "no policy file $POLICY" >&2; exit 2; fi
mkdir -p "$OUT" "$EVAL_OUT" "$LOGS" "$RUNS" "$TKUJAX_CACHE_DIR"
cp "$POLICY" "$EVAL_OUT/policy_evaluated.json"

T0=$(date +%s%N)
seconds_since() {
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
  echo "policy: $POLICY ($(sha256sum "$POLICY" | cut -c1-16))"
  nvidia-smi --query-gpu=name,memory.total --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
} > "$LOGS/device.txt" 2>&1

for s in $SETS; do
  spec=$SPEC_DIR/$s.toml
  step "sweep_${s}_old" "$PY" -m tkujax.cli sweep "$spec" --out "$RUNS/$s-old" --params recommended
  step "sweep_${s}_new" "$PY" -m tkujax.cli sweep "$spec" --out "$RUNS/$s-new" --params "$POLICY"
  for side in old new; do                     # the sweeps' manifests: timing and device
    cp "$RUNS/$s-$side/manifest.json" "$EVAL_OUT/manifest_${s}_$side.json" 2>/dev/null
  done
  step "compare_$s" "$PY" -m tkujax.cli compare "$RUNS/$s-old:off" "$RUNS/$s-old:on" \
    "$RUNS/$s-new:on" --labels "control off,recommended policy,retuned policy" \
    --impulse-edges "$EDGES" --min-pushes "$MIN_PUSHES" --out "$EVAL_OUT/$s"
  step "compare_${s}_vs_old" "$PY" -m tkujax.cli compare "$RUNS/$s-old:on" "$RUNS/$s-new:on" \
    --labels "recommended policy,retuned policy" --impulse-edges "$EDGES" \
    --min-pushes "$MIN_PUSHES" --out "$EVAL_OUT/${s}_vs_old"
  step "j50_$s" "$PY" scripts/j50_by_direction.py "$RUNS/$s-old" "$RUNS/$s-new"
  grep '^{' "$LOGS/j50_$s.log" > "$EVAL_OUT/$s/j50.jsonl"
done

step headline "$PY" - "$EVAL_OUT" $SETS <<'EOF'
import json, sys
from pathlib import Path

out, sets = Path(sys.argv[1]), sys.argv[2:]
TARGET_RATIO, TARGET_J50 = 0.5, 2.0
rows, lines = {}, ["| set | control off | recommended policy | retuned policy | ratio (old / new) "
                   "| harmed cells (old / new) | worse than old | J50 behind, N s (off / old / new) "
                   "| targets met |", "|---" * 9 + "|"]
for s in sets:
    v = json.loads((out / s / "verdict.json").read_text())
    vo = json.loads((out / f"{s}_vs_old" / "verdict.json").read_text())
    old, new = v["runs"]["recommended policy"], v["runs"]["retuned policy"]
    j = [json.loads(x) for x in (out / s / "j50.jsonl").read_text().splitlines() if x.strip()]
    j50 = {"off": j[0]["j50_ns"]["0"]["off"], "old": j[0]["j50_ns"]["0"]["on"],
           "new": j[1]["j50_ns"]["0"]["on"]}
    worse = vo["runs"]["retuned policy"]
    met = dict(ratio=new["ratio_to_reference"] <= TARGET_RATIO, no_harm=bool(new["no_harm"]),
               j50_behind=j50["new"] >= TARGET_J50)
    rows[s] = dict(off=v["reference"]["fall_rate"], old=old["fall_rate"], new=new["fall_rate"],
                   ratio_old=old["ratio_to_reference"], ratio_new=new["ratio_to_reference"],
                   harmed_old=len(old["harmed_cells"]), harmed_new=len(new["harmed_cells"]),
                   harmed_new_cells=new["harmed_cells"], cells_checked=new["cells_checked"],
                   worse_than_old_cells=len(worse["harmed_cells"]), j50_by_azimuth={
                       "old": j[0]["j50_ns"], "new": j[1]["j50_ns"]},
                   j50_behind=j50, targets_met=met)
    pct = lambda x: f"{100 * x:.1f} %"  # noqa: E731
    lines.append(f"| {s} | {pct(rows[s]['off'])} | {pct(rows[s]['old'])} | {pct(rows[s]['new'])} "
                 f"| {rows[s]['ratio_old']:.3f} / {rows[s]['ratio_new']:.3f} "
                 f"| {rows[s]['harmed_old']} / {rows[s]['harmed_new']} of {rows[s]['cells_checked']} "
                 f"| {rows[s]['worse_than_old_cells']} | {j50['off']:.2f} / {j50['old']:.2f} / "
                 f"{j50['new']:.2f} | {', '.join(k for k, ok in met.items() if ok) or 'none'} |")
(out / "headline.json").write_text(json.dumps(rows, indent=1))
(out / "headline.md").write_text("\n".join(lines) + "\n")
print("\n".join(lines))
EOF

printf 'total\t%s\n' "$(seconds_since "$T0")" | tee -a "$LOGS/timings.tsv"
tar czf "$OUT/retune_eval.tar.gz" -C "$(dirname "$EVAL_OUT")" "$(basename "$EVAL_OUT")"
cp "$EVAL_OUT/headline.md" "$OUT/headline.md" 2>/dev/null
ls -la "$OUT"
exit "$RC"
