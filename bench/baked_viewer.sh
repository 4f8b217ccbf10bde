#!/usr/bin/env bash
# Baked-asset frame time in a real browser: headless Chromium with software
# WebGL2 (SwiftShader, on this machine's CPU cores), the procedural object of
# the BakedBrowserEndToEnd test at 128^3, 5 frames each at 400x300 and
# 800x600 (tests/viewer/baked_browser_test.py --frame-times; the test's own
# checks run first). Prints JSON and a human line; target <= 100 ms at
# 400x300 (issue 41). Never run beside another benchmark.
# With ASSET_DIRs (folders `clnerf bake` wrote) it then times each of them
# too, at its first stored training view.
# Usage: bench/baked_viewer.sh [OUT_DIR [ASSET_DIR...]]   (default bench/results/baking)
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-bench/results/baking}
shift || true
[ -x build/client/clnerf ] || bash scripts/build.sh
mkdir -p "$OUT"
/usr/bin/python3 tests/viewer/baked_browser_test.py --client build/client/clnerf --web server/frontends/web \
  --out "$OUT/browser" --frame-times | tee "$OUT/browser_frames.txt"
if [ $# -gt 0 ]; then
  args=()
  for a in "$@"; do args+=(--time-asset "$a"); done
  /usr/bin/python3 tests/viewer/baked_browser_test.py --client build/client/clnerf --web server/frontends/web \
    --out "$OUT/browser" "${args[@]}" | tee "$OUT/browser_assets.txt"
fi
