#!/usr/bin/env bash
# Rescans as people bring them (`clnerf bench rescan`): each capture in
# ../shared/data (and any dataset folders given as arguments) split into two
# visits by alternate frames; visit A trains the place's first model, visit B
# comes in the place's frame, in its own (rotated 40 degrees, scaled 1.7,
# shifted) and unposed (posed by COLMAP), is registered and trained; and
# visit A again unposed as a first scan (over FIRST_SEEDS training seeds,
# each against visit A posed with the same seed; UPDATE_SEEDS: visit B's
# update trained with that many seeds, PSNRs their means). Held-out PSNR after each, pose
# errors against the known poses, seconds per stage. One JSON per capture.
# With no arguments, also the procedural forward-facing scene and the
# procedural capture whose objects move between visits.
# Usage: bench/rescan.sh [DATASET_DIR ...]   (FIRST_ITERS=2000 ITERS=1000 FIRST_SEEDS=3 UPDATE_SEEDS=1 OUT=bench/results/rescan)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-./build/client/clnerf}
FIRST_ITERS=${FIRST_ITERS:-2000}  # The first scan's budget in the service.
ITERS=${ITERS:-1000}
FIRST_SEEDS=${FIRST_SEEDS:-3}
UPDATE_SEEDS=${UPDATE_SEEDS:-1}
OUT=${OUT:-bench/results/rescan}
mkdir -p "$OUT"
DATA=("$@")
if [ ${#DATA[@]} -eq 0 ]; then
  for d in ../shared/data/*/; do [ -d "$d" ] && DATA+=("${d%/}"); done
  DATA+=(procedural procedural-moved)  # Generated: forward-facing; objects moved between visits.
fi
for d in "${DATA[@]}"; do
  name=$(basename "$d")
  echo "== $name"
  "$BIN" --log-level warn bench rescan --data "$d" --first-iters "$FIRST_ITERS" --iters "$ITERS" \
    --first-seeds "$FIRST_SEEDS" --update-seeds "$UPDATE_SEEDS" --json "$OUT/$name.json" || echo "(bench rescan failed on $name)"
done
