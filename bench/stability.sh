#!/usr/bin/env bash
# The stability matrix: `clnerf bench stability` (every continual method and
# ub against every stressor, each update through the deployment gate) on the
# project's procedural changing scene. Writes OUT/stability.{md,json,log}.
#
# Usage: bench/stability.sh [OUT_DIR]   (default bench/results/stability)
# Env: ARGS  extra flags for `clnerf bench stability` (e.g. "--iters 100").
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-bench/results/stability}
ARGS=${ARGS:-}
BIN=./build/client/clnerf
[ -x "$BIN" ] || bash scripts/build.sh
mkdir -p "$OUT"
# Exit 4 = an invariant broke (a non-finite model deployed, or an update
# modified θ_{t-1}); the table and JSON are still written.
rc=0
$BIN bench stability --json "$OUT/stability.json" --markdown "$OUT/stability.md" $ARGS 2> "$OUT/stability.log" \
  | grep -v '^{' || rc=$?
echo "wrote $OUT/stability.md, $OUT/stability.json (per-cell log: $OUT/stability.log)"
exit $rc
