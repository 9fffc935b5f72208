#!/usr/bin/env bash
# Instruction counts (valgrind --tool=callgrind) of a seed solve and of one
# POST /solve, in process and through the release server: figures that do
# not move with the machine's load, unlike every timing in BENCHMARKS.md.
# They count user-space instructions only: the kernel's share (loopback TCP,
# epoll, futex, context switches) and how fast the instructions run (cache
# misses after a preemption, a host taking the core away) are not in them.
#
#   bash bench/instructions.sh            # about a minute
#   REQUESTS=50 bash bench/instructions.sh
#   bash bench/instructions.sh RUST_LOG=warn   # env for the server (step 3)
#
# 1. The seed solve: `ilqr-service solve` (no file: the default problem)
#    under callgrind, counting inside `ilqr_service::solve::solve` only
#    (`--toggle-collect`): building the problem, one solve, and the wire
#    types of the result; no start-up, no parsing, no printing.
# 2. In process, per request: the `http_path` bench's throughput mode on one
#    thread for 3 s under callgrind, counting inside its `handle` (parse,
#    validate, solve, serialise, what bench/load.sh's in-process ceiling
#    runs), divided by the requests it completed. Lean and full bodies.
# 3. The server, per request: `ilqr-service serve --workers 1` under
#    callgrind (`--separate-threads=yes`), warmed with 5 requests, counters
#    zeroed, then REQUESTS (default 100) sequential POST /solve from one
#    keep-alive Python `http.client` connection, then dumped: every thread's
#    count divided by REQUESTS, the solver worker apart from the rest
#    (runtime thread, metrics upkeep, main). Lean, then full.
#
# Everything runs on 127.0.0.1, bounded in time; the server is killed on
# exit whatever happens. Needs valgrind (apt-get install valgrind).
set -euo pipefail

cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
REQUESTS="${REQUESTS:-100}"
# shellcheck source=scripts/lib.sh
. scripts/lib.sh
BIN="$(target_dir)/release/ilqr-service" # honours CARGO_TARGET_DIR
command -v valgrind >/dev/null || { echo "needs valgrind (apt-get install valgrind)" >&2; exit 1; }
command -v callgrind_control >/dev/null || { echo "needs callgrind_control (valgrind)" >&2; exit 1; }

tmp="$(mktemp -d)"
SERVER_PID=""
trap kill_server_and_tmp EXIT
trap 'exit 130' INT TERM

echo "building: cargo build --release --bin ilqr-service; cargo bench --bench http_path --no-run" >&2
cargo build --release --quiet --bin ilqr-service
INPROC="$(cargo bench --bench http_path --no-run --quiet --message-format=json 2>/dev/null |
    python3 -c 'import json, sys
for line in sys.stdin:
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m["target"]["name"] == "http_path" and m.get("executable"):
        print(m["executable"])')"
[[ -x "$INPROC" ]] || { echo "could not find the http_path bench binary" >&2; exit 1; }

total() { # callgrind output files... -> the sum of their "summary:" lines
    awk '/^summary:/ { s += $2 } END { printf "%d\n", s }' "$@"
}

echo "== seed solve (ilqr_service::solve::solve, one solve)"
valgrind --tool=callgrind --callgrind-out-file="$tmp/seed.out" \
    --toggle-collect='ilqr_service::solve::solve' "$BIN" solve >"$tmp/seed.txt" 2>"$tmp/seed.err"
seed="$(total "$tmp/seed.out")"
printf '  %s instructions  (%s)\n' "$seed" "$(grep -E '^(status|iterations)' "$tmp/seed.txt" | tr -s ' ' | paste -sd ',' -)"

declare -A inproc
for body in lean full; do
    HTTP_PATH_THROUGHPUT_SECS=3 HTTP_PATH_THREADS=1 HTTP_PATH_BODY="$body" \
        valgrind --tool=callgrind --callgrind-out-file="$tmp/inproc-$body.out" \
        --toggle-collect='http_path::handle' "$INPROC" --bench >"$tmp/inproc-$body.txt" 2>"$tmp/inproc-$body.err"
    n="$(grep -o 'requests=[0-9]*' "$tmp/inproc-$body.txt" | cut -d= -f2)"
    [[ "${n:-0}" -gt 0 ]] || { echo "the in-process run completed no request:" >&2; cat "$tmp/inproc-$body.err" >&2; exit 1; }
    inproc[$body]=$(( $(total "$tmp/inproc-$body.out") / n ))
done

PORT="$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')"
env "$@" valgrind --tool=callgrind --callgrind-out-file="$tmp/srv.out" --separate-threads=yes \
    "$BIN" serve --bind "127.0.0.1:$PORT" --workers 1 >"$tmp/srv.log" 2>&1 &
SERVER_PID=$!
# valgrind starts slowly: up to 60 s.
wait_healthy "$BIN" "$PORT" "$SERVER_PID" "$tmp/srv.log" 600 || exit 1

post() { # body count
    python3 - "$PORT" "$1" "$2" <<'EOF'
import http.client, sys
port, body, n = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
payload = (b'{"output":{"gains":false,"trace":false}}' if body == "lean" else b"{}")
c = http.client.HTTPConnection("127.0.0.1", port, timeout=300)
for _ in range(n):
    c.request("POST", "/solve", payload, {"content-type": "application/json"})
    r = c.getresponse()
    r.read()
    if r.status != 200:
        sys.exit(f"POST /solve answered {r.status}")
EOF
}

dump=0
for body in lean full; do
    post "$body" 5
    callgrind_control -z "$SERVER_PID" >/dev/null 2>&1
    post "$body" "$REQUESTS"
    callgrind_control -d "$SERVER_PID" >/dev/null 2>&1
    dump=$((dump + 1)) # zeroing writes no file; each dump is numbered
    files=("$tmp"/srv.out."$dump"-*)
    if [[ ! -e "${files[0]}" ]]; then
        echo "callgrind wrote no dump $dump; files: $(ls "$tmp")" >&2
        exit 1
    fi
    worker=0 rest=0
    for f in "${files[@]}"; do
        n="$(total "$f")"
        if grep -q 'ilqr_service::solve::solve' "$f"; then worker=$((worker + n)); else rest=$((rest + n)); fi
    done
    worker=$((worker / REQUESTS)) rest=$((rest / REQUESTS))
    python3 - "$body" "${inproc[$body]}" "$worker" "$rest" "$REQUESTS" <<'EOF'
import sys
body, inproc, worker, rest, n = sys.argv[1], *map(int, sys.argv[2:])
server = worker + rest
print(f"== {body} body, per request")
print(f"  in process (parse, validate, solve, serialise)  {inproc / 1e6:.3f} M")
print(f"  server: solver worker {worker / 1e6:.3f} M + runtime and other threads {rest / 1e3:.1f} k"
      f" = {server / 1e6:.3f} M  ({n} requests)")
print(f"  server / in process  {server / inproc:.4f}  (+{(server - inproc) / 1e3:.1f} k instructions)")
EOF
done
