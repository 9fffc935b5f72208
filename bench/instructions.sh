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
# 1. The seed's single solve as `ilqr-service solve -` (the default problem
#    with `multi_start: false`,
#    gains and trace included) runs it, under callgrind, counting inside
#    `ilqr_service::solve::solve` only (`--toggle-collect`): building the
#    problem, the solve, the result's wire types; no start-up, parsing or
#    printing. It is the process's first solve, so the solver's workspace
#    is allocated and zeroed in it (a server worker does that once).
# 2. In process, per request: the `http_path` bench's count mode
#    (`HTTP_PATH_COUNT`) under callgrind: 5 warm-up requests, then REQUESTS
#    more inside its `measured`, the only function counted. Each request is
#    parse, validate, solve, serialise, what bench/load.sh's in-process
#    ceiling runs. (The bench's global allocator is divan's AllocProfiler,
#    which counts every allocation; the server's is the system's.)
# 3. The server, per request: `ilqr-service serve --workers 1` under
#    callgrind (`--separate-threads=yes`), warmed with 5 requests, counters
#    zeroed, then REQUESTS (default 100) sequential POST /solve from one
#    keep-alive Python `http.client` connection, then dumped: every thread's
#    count divided by REQUESTS, the solver worker (the one thread that ran
#    `ilqr_service::solve::solve`) apart from the rest (runtime thread,
#    metrics upkeep, main). Lean, then full.
#
# Everything runs on 127.0.0.1; valgrind's control commands are bounded by
# `timeout`; the server is stopped on exit whatever happens. A step that
# fails prints its output and the script exits 1. Needs valgrind
# (apt-get install valgrind).
set -euo pipefail

cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
REQUESTS="${REQUESTS:-100}"
[[ "$REQUESTS" =~ ^[1-9][0-9]*$ ]] || { echo "REQUESTS must be a positive integer, not '$REQUESTS'" >&2; exit 1; }
for a in "$@"; do
    [[ "$a" =~ ^[A-Za-z_][A-Za-z0-9_]*= ]] || { echo "arguments are VAR=value for the server's environment, not '$a'" >&2; exit 1; }
done
# shellcheck source=scripts/lib.sh
. scripts/lib.sh
BIN="$(target_dir)/release/ilqr-service" # honours CARGO_TARGET_DIR
command -v valgrind >/dev/null || { echo "needs valgrind (apt-get install valgrind)" >&2; exit 1; }
command -v callgrind_control >/dev/null || { echo "needs callgrind_control (valgrind)" >&2; exit 1; }

tmp="$(mktemp -d)"
SERVER_PID=""
trap kill_server_and_tmp EXIT
trap 'exit 130' INT TERM

fail() { # message files... : print both, exit 1
    echo "$1" >&2
    shift
    for f in "$@"; do [[ -e "$f" ]] && cat "$f" >&2; done
    exit 1
}

echo "building: cargo build --release --bin ilqr-service; cargo bench --bench http_path --no-run" >&2
cargo build --release --quiet --bin ilqr-service
cargo bench --bench http_path --no-run --quiet --message-format=json >"$tmp/build.json" 2>"$tmp/build.err" ||
    fail "cargo bench --bench http_path --no-run failed:" "$tmp/build.err"
INPROC="$(python3 -c 'import json, sys
for line in open(sys.argv[1]):
    m = json.loads(line)
    if m.get("reason") == "compiler-artifact" and m["target"]["name"] == "http_path" and m.get("executable"):
        print(m["executable"])' "$tmp/build.json")"
[[ -x "$INPROC" ]] || fail "could not find the http_path bench binary in cargo's output"

total() { # callgrind output files... -> the sum of their "summary:" lines
    awk '/^summary:/ { s += $2 } END { printf "%.0f\n", s }' "$@"
}

control() { # -z | -d : a callgrind_control command, checked (it exits 0 even when it fails)
    local out
    out="$(timeout 60 callgrind_control "$1" "$SERVER_PID" 2>&1)" || true
    grep -q 'OK' <<<"$out" || fail "callgrind_control $1 $SERVER_PID did not succeed: $out"
}

echo "== seed solve (ilqr_service::solve::solve: the process's first solve, gains and trace on)"
valgrind --tool=callgrind --callgrind-out-file="$tmp/seed.out" \
    --toggle-collect='ilqr_service::solve::solve' "$BIN" solve - \
    <<<'{"solver":{"multi_start":false}}' >"$tmp/seed.txt" 2>"$tmp/seed.err" ||
    fail "ilqr-service solve under valgrind failed:" "$tmp/seed.txt" "$tmp/seed.err"
seed="$(total "$tmp/seed.out")"
printf '  %s instructions  (%s)\n' "$seed" "$(grep -E '^(status|iterations)' "$tmp/seed.txt" | tr -s ' ' | paste -sd ',' -)"

declare -A inproc
for body in lean full; do
    HTTP_PATH_COUNT="$REQUESTS" HTTP_PATH_BODY="$body" \
        valgrind --tool=callgrind --callgrind-out-file="$tmp/inproc-$body.out" \
        --toggle-collect='http_path::measured' "$INPROC" >"$tmp/inproc-$body.txt" 2>"$tmp/inproc-$body.err" ||
        fail "the in-process count ($body) failed:" "$tmp/inproc-$body.txt" "$tmp/inproc-$body.err"
    grep -q "^COUNT body=$body requests=$REQUESTS\$" "$tmp/inproc-$body.txt" ||
        fail "the in-process count ($body) did not report $REQUESTS requests:" "$tmp/inproc-$body.txt" "$tmp/inproc-$body.err"
    inproc[$body]=$(($(total "$tmp/inproc-$body.out") / REQUESTS))
done

PORT="$(free_port)"
env "$@" valgrind --tool=callgrind --callgrind-out-file="$tmp/srv.out" --separate-threads=yes \
    "$BIN" serve --bind "127.0.0.1:$PORT" --workers 1 >"$tmp/srv.log" 2>&1 &
SERVER_PID=$!
# valgrind starts slowly: up to 60 s.
wait_healthy "$BIN" "$PORT" "$SERVER_PID" "$tmp/srv.log" 600 || exit 1

post() { # body count
    python3 - "$PORT" "$1" "$2" <<'EOF'
import http.client, sys
port, body, n = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
payload = (b'{"solver":{"multi_start":false},"output":{"gains":false,"trace":false}}' if body == "lean"
           else b'{"solver":{"multi_start":false}}')
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
    post "$body" 5 || fail "the warm-up requests failed; the server's log:" "$tmp/srv.log"
    control -z
    post "$body" "$REQUESTS" || fail "the counted requests failed; the server's log:" "$tmp/srv.log"
    control -d
    dump=$((dump + 1)) # zeroing writes no file; each dump is numbered
    files=("$tmp"/srv.out."$dump"-*)
    [[ -e "${files[0]}" ]] || fail "callgrind wrote no dump $dump; files: $(ls "$tmp")"
    worker=0 rest=0 workers=0
    for f in "${files[@]}"; do
        n="$(total "$f")"
        if grep -qE '^c?fn=\([0-9]+\) ilqr_service::solve::solve$' "$f"; then
            worker=$((worker + n)) workers=$((workers + 1))
        else
            rest=$((rest + n))
        fi
    done
    [[ "$workers" -eq 1 ]] || fail "expected one thread that ran ilqr_service::solve::solve in dump $dump, found $workers"
    python3 - "$body" "${inproc[$body]}" "$((worker / REQUESTS))" "$((rest / REQUESTS))" "$REQUESTS" <<'EOF'
import sys
body, inproc, worker, rest, n = sys.argv[1], *map(int, sys.argv[2:])
server = worker + rest
print(f"== {body} body, per request")
print(f"  in process (parse, validate, solve, serialise)  {inproc / 1e6:.3f} M  ({n} requests after 5 warm-up)")
print(f"  server: solver worker {worker / 1e6:.3f} M + runtime and other threads {rest / 1e3:.1f} k"
      f" = {server / 1e6:.3f} M  ({n} requests after 5 warm-up)")
print(f"  server / in process  {server / inproc:.4f}  (+{(server - inproc) / 1e3:.1f} k instructions)")
EOF
done
