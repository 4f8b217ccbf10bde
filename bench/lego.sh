#!/usr/bin/env bash
# Engine benchmark on the real NeRF-synthetic lego at 100x100
# (../shared/data/lego_100): train + eval at the default budget with a
# PSNR-vs-wall-time curve, render timing at 100x100 and 200x200, and a
# capacity sweep (table sizes) so the size/quality trade is visible.
#
# Usage: bench/lego.sh [OUT_DIR]   (env: ITERS, SWEEP_ITERS, SWEEP_TABLES, DATA)
# Prints one human-readable line per result and writes JSON to OUT_DIR.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-../shared/data/lego_100}
OUT=${1:-bench/results/lego}
ITERS=${ITERS:-2000}
SWEEP_ITERS=${SWEEP_ITERS:-$ITERS}
SWEEP_TABLES=${SWEEP_TABLES:-"14 16 18"}
BIN=./build/client/clnerf
if [ ! -d "$DATA" ]; then echo "bench/lego.sh: $DATA not found; skipping" >&2; exit 0; fi
[ -x "$BIN" ] || bash scripts/build.sh
mkdir -p "$OUT"

echo "== default capacity, $ITERS steps, PSNR-vs-time curve =="
$BIN train --data "$DATA" --out "$OUT/lego.clnerf" --iters "$ITERS" --curve-every 100 --curve-views 25 \
  --json "$OUT/train.json"
$BIN eval --model "$OUT/lego.clnerf" --data "$DATA" --split test --json "$OUT/eval.json"
$BIN bench render --model "$OUT/lego.clnerf" --data "$DATA" --sizes 100,200 --views 20 --repeats 3 \
  --json "$OUT/render.json" | head -2

echo "== capacity sweep ($SWEEP_ITERS steps each) =="
for T in $SWEEP_TABLES; do
  $BIN train --data "$DATA" --out "$OUT/lego_t$T.clnerf" --iters "$SWEEP_ITERS" --table-log2 "$T" \
    --json "$OUT/sweep_t$T.json" | tail -1 | sed "s/^/table 2^$T: /"
done
python3 bench/summarize_lego.py "$OUT"
