#!/usr/bin/env bash
# Continual-learning sweep: every method at several per-step iteration
# budgets through `clnerf bench continual`, then a CSV, a markdown table and a
# PNG chart of final mean PSNR against total update time (one line per
# method through its budgets).
#
# Usage: bench/continual_sweep.sh [OUT_DIR]
# Env:
#   DATA            dataset, scan-folder directory or "procedural"
#                   (default ../shared/data/lego_100)
#   METHODS         methods run at every budget (default: all seven)
#   BUDGETS         per-step iterations (default "100 300")
#   INIT            init of the continual methods (default warm)
#   REINIT_BUDGETS  extra clnerf runs with --init reinit (default "300")
#   EXTRA_ARGS      passed to every run (e.g. "--tasks 5")
# Finished runs (OUT_DIR/<label>_<iters>.json) are skipped, so an interrupted
# sweep resumes where it stopped. A run that diverges is recorded as such.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-../shared/data/lego_100}
OUT=${1:-bench/results/continual_lego}
METHODS=${METHODS:-"nt ewc er meil clnerf-noer clnerf ub"}
BUDGETS=${BUDGETS:-"100 300"}
INIT=${INIT:-warm}
REINIT_BUDGETS=${REINIT_BUDGETS-"300"}
EXTRA_ARGS=${EXTRA_ARGS:-}
BIN=./build/client/clnerf
if [ "$DATA" != procedural ] && [ ! -d "$DATA" ]; then
  echo "bench/continual_sweep.sh: $DATA not found; skipping" >&2
  exit 0
fi
[ -x "$BIN" ] || bash scripts/build.sh
mkdir -p "$OUT"

run() {  # run LABEL ITERS ARGS...
  local label=$1 iters=$2
  shift 2
  local json="$OUT/${label}_${iters}.json"
  if [ -s "$json" ]; then echo "skip $label @ $iters (done)"; return; fi
  echo "== $label @ $iters iterations/step =="
  # Exit 3 = the method diverged; the JSON records it and the sweep goes on.
  local log="$OUT/${label}_${iters}.log"
  $BIN bench continual --data "$DATA" --iters "$iters" --json "$json.tmp" $EXTRA_ARGS "$@" > "$log" 2>&1 || true
  grep -E '^bench continual' "$log" || true
  if [ -s "$json.tmp" ]; then mv "$json.tmp" "$json"; else echo "run $label @ $iters failed; see $OUT/${label}_${iters}.log"; fi
}

for B in $BUDGETS; do
  for M in $METHODS; do
    if [ "$M" = ub ]; then
      run ub "$B" --method ub  # Equal compute: tasks x B iterations.
      run ub-per-step "$B" --method ub --ub-budget per-step  # The paper's protocol.
    else run "$M-$INIT" "$B" --method "$M" --init "$INIT"; fi
  done
done
for B in $REINIT_BUDGETS; do
  run clnerf-reinit "$B" --method clnerf --init reinit
done
# Debian's python3 (where apt puts python3-matplotlib) even when another python3 is first in PATH.
PY=python3
[ -x /usr/bin/python3 ] && PY=/usr/bin/python3
"$PY" bench/summarize_continual.py "$OUT"
