#!/usr/bin/env bash
# Many places on one server (issue 22): for stores of 1, 10 and 50 places of
# a small procedural 100x100 scene, a clnerf-server with default options:
#   * its resident memory with every model loaded (the start-up warm-up loads
#     them while the budget has room);
#   * the first render of each place and warm 100x100 renders round robin
#     over all places;
#   * the time from an upload's acknowledgement to its version being served
#     (300 iterations, the default);
# then the largest store under --model-memory-budget for 2 models, where
# almost every render must load its model first (cold), to show the memory
# stays within the budget. Targets: warm p50 at N places <= 1.2x that at 1
# place; cold p50 <= 1 s; loaded model bytes <= the budget.
# One place is trained (default options) and copied: N places of the same
# small scene, each loaded, cached and rendered on its own.
# Usage: bench/places.sh [OUT_DIR]   (default bench/results/places)
# Env: COUNTS (default "1 10 50").
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${1:-bench/results/places}
read -r -a COUNTS <<< "${COUNTS:-1 10 50}"
MAX=${COUNTS[${#COUNTS[@]}-1]}
[ -x build/client/clnerf ] && [ -x build/server/clnerf-server ] || bash scripts/build.sh
mkdir -p "$OUT"
WORK=$(mktemp -d /tmp/clnerf-bench-places.XXXXXX)
SERVER_PID=""
stop_server() {
  if [ -n "$SERVER_PID" ]; then
    kill -TERM "$SERVER_PID" 2>/dev/null || true
    wait "$SERVER_PID" 2>/dev/null || true
    SERVER_PID=""
  fi
}
trap 'stop_server; rm -rf "$WORK"' EXIT
# shellcheck source=scripts/start-server.sh
source scripts/start-server.sh
CLNERF=./build/client/clnerf

wait_warm() {  # The start-up warm-up has checked every place.
  for _ in $(seq 1 600); do
    grep -q "warm-up: checked" "$1" && return 0
    sleep 0.1
  done
  echo "bench/places.sh: the warm-up did not finish" >&2
  return 1
}

echo "training one place with default options..." >&2
start_server "$WORK/seed" "$OUT/seed"
$CLNERF bench places --seed 1 --server "127.0.0.1:$SERVER_PORT" --json-out "$OUT/seed.json" 2> "$OUT/seed_bench.log"
stop_server
for i in $(seq 1 $((MAX - 1))); do cp -r "$WORK/seed/places/bench-000" "$WORK/seed/places/$(printf bench-%03d "$i")"; done

for N in "${COUNTS[@]}"; do
  STORE="$WORK/store_$N"
  mkdir -p "$STORE/places"
  for i in $(seq 0 $((N - 1))); do cp -r "$WORK/seed/places/$(printf bench-%03d "$i")" "$STORE/places/"; done
  start_server "$STORE" "$OUT/server_$N"
  wait_warm "$OUT/server_$N.log"
  $CLNERF bench places --label "$N places" --server "127.0.0.1:$SERVER_PORT" --server-pid "$SERVER_PID" \
    --upload-served --json-out "$OUT/places_$N.json" 2> "$OUT/bench_$N.log"
  stop_server
done

# The largest store under a budget for two models.
PER=$(/usr/bin/python3 -c "import json; print(json.load(open('$OUT/places_$MAX.json'))['model_bytes_per_place'])")
BUDGET=$((PER * 5 / 2))
rm -rf "$WORK/store_budget" && cp -r "$WORK/store_$MAX" "$WORK/store_budget"
start_server "$WORK/store_budget" "$OUT/server_budget" --model-memory-budget "$BUDGET"
wait_warm "$OUT/server_budget.log"
$CLNERF bench places --label "$MAX places, budget $BUDGET bytes" --renders 100 --server "127.0.0.1:$SERVER_PORT" \
  --server-pid "$SERVER_PID" --json-out "$OUT/places_budget.json" 2> "$OUT/bench_budget.log"
stop_server

/usr/bin/python3 - "$OUT" "$BUDGET" "${COUNTS[@]}" <<'PY' | tee "$OUT/places.txt"
import json, sys
out, budget, counts = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
runs = {n: json.load(open(f"{out}/places_{n}.json")) for n in counts}
b = json.load(open(f"{out}/places_budget.json"))
base = runs[counts[0]]["warm_p50_ms"]
rows = []
for n in counts:
    r = runs[n]
    rows.append({"places": int(n), "rss_mb": r["rss_bytes"] / 1e6, "models_loaded": r["loaded_after"],
                 "model_mb_loaded": r["model_bytes_loaded"] / 1e6, "warm_p50_ms": r["warm_p50_ms"],
                 "warm_p99_ms": r["warm_p99_ms"], "warm_ratio_to_1_place": r["warm_p50_ms"] / base,
                 "upload_to_served_s": r.get("upload_to_served_seconds"), "failures": r["failures"]})
summary = {
    "rows": rows,
    "model_bytes_per_place": runs[counts[-1]]["model_bytes_per_place"],
    "model_param_bytes_per_place": runs[counts[-1]].get("model_param_bytes_per_place"),
    "budget_run": {"places": b["places"], "budget_bytes": budget, "cold_renders": b["cold_renders"],
                   "cold_p50_ms": b["cold_p50_ms"], "cold_max_ms": b["cold_max_ms"],
                   "round_robin_p50_ms": b["warm_p50_ms"], "models_loaded": b["loaded_after"],
                   "model_bytes_loaded": b["model_bytes_loaded"], "rss_mb": b["rss_bytes"] / 1e6,
                   "failures": b["failures"]},
}
worst = max(r["warm_ratio_to_1_place"] for r in rows)
summary["targets"] = {
    "warm_p50_within_1.2x_of_1_place": worst <= 1.2,
    "cold_p50_at_most_1s": b["cold_p50_ms"] <= 1000,
    "loaded_bytes_within_budget": b["model_bytes_loaded"] <= budget,
}
json.dump(summary, open(f"{out}/places.json", "w"), indent=2)
print(json.dumps(summary, indent=2))
for r in rows:
    print(f"{r['places']:3d} places: RSS {r['rss_mb']:.0f} MB, {r['models_loaded']} models loaded "
          f"({r['model_mb_loaded']:.1f} MB counted), warm 100x100 p50 {r['warm_p50_ms']:.1f} ms "
          f"({r['warm_ratio_to_1_place']:.2f}x of 1 place), upload ack -> served {r['upload_to_served_s']:.1f} s")
br = summary["budget_run"]
print(f"{br['places']} places, budget {budget/1e6:.1f} MB ({summary['model_bytes_per_place']/1e6:.2f} MB a loaded model, "
      f"{summary['model_param_bytes_per_place']/1e6:.2f} MB of it parameters): "
      f"cold render p50 {br['cold_p50_ms']:.0f} ms max {br['cold_max_ms']:.0f} ms over {br['cold_renders']}, "
      f"round robin p50 {br['round_robin_p50_ms']:.0f} ms, {br['models_loaded']} loaded "
      f"({br['model_bytes_loaded']/1e6:.1f} MB), RSS {br['rss_mb']:.0f} MB | targets: "
      + ", ".join(f"{k} {'met' if v else 'NOT met'}" for k, v in summary["targets"].items()))
PY
