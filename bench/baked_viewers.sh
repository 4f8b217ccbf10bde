#!/usr/bin/env bash
# Many browsers on one place (issue 41): N separate headless Chromium
# browsers (SwiftShader WebGL2) view a real clnerf-server's place with baked
# frames; prints the server's renders (0), asset requests, bytes sent, files
# read from disk and CPU seconds, as JSON and a human line
# (bench/baked_viewers.py). Never run beside another benchmark.
# Usage: bench/baked_viewers.sh [OUT_DIR] [--viewers N] [--data CAPTURE]
#        (default bench/results/baking, 20 viewers, a procedural scan)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-bench/results/baking}
shift || true
[ -x build/client/clnerf ] && [ -x build/server/clnerf-server ] || bash scripts/build.sh
mkdir -p "$OUT"
/usr/bin/python3 bench/baked_viewers.py --server build/server/clnerf-server --client build/client/clnerf \
  --out "$OUT/viewers" --json-out "$OUT/viewers.json" "$@" | tee "$OUT/viewers.txt"
