#!/usr/bin/env bash
# gRPC against HTTP on one release server, in one run: solves/s and the
# server's CPU per solve (benches/transports.rs says how it measures).
#
#   bash bench/transports.sh [--clients 8] [--secs 8] [--rounds 4] [--body lean|full]
#
# Starts `serve --workers 2 --queue-capacity 64` on free ports, waits for
# it, runs the rounds and stops it. The server's threads are pinned to CPU
# 0 and the load generator to CPU 1 (taskset), so that the generator's own
# work, which differs between its HTTP and gRPC clients, does not share
# the server's core and caches: unpinned on 2 cores, the transport whose
# client works harder shows a higher server CPU per solve.
set -euo pipefail
cd "$(dirname "$0")/.."
# shellcheck source=scripts/lib.sh
. scripts/lib.sh

cargo build --release --bin ilqr-service
cargo bench --bench transports --no-run
BIN="$(target_dir)/release/ilqr-service"
GRPC_PORT=$(free_port)
LOG=$(mktemp -t ilqr-transports-server.XXXXXX.log)
trap 'stop_server' EXIT
start_server "$BIN" "$LOG" --workers 2 --queue-capacity 64 --grpc-bind "127.0.0.1:$GRPC_PORT"
taskset -a -p -c 0 "$SERVER" >/dev/null
BENCH=$(cargo bench --bench transports --no-run --message-format=json 2>/dev/null \
  | sed -n 's/.*"executable":"\([^"]*\)".*/\1/p' | tail -1)
RUST_LOG=warn taskset -c 1 "$BENCH" --pid "$SERVER" \
  --http "127.0.0.1:$PORT" --grpc "127.0.0.1:$GRPC_PORT" "$@"
