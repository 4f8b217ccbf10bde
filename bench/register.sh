#!/usr/bin/env bash
# Registration of a second visit into a place's frame by the place's model
# (core/pose/registration.h), on every capture in ../shared/data (and any
# dataset folders given as arguments) plus the procedural forward-facing
# scene: each capture's training views split into two visits (alternate
# frames), visit A trains θ_A, visit B is registered in the place's frame
# (the fit must be the identity) and in its own (rotated 40 degrees, scaled
# 1.7, shifted). One JSON per capture and one summary line each.
# Usage: bench/register.sh [DATASET_DIR ...]   (ITERS=1000 OUT=bench/results/registration)
set -euo pipefail
cd "$(dirname "$0")/.."
BIN=${BIN:-./build/client/clnerf}
ITERS=${ITERS:-2000}  # The first scan's budget in the service.
OUT=${OUT:-bench/results/registration}
mkdir -p "$OUT"
DATA=("$@")
if [ ${#DATA[@]} -eq 0 ]; then
  for d in ../shared/data/*/; do [ -d "$d" ] && DATA+=("${d%/}"); done
  DATA+=(procedural)
fi
for d in "${DATA[@]}"; do
  name=$(basename "$d")
  echo "== $name"
  "$BIN" --log-level warn bench register --data "$d" --iters "$ITERS" --json "$OUT/$name.json"
done
