# shellcheck shell=bash
# Sourced by scripts/service-demo.sh and bench/serve.sh (not run directly).
# start_server STORE LOG_PREFIX [clnerf-server flags...]
#   Starts ./build/server/clnerf-server on 127.0.0.1 with a free port and
#   store STORE, stdout to LOG_PREFIX.out and stderr to LOG_PREFIX.log, and
#   waits until it listens. Sets SERVER_PID and SERVER_PORT; exits the calling
#   script with the server log if it does not come up.
start_server() {
  local store=$1 prefix=$2
  shift 2
  ./build/server/clnerf-server --listen 127.0.0.1:0 --store "$store" "$@" > "$prefix.out" 2> "$prefix.log" &
  SERVER_PID=$!
  SERVER_PORT=""
  for _ in $(seq 1 100); do
    SERVER_PORT=$(sed -n 's/^clnerf-server listening on port \([0-9]*\)$/\1/p' "$prefix.out")
    [ -n "$SERVER_PORT" ] && return 0
    kill -0 "$SERVER_PID" 2>/dev/null || break
    sleep 0.1
  done
  kill -TERM "$SERVER_PID" 2>/dev/null || true
  echo "clnerf-server did not start:" >&2
  cat "$prefix.log" >&2
  exit 1
}
