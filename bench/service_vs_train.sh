#!/usr/bin/env bash
# Does the service train a real capture as well as `clnerf train`?
# Uploads DATA (a dataset folder with a train/test split, e.g. fox_8 or
# beer_2) to a fresh clnerf-server that trains ITERS iterations per update,
# renders the dataset's held-out views through the server, and compares their
# PSNR with `clnerf train --iters ITERS` + `clnerf eval --split test` on the
# same data. Prints one line and writes OUT/service_vs_train.json and
# OUT/train.json; the server's store, logs and renders go to a temporary
# directory (removed on success, kept on failure) so nothing large lands in the results.
# Usage: bench/service_vs_train.sh DATA [OUT]   (env ITERS, default 1500)
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${1:?usage: bench/service_vs_train.sh DATA [OUT]}
OUT=${2:-bench/results/service_vs_train/$(basename "$DATA")}
ITERS=${ITERS:-1500}
BIN=./build/client/clnerf
[ -x "$BIN" ] && [ -x ./build/server/clnerf-server ] || bash scripts/build.sh
rm -rf "$OUT"; mkdir -p "$OUT"
WORK=$(mktemp -d)
# On failure the logs stay for inspection; on success the directory goes.
cleanup() { rc=$?; [ -n "${SERVER_PID:-}" ] && kill -TERM "$SERVER_PID" 2>/dev/null; if [ $rc -eq 0 ]; then rm -rf "$WORK"; else echo "service_vs_train: failed; logs in $WORK" >&2; fi; }
trap cleanup EXIT

$BIN train --data "$DATA" --out "$OUT/train.clnerf" --iters "$ITERS" --json "$OUT/train.json" 2> "$WORK/train.log"
train_psnr=$(python3 -c "import json;print('%.2f'%json.load(open('$OUT/train.json'))['psnr'])")

# shellcheck source=scripts/start-server.sh
source scripts/start-server.sh
start_server "$WORK/store" "$WORK/server" --iters "$ITERS"
export CLNERF_SERVER=127.0.0.1:$SERVER_PORT
$BIN upload "$DATA" --name "$(basename "$DATA")" --watch --timeout 3600 2> "$WORK/upload.log"
served=$($BIN render --views-from "$DATA" --time-step 0 --out "$WORK/renders" 2>> "$WORK/upload.log")
served_psnr=$(echo "$served" | sed -n 's/.*mean PSNR \([0-9.]*\) dB.*/\1/p')
kill -TERM $SERVER_PID; wait $SERVER_PID || true; SERVER_PID=
diff=$(python3 -c "print('%.2f'%($served_psnr-$train_psnr))")
echo "{\"data\": \"$DATA\", \"iterations\": $ITERS, \"train_psnr\": $train_psnr, \"served_psnr\": $served_psnr, \"difference_db\": $diff}" > "$OUT/service_vs_train.json"
echo "service vs train ($(basename "$DATA"), $ITERS iterations): clnerf train + eval ${train_psnr} dB | uploaded + rendered by the server ${served_psnr} dB | difference ${diff} dB"
cat "$OUT/service_vs_train.json"
