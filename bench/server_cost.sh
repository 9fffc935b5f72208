#!/usr/bin/env bash
# What one POST /solve costs the server beyond the solve: CPU (user, kernel),
# context switches and page faults per request, read from /proc while wrk
# loads the release binary on loopback.
#
#   bash bench/server_cost.sh                      # 3 rounds of 6 s, lean body
#   ROUNDS=4 BODY=full bash bench/server_cost.sh
#   bash bench/server_cost.sh ILQR_RUNTIME_THREADS=2   # env for the server
#
# Each round starts a fresh `ilqr-service serve --workers 2 --queue-capacity
# 64`, warms it for 2 s, then runs `wrk -t2 -c8 -d${DURATION}s -s
# bench/post_seed.lua URL -- $BODY` and prints, per request:
#   usr_us, sys_us   server user and kernel CPU (/proc/PID/stat utime, stime)
#   wrk_us           wrk's own CPU (user + system, from /usr/bin/time)
#   vcs, ivcs        voluntary and involuntary context switches, summed over
#                    the server's threads (/proc/PID/task/*/status)
#   minflt           minor page faults of the server (/proc/PID/stat)
# Absolute CPU times move with the machine's load; compare configurations
# by alternating them (e.g. run the script with and without a setting,
# twice each).
set -euo pipefail

cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
ROUNDS="${ROUNDS:-3}"
DURATION="${DURATION:-6}"
BODY="${BODY:-lean}"
# shellcheck source=scripts/lib.sh
. scripts/lib.sh
BIN="$(target_dir)/release/ilqr-service" # honours CARGO_TARGET_DIR
tmp="$(mktemp -d)"
SERVER_PID=""
trap kill_server_and_tmp EXIT

command -v wrk >/dev/null || { echo "needs wrk (apt-get install wrk)" >&2; exit 1; }
[[ -x /usr/bin/time ]] || { echo "needs /usr/bin/time (apt-get install time)" >&2; exit 1; }
cargo build --release --quiet --bin ilqr-service

switches() { # voluntary and involuntary context switches over all threads
    cat /proc/"$1"/task/*/status 2>/dev/null |
        awk '/^voluntary_ctxt_switches/ { v += $2 } /^nonvoluntary_ctxt_switches/ { n += $2 } END { print v, n }'
}

for round in $(seq "$ROUNDS"); do
    port="$(free_port)"
    url="http://127.0.0.1:$port/solve"
    env "$@" "$BIN" serve --bind "127.0.0.1:$port" --workers 2 --queue-capacity 64 \
        >"$tmp/server.log" 2>&1 &
    SERVER_PID=$!
    wait_healthy "$BIN" "$port" "$SERVER_PID" "$tmp/server.log" || exit 1
    wrk -t2 -c8 -d2s -s bench/post_seed.lua "$url" -- "$BODY" >/dev/null
    read -r u0 s0 f0 < <(awk '{ print $14, $15, $10 }' /proc/"$SERVER_PID"/stat)
    read -r v0 n0 < <(switches "$SERVER_PID")
    /usr/bin/time -o "$tmp/wrk.time" -f "%U %S" \
        wrk -t2 -c8 -d"${DURATION}s" -s bench/post_seed.lua "$url" -- "$BODY" >"$tmp/wrk.out"
    read -r u1 s1 f1 < <(awk '{ print $14, $15, $10 }' /proc/"$SERVER_PID"/stat)
    read -r v1 n1 < <(switches "$SERVER_PID")
    kill -KILL "$SERVER_PID"
    wait "$SERVER_PID" 2>/dev/null || true
    SERVER_PID=""
    read -r wu ws <"$tmp/wrk.time"
    if ! grep -q '^RESULT requests=[1-9]' "$tmp/wrk.out"; then
        echo "wrk got no answers; its output:" >&2
        cat "$tmp/wrk.out" >&2
        exit 1
    fi
    python3 - "$round" "$BODY" "$*" "$(grep '^RESULT' "$tmp/wrk.out")" \
        "$u0" "$u1" "$s0" "$s1" "$f0" "$f1" "$v0" "$v1" "$n0" "$n1" "$wu" "$ws" "$(getconf CLK_TCK)" <<'EOF'
import sys
rnd, body, env, result = sys.argv[1:5]
u0, u1, s0, s1, f0, f1, v0, v1, n0, n1 = map(int, sys.argv[5:15])
wu, ws, tck = float(sys.argv[15]), float(sys.argv[16]), int(sys.argv[17])
kv = dict(p.split("=", 1) for p in result.split()[1:])
n = int(kv["requests"])
print(f"round {rnd} body={body} env=[{env}] {float(kv['ok_per_s']):.0f} solves/s: "
      f"usr_us={(u1 - u0) / tck / n * 1e6:.0f} sys_us={(s1 - s0) / tck / n * 1e6:.0f} "
      f"wrk_us={(wu + ws) / n * 1e6:.0f} vcs={(v1 - v0) / n:.2f} ivcs={(n1 - n0) / n:.2f} "
      f"minflt={(f1 - f0) / n:.2f}")
EOF
done
