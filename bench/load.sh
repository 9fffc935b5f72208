#!/usr/bin/env bash
# HTTP load test of the release binary on loopback, with wrk, against the
# in-process ceiling measured in the same run.
#
#   bash bench/load.sh                   # about 3 minutes
#   ROUNDS=8 DURATION=20 bash bench/load.sh
#
# Everything goes to 127.0.0.1 only; every run is bounded in time; the
# server is killed on exit (trap), whatever happens.
#
# 1. Saturation, ROUNDS times (default 6, of DURATION = 8 s each),
#    alternating so that both sides see the same machine load. Many short
#    rounds rather than a few long ones: a host's speed drifts within a
#    minute, and with two rounds one odd minute can move a figure by several
#    points; more, shorter rounds give more samples of the drift in about
#    the same time, though no less drift.
#    a. in-process: `HTTP_PATH_THROUGHPUT_SECS=$DURATION HTTP_PATH_THREADS=2
#       cargo bench --bench http_path`: 2 threads run parse + validate +
#       solve + serialise back to back (benches/http_path.rs), requests/s
#       and CPU seconds;
#    b. HTTP: `ilqr-service serve --workers 2 --queue-capacity 64` and
#       `wrk -t2 -c8 -d${DURATION}s --latency -s bench/post_seed.lua URL --
#       lean` (body {"solver":{"multi_start":false},"output":{"gains":false,"trace":false}}): 200 answers
#       per second, p50/p99, and the server's CPU time from /proc/PID/stat.
#       The script does not count statuses here (see bench/post_seed.lua:
#       a Lua `response` callback costs wrk 10-20 us per answer on the same
#       cores); wrk's own tally of statuses >= 400 gives the 200s.
#    Then the same FULL_ROUNDS times (default 4, of FULL_DURATION = 8 s) for
#    the `full` body (gains and trace in the answer).
#    The server's RSS after the first lean round and after the last full
#    one says whether memory grows with solves served (/metrics is never
#    scraped here).
#    Ratios: HTTP/in-process throughput (wall clock: includes wrk's own CPU
#    on the same 2 cores) and in-process/server CPU per request (not
#    affected by wrk or by other processes taking cores away).
# 2. Overload: `--queue-capacity 2` (4 admission slots: 2 running, 2
#    waiting) against `wrk -t2 -c16 -d${OVERLOAD_DURATION}s` (4x the
#    slots): every answer
#    must be 200 or 503 and wrk must see no socket error or timeout; the
#    server's RSS (`ps -o rss=`) is sampled every second, min/max printed.
#    This run counts every status (`-- lean count`).
#
# Exit status: 0 if the overload run saw only 200s and 503s and no socket
# errors, 1 otherwise.
set -euo pipefail

cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
ROUNDS="${ROUNDS:-6}"
DURATION="${DURATION:-8}"
FULL_DURATION="${FULL_DURATION:-8}"
FULL_ROUNDS="${FULL_ROUNDS:-4}"
OVERLOAD_DURATION="${OVERLOAD_DURATION:-20}"
CONNS="${CONNS:-8}"
OVERLOAD_CONNS="${OVERLOAD_CONNS:-16}"
# shellcheck source=scripts/lib.sh
. scripts/lib.sh
BIN="$(target_dir)/release/ilqr-service" # honours CARGO_TARGET_DIR
LUA=bench/post_seed.lua

tmp="$(mktemp -d)"
SERVER_PID=""
SAMPLER_PID=""
CHILD=""
cleanup() {
    if [[ -n "$CHILD" ]]; then kill "$CHILD" 2>/dev/null || true; fi
    if [[ -n "$SAMPLER_PID" ]]; then kill "$SAMPLER_PID" 2>/dev/null || true; fi
    kill_server_and_tmp # SIGTERM, SIGKILL after 5 s (scripts/lib.sh)
}
trap cleanup EXIT
trap 'exit 130' INT TERM

if ! command -v wrk >/dev/null; then
    echo "installing wrk (apt-get)" >&2
    apt-get install -y -qq wrk >/dev/null 2>&1 || { apt-get update -qq && apt-get install -y -qq wrk; }
fi

echo "building: cargo build --release --bin ilqr-service; cargo bench --bench http_path --no-run" >&2
cargo build --release --quiet --bin ilqr-service
cargo bench --bench http_path --no-run --quiet 2>/dev/null

PORT="${PORT:-$(free_port)}"
URL="http://127.0.0.1:$PORT/solve"

start_server() { # queue capacity
    "$BIN" serve --bind "127.0.0.1:$PORT" --workers 2 --queue-capacity "$1" \
        >"$tmp/server-q$1.log" 2>&1 &
    SERVER_PID=$!
    wait_healthy "$BIN" "$PORT" "$SERVER_PID" "$tmp/server-q$1.log" || exit 1
}

stop_server() {
    kill -TERM "$SERVER_PID"
    wait "$SERVER_PID" || true
    SERVER_PID=""
}

run() { # "$@" in the background, waited for, so that a signal is handled at once
    "$@" &
    CHILD=$!
    local rc=0
    wait "$CHILD" || rc=$?
    CHILD=""
    return "$rc"
}

cpu_ticks() { # user + system CPU time of a process, in clock ticks
    awk '{ print $14 + $15 }' "/proc/$1/stat"
}

inproc() { # body seconds -> appends a THROUGHPUT line to $tmp/inproc-BODY.txt
    echo "running: HTTP_PATH_THROUGHPUT_SECS=$2 HTTP_PATH_THREADS=2 HTTP_PATH_BODY=$1 cargo bench --bench http_path" >&2
    HTTP_PATH_THROUGHPUT_SECS="$2" HTTP_PATH_THREADS=2 HTTP_PATH_BODY="$1" \
        run cargo bench --bench http_path --quiet >"$tmp/inproc.out" 2>/dev/null
    tee -a "$tmp/inproc-$1.txt" <"$tmp/inproc.out" >&2
}

http() { # body seconds round -> $tmp/http-BODY-ROUND.txt (+ SERVERCPU line)
    echo "running: wrk -t2 -c$CONNS -d$2s --latency -s $LUA $URL -- $1" >&2
    local before
    before="$(cpu_ticks "$SERVER_PID")"
    run wrk -t2 -c"$CONNS" -d"$2s" --latency -s "$LUA" "$URL" -- "$1" >"$tmp/http-$1-$3.txt"
    cat "$tmp/http-$1-$3.txt" >&2
    echo "SERVERCPU ticks=$(( $(cpu_ticks "$SERVER_PID") - before )) clk_tck=$(getconf CLK_TCK)" \
        >>"$tmp/http-$1-$3.txt"
}

# 1. Saturation.
start_server 64
for round in $(seq "$ROUNDS"); do
    inproc lean "$DURATION"
    http lean "$DURATION" "$round"
    # Warm after the first round: pools and buffers have their size.
    if [[ "$round" == 1 ]]; then rss_warm="$(ps -o rss= -p "$SERVER_PID" | tr -d ' ')"; fi
done
for round in $(seq "$FULL_ROUNDS"); do
    inproc full "$FULL_DURATION"
    http full "$FULL_DURATION" "$round"
done
rss_saturated="$(ps -o rss= -p "$SERVER_PID" | tr -d ' ')"
stop_server

# 2. Overload.
start_server 2
rss_idle="$(ps -o rss= -p "$SERVER_PID" | tr -d ' ')"
(
    while kill -0 "$SERVER_PID" 2>/dev/null; do
        ps -o rss= -p "$SERVER_PID" | tr -d ' ' >>"$tmp/rss.txt" || true
        sleep 1
    done
) &
SAMPLER_PID=$!
echo "running: wrk -t2 -c$OVERLOAD_CONNS -d${OVERLOAD_DURATION}s --latency -s $LUA $URL -- lean count  (queue capacity 2)" >&2
run wrk -t2 -c"$OVERLOAD_CONNS" -d"${OVERLOAD_DURATION}s" --latency -s "$LUA" "$URL" -- lean count \
    >"$tmp/overload.txt"
cat "$tmp/overload.txt" >&2
kill "$SAMPLER_PID" 2>/dev/null || true
wait "$SAMPLER_PID" 2>/dev/null || true
SAMPLER_PID=""
rss_after="$(ps -o rss= -p "$SERVER_PID" | tr -d ' ')"
stop_server

# Report.
python3 - "$tmp" "$ROUNDS" "$FULL_ROUNDS" "$rss_idle" "$rss_after" "$CONNS" "$OVERLOAD_CONNS" \
    "$rss_warm" "$rss_saturated" <<'EOF'
import re, sys

tmp, rounds, full_rounds = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
rss_idle, rss_after, conns, overload_conns = sys.argv[4:8]
rss_warm, rss_saturated = int(sys.argv[8]), int(sys.argv[9])

def kv(text, tag):
    lines = re.findall(rf"^{tag} (.*)$", text, re.M)
    return dict(p.split("=", 1) for p in lines[-1].split()) if lines else {}

def wrk(name):
    text = open(f"{tmp}/{name}.txt").read()
    r = {k: float(v) for k, v in {**kv(text, "RESULT"), **kv(text, "ERRORS")}.items()}
    cpu = kv(text, "SERVERCPU")
    if cpu:
        r["cpu_s"] = int(cpu["ticks"]) / int(cpu["clk_tck"])
    codes = {k: int(v) for k, v in kv(text, "STATUS").items()}
    return r, codes

def inproc(body):
    rows = re.findall(r"^THROUGHPUT (.*)$", open(f"{tmp}/inproc-{body}.txt").read(), re.M)
    return [{k: (v if k == "body" else float(v)) for k, v in (p.split("=", 1) for p in row.split())}
            for row in rows]

def compare(label, body, http_runs, ins):
    print(f"== {label}")
    ratios = []
    tot = {"http_ok": 0, "http_s": 0.0, "http_cpu": 0.0, "in_n": 0, "in_s": 0.0, "in_cpu": 0.0}
    for i, ((r, codes), p) in enumerate(zip(http_runs, ins), 1):
        ok = codes.get("200", 0)
        http_cpu = r["cpu_s"] / max(ok, 1)
        in_cpu = p["cpu_s"] / max(p["requests"], 1)
        print(f"  round {i}: in-process {p['per_s']:.1f} req/s (2 threads, {in_cpu * 1e3:.3f} ms CPU/req) | "
              f"HTTP {r['ok_per_s']:.1f} solves/s, p50 {r['p50_us'] / 1e3:.2f} ms, "
              f"p99 {r['p99_us'] / 1e3:.2f} ms, {http_cpu * 1e3:.3f} ms server CPU/req, statuses {codes} | "
              f"throughput ratio {r['ok_per_s'] / p['per_s']:.1%}, CPU ratio {in_cpu / http_cpu:.1%}")
        ratios.append(r["ok_per_s"] / p["per_s"])
        tot["http_ok"] += ok; tot["http_s"] += r["duration_s"]; tot["http_cpu"] += r["cpu_s"]
        tot["in_n"] += p["requests"]; tot["in_s"] += p["duration_s"]; tot["in_cpu"] += p["cpu_s"]
    h = tot["http_ok"] / tot["http_s"]
    n = tot["in_n"] / tot["in_s"]
    c = (tot["in_cpu"] / tot["in_n"]) / (tot["http_cpu"] / tot["http_ok"])
    ratios.sort()
    mid = len(ratios) // 2
    median = ratios[mid] if len(ratios) % 2 else (ratios[mid - 1] + ratios[mid]) / 2
    print(f"  all rounds: HTTP {h:.1f} solves/s vs in-process {n:.1f} req/s -> {h / n:.1%} "
          f"(target >= 80%); median of the rounds' ratios {median:.1%}; "
          f"CPU per request in-process/HTTP {c:.1%}")

compare(f"saturation, lean body (2 workers, queue 64, wrk -c{conns})", "lean",
        [wrk(f"http-lean-{i}") for i in range(1, rounds + 1)], inproc("lean"))
compare("saturation, gains+trace body", "full",
        [wrk(f"http-full-{i}") for i in range(1, full_rounds + 1)], inproc("full"))

# Memory across the saturation runs: an unscraped service that kept every
# histogram sample would grow by 58 B a solve, 17 MB a minute at saturation.
later = [wrk(f"http-lean-{i}")[1].get("200", 0) for i in range(2, rounds + 1)] + \
    [wrk(f"http-full-{i}")[1].get("200", 0) for i in range(1, full_rounds + 1)]
grown = rss_saturated - rss_warm
print(f"== memory under saturation (/metrics never scraped)")
print(f"  server RSS after the first round {rss_warm / 1024:.1f} MiB, after the last "
      f"{rss_saturated / 1024:.1f} MiB: {grown / 1024:+.1f} MiB over {sum(later)} solves "
      f"({grown * 1024 / max(sum(later), 1):+.1f} B per solve)")

r, codes = wrk("overload")
other = {k: v for k, v in codes.items() if k not in ("200", "503")}
errors = {k: int(r[k]) for k in ("connect", "read", "write", "timeout")}
rss = [int(x) for x in open(f"{tmp}/rss.txt").read().split()]
print(f"== overload (2 workers, queue 2, wrk -c{overload_conns})")
print(f"  200={codes.get('200', 0)} 503={codes.get('503', 0)} other={sum(other.values())} "
      f"{other or ''} socket errors {errors}")
print(f"  {r['ok_per_s']:.1f} solves/s (200s), {r['requests'] / r['duration_s']:.1f} answers/s; "
      f"p50 {r['p50_us'] / 1e3:.2f} ms, p99 {r['p99_us'] / 1e3:.2f} ms, max {r['max_us'] / 1e3:.2f} ms "
      f"(all answers)")
print(f"  server RSS: idle {int(rss_idle) / 1024:.1f} MiB; during the run min {min(rss) / 1024:.1f} MiB, "
      f"max {max(rss) / 1024:.1f} MiB ({len(rss)} samples, 1/s); after {int(rss_after) / 1024:.1f} MiB")
if other or any(errors.values()):
    print("  FAIL: answers other than 200/503, or socket errors")
    sys.exit(1)
print("  only 200 and 503, no socket errors")
EOF
