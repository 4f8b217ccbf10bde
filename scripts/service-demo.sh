#!/usr/bin/env bash
# The service's main job, on embedded data (nothing to download):
#   1. writes 3 scans of the procedural changing scene (lighting + geometry
#      change between scans),
#   2. starts clnerf-server on a free local port with a fresh store,
#   3. uploads the scans one by one and watches each update train, pass the
#      deployment gate and go live,
#   4. renders a past view (scan 0's test cameras at time step 0) and a present
#      view (scan 2's at time step 2) and prints their PSNR against the held-out
#      images,
#   5. stops the server with SIGTERM (graceful shutdown); the last line says
#      how to serve the store in the web viewer.
# Output: clnerf-service-demo/ (scans, store, renders, server.log).
# Env: OUT (output dir), ITERS (iterations per update, default 300),
#      SIZE (image size, default 64).
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-clnerf-service-demo}
ITERS=${ITERS:-300}
SIZE=${SIZE:-64}
BIN=./build/client/clnerf
SERVER=./build/server/clnerf-server
[ -x "$BIN" ] && [ -x "$SERVER" ] || bash scripts/build.sh
rm -rf "$OUT"
mkdir -p "$OUT"

echo "== 1. three scans of the procedural changing scene -> $OUT/scans"
$BIN --log-level warn scans --out "$OUT/scans" --scans 3 --size "$SIZE"

echo "== 2. clnerf-server (store $OUT/store, $ITERS iterations per update)"
# shellcheck source=scripts/start-server.sh
source scripts/start-server.sh
start_server "$OUT/store" "$OUT/server" --iters "$ITERS"
trap 'kill -TERM $SERVER_PID 2>/dev/null || true' EXIT
export CLNERF_SERVER=127.0.0.1:$SERVER_PORT
$BIN info

echo "== 3. upload and train, scan by scan"
for t in 0 1 2; do
  $BIN upload "$OUT/scans/scan_00$t" --name "visit-$t" --pose-frame place --watch
done
$BIN versions

echo "== 4. render the past and the present"
past=$($BIN render --views-from "$OUT/scans/scan_000" --time-step 0 --out "$OUT/renders/past_t0")
present=$($BIN render --views-from "$OUT/scans/scan_002" --time-step 2 --out "$OUT/renders/present_t2")
past_psnr=$(echo "$past" | sed -n 's/.*mean PSNR \([0-9.]*\) dB.*/\1/p')
present_psnr=$(echo "$present" | sed -n 's/.*mean PSNR \([0-9.]*\) dB.*/\1/p')

echo "== 5. graceful shutdown"
kill -TERM $SERVER_PID
wait $SERVER_PID || true
trap - EXIT
echo "service demo: past view (scan 0 at time step 0) PSNR ${past_psnr} dB | present view (scan 2 at time step 2) PSNR ${present_psnr} dB | renders in $OUT/renders"
echo "view it in a browser: ./build/server/clnerf-server --store $OUT/store --http 127.0.0.1:8080  then open http://127.0.0.1:8080/"
