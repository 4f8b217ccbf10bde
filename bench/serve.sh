#!/usr/bin/env bash
# Service benchmark: starts clnerf-server (default options: clnerf, warm
# start, 300 iterations per update, 2 training threads, 2 render slots of 1
# thread) on a fresh store and a free port, then runs `clnerf bench serve`:
# upload throughput and upload-end -> served time for lego_100 tasks 0 and 1,
# and render latency p50/p99 at 32x32, 100x100 and 200x200 with 1 and 4
# concurrent clients, idle and while task 1 trains, against the idle targets
# (32x32 p50 <= 10 ms; 100x100 p50 <= 1.5x the same render in-process; with
# 4 clients p99 <= 4x p50).
# Usage: bench/serve.sh [OUT_DIR]   (default bench/results/serve)
# Env: DATA (default ../shared/data/lego_100; "procedural" needs no data),
#      EXTRA_ARGS (passed to `clnerf bench serve`), SERVER_ARGS.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-../shared/data/lego_100}
OUT=${1:-bench/results/serve}
if [ "$DATA" != procedural ] && [ ! -d "$DATA" ]; then
  echo "bench/serve.sh: $DATA not found; skipping (DATA=procedural needs no data)" >&2
  exit 0
fi
[ -x build/client/clnerf ] && [ -x build/server/clnerf-server ] || bash scripts/build.sh
mkdir -p "$OUT"
STORE=$(mktemp -d /tmp/clnerf-bench-store.XXXXXX)
trap 'rm -rf "$STORE"' EXIT
# shellcheck source=scripts/start-server.sh
source scripts/start-server.sh
# shellcheck disable=SC2086  # SERVER_ARGS is a list of flags.
start_server "$STORE" "$OUT/server" ${SERVER_ARGS:-}
trap 'kill -TERM $SERVER_PID 2>/dev/null || true; wait $SERVER_PID 2>/dev/null || true; rm -rf "$STORE"' EXIT
./build/client/clnerf bench serve --server "127.0.0.1:$SERVER_PORT" --data "$DATA" --store "$STORE" \
  --json-out "$OUT/serve.json" ${EXTRA_ARGS:-} \
  2> "$OUT/bench.log" | tee "$OUT/serve.txt"
