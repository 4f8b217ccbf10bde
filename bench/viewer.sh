#!/usr/bin/env bash
# Viewer benchmark (bench/viewer_bench.py): release-to-full-resolution time at
# 400x300, preview frames per second while dragging, and both while an update
# trains, in a real headless Chromium against clnerf-server with default
# options, on lego_100 and fox_8 (skipped when ../shared/data is absent).
# Usage: bench/viewer.sh [OUT_DIR]   (default bench/results/viewer)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-bench/results/viewer}
shift || true
[ -x build/client/clnerf ] && [ -x build/server/clnerf-server ] || bash scripts/build.sh
mkdir -p "$OUT"
/usr/bin/python3 bench/viewer_bench.py --data ../shared/data/lego_100 --data ../shared/data/fox_8 \
  --out "$OUT" --json-out "$OUT/viewer.json" "$@" | tee "$OUT/viewer.txt"
