# Sourced by scripts/test.sh, scripts/browser_check.sh and the bench/*.sh
# scripts.

# The cargo target directory of this checkout: honours CARGO_TARGET_DIR
# (a stale ./target must not be tested instead).
target_dir() {
  cargo metadata --format-version 1 --no-deps \
    | python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])'
}

#   start_server BIN LOG [serve flags...]
# starts `BIN serve --bind 127.0.0.1:PORT flags...` on a free port, waits
# until it answers /healthz, and sets PORT and SERVER (its PID). The port
# was free when picked; if another process takes it before the server
# binds, the server exits and another port is tried (three tries). Returns
# 1, with the server's log printed, if it never became healthy.
start_server() {
  local bin=$1 log=$2
  shift 2
  for _ in 1 2 3; do
    PORT=$(free_port)
    "$bin" serve --bind "127.0.0.1:$PORT" "$@" >"$log" 2>&1 &
    SERVER=$!
    poll_healthy "$bin" "$PORT" "$SERVER" && return 0
    kill "$SERVER" 2>/dev/null || true
    wait "$SERVER" 2>/dev/null || true
  done
  echo "the server never became healthy:"
  cat "$log"
  return 1
}

# Stops the server start_server started (if any) and waits for it.
stop_server() {
  if [ -n "${SERVER:-}" ]; then
    kill "$SERVER" 2>/dev/null || true
    wait "$SERVER" 2>/dev/null || true
    SERVER=""
  fi
}

# A TCP port on 127.0.0.1 that was free when asked (another process may
# take it before the caller binds it).
free_port() {
  python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

#   poll_healthy BIN PORT PID [TRIES]
# returns 0 as soon as `BIN healthcheck` reaches 127.0.0.1:PORT, trying
# TRIES times (default 100) 0.1 s apart and only while process PID lives (a
# server that exits at once is not waited for); 1 otherwise, silently.
poll_healthy() {
  local bin=$1 port=$2 pid=$3 tries=${4:-100}
  for _ in $(seq "$tries"); do
    "$bin" healthcheck --addr "127.0.0.1:$port" 2>/dev/null && return 0
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.1
  done
  return 1
}

#   wait_healthy BIN PORT PID LOG [TRIES]
# poll_healthy, printing LOG to stderr when the server never answered. For
# bench scripts that start the server their own way (under valgrind, say)
# rather than with start_server.
wait_healthy() {
  poll_healthy "$1" "$2" "$3" "${5:-100}" && return 0
  echo "the server did not come up; its log:" >&2
  cat "$4" >&2
  return 1
}

# An EXIT trap for bench scripts. It reads two globals of the script: it
# stops the server whose PID is in SERVER_PID, if set (SIGTERM, so that it
# drains and a valgrind under it cleans up; SIGKILL if it is still there
# after 5 s), then removes the scratch directory $tmp, if set.
kill_server_and_tmp() {
  if [ -n "${SERVER_PID:-}" ]; then
    kill -TERM "$SERVER_PID" 2>/dev/null || true
    for _ in $(seq 50); do kill -0 "$SERVER_PID" 2>/dev/null || break; sleep 0.1; done
    kill -KILL "$SERVER_PID" 2>/dev/null || true
  fi
  if [ -n "${tmp:-}" ]; then rm -rf "$tmp"; fi
}
