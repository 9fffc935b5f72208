#!/usr/bin/env bash
# Server instructions per solve, gRPC against HTTP: deterministic where
# bench/transports.sh's CPU time is not (the host's other tenants move it).
#
#   bash bench/transports_instructions.sh [lean|full] [SOLVES]
#
# For each transport, runs the release server under callgrind twice, once
# answering 40 solves and once 40 + SOLVES (default 160), from 2 clients
# of benches/transports.rs, and divides the difference of the two runs'
# instruction totals by SOLVES: start-up, connection set-up and shutdown
# cancel out. User space only (callgrind counts no kernel work), all of the
# server's threads. Takes 3 to 5 minutes.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=scripts/lib.sh
. scripts/lib.sh

BODY=${1:-lean}
SOLVES=${2:-160}
BASE=40
command -v valgrind >/dev/null || { echo "needs valgrind (apt-get install valgrind)"; exit 1; }
cargo build --release --bin ilqr-service
cargo bench --bench transports --no-run
BIN="$(target_dir)/release/ilqr-service"
BENCH=$(cargo bench --bench transports --no-run --message-format=json 2>/dev/null \
  | sed -n 's/.*"executable":"\([^"]*\)".*/\1/p' | tail -1)
OUT=$(mktemp -d -t ilqr-transports-callgrind.XXXXXX)
trap 'stop_server' EXIT

# Instructions of one server run that answers $2 solves over transport $1.
instructions() {
  local transport=$1 count=$2 grpc_port
  grpc_port=$(free_port)
  PORT=$(free_port)
  valgrind --tool=callgrind --callgrind-out-file="$OUT/$transport.$count" \
    "$BIN" serve --bind "127.0.0.1:$PORT" --grpc-bind "127.0.0.1:$grpc_port" --workers 2 \
    --default-time-limit-ms 60000 >"$OUT/$transport.$count.log" 2>&1 &
  SERVER=$!
  poll_healthy "$BIN" "$PORT" "$SERVER" 600 || { cat "$OUT/$transport.$count.log"; exit 1; }
  RUST_LOG=warn "$BENCH" --pid "$SERVER" --http "127.0.0.1:$PORT" --grpc "127.0.0.1:$grpc_port" \
    --only "$transport" --count "$count" --clients 2 --rounds 1 --body "$BODY" >/dev/null
  stop_server
  sed -n 's/^summary: //p' "$OUT/$transport.$count"
}

declare -A PER
for transport in http grpc; do
  low=$(instructions "$transport" "$BASE")
  high=$(instructions "$transport" $((BASE + SOLVES)))
  PER[$transport]=$(( (high - low) / SOLVES ))
  echo "$transport: $low and $high instructions for $BASE and $((BASE + SOLVES)) solves: ${PER[$transport]} per solve"
done
awk -v g="${PER[grpc]}" -v h="${PER[http]}" \
  'BEGIN { printf "grpc/http instructions per solve (%s body): %.4f\n", "'"$BODY"'", g / h }'
