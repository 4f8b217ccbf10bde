#!/usr/bin/env bash
# Scene-suite benchmark: `clnerf bench scenes` trains every dataset with the
# default flags (`clnerf train`'s), evaluates it, and writes a markdown and
# CSV table, scenes.json, and PNG charts of test PSNR against training time
# and (with --capacity-sweep) against model bytes.
#
# Usage: bench/scenes.sh [ARGS...]   (ARGS go to `clnerf bench scenes`, e.g.
#        --capacity-sweep, --iters N, --threads T, --curve-every K, --force)
# Env:
#   SCENES  dataset directories (default: ../shared/data/{lego_100,fox_8,beer_2},
#           those present)
#   OUT     output directory (default bench/results/scenes)
# Finished runs (OUT/runs/*.json, same --iters) are reused, so an interrupted
# suite resumes where it stopped.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-bench/results/scenes}
if [ -z "${SCENES:-}" ]; then
  SCENES=""
  for s in lego_100 fox_8 beer_2; do
    [ -d "../shared/data/$s" ] && SCENES="$SCENES ../shared/data/$s"
  done
fi
if [ -z "${SCENES// /}" ]; then echo "bench/scenes.sh: no datasets found; skipping" >&2; exit 0; fi
BIN=./build/client/clnerf
[ -x "$BIN" ] || bash scripts/build.sh
# shellcheck disable=SC2086  # SCENES is a list.
$BIN bench scenes $SCENES --out "$OUT" "$@"
