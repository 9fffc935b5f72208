#!/usr/bin/env bash
# What a small server answers under 4x and 20x overload (benches/overload.rs
# says what it counts): `serve --workers 2 --queue-capacity 4` (6 admission
# slots) pinned to CPU 0, the load generator pinned to CPU 1, so that the
# clients' own work does not take the server's core. Each round starts a
# fresh server.
#
#   bash bench/overload.sh [--secs 20] [--factors "4 20"] [--problem FILE]
#
# The default problem is issue 40's problem 2: 5000 steps of 1 ms past 40
# soft points, a 500 ms budget, no gains and no trace, searched (the
# default).
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=scripts/lib.sh
. scripts/lib.sh

SECS=20
FACTORS="4 20"
PROBLEM=""
while [ $# -gt 0 ]; do
  case "$1" in
    --secs) SECS=$2; shift 2 ;;
    --factors) FACTORS=$2; shift 2 ;;
    --problem) PROBLEM=$2; shift 2 ;;
    *) echo "unknown flag $1" >&2; exit 2 ;;
  esac
done

cargo build --release --bin ilqr-service
cargo bench --bench overload --no-run
BIN="$(target_dir)/release/ilqr-service"
BENCH=$(cargo bench --bench overload --no-run --message-format=json 2>/dev/null \
  | sed -n 's/.*"executable":"\([^"]*\)".*/\1/p' | tail -1)
tmp=$(mktemp -d -t ilqr-overload.XXXXXX)
trap 'stop_server; rm -rf "$tmp"' EXIT
if [ -z "$PROBLEM" ]; then
  PROBLEM="$tmp/problem.json"
  python3 - "$PROBLEM" <<'PY'
import json, sys
obstacles = [{"center": [4 + 0.1 * i, 4.5]} for i in range(40)]
json.dump({"horizon": 5000, "dt": 0.001, "obstacles": obstacles,
           "solver": {"time_limit_ms": 500},
           "output": {"gains": False, "trace": False}}, open(sys.argv[1], "w"))
PY
fi
BUDGET=$(python3 -c 'import json, sys; print(json.load(open(sys.argv[1]))["solver"]["time_limit_ms"])' "$PROBLEM")

for factor in $FACTORS; do
  echo
  echo "== ${factor}x the 6 admission slots"
  start_server "$BIN" "$tmp/server.log" --workers 2 --queue-capacity 4 --log-format json
  taskset -a -p -c 0 "$SERVER" >/dev/null
  taskset -c 1 "$BENCH" --url "http://127.0.0.1:$PORT" --problem "$PROBLEM" \
    --clients $((factor * 6)) --secs "$SECS" --budget-ms "$BUDGET" --pid "$SERVER"
  stop_server
done
