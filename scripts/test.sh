#!/usr/bin/env bash
# The whole test suite, as CI runs it (`.ci/run` calls this) and as the
# README tells a newcomer to run it. Installs what it needs into ./.venv.
#
#   1. cargo fmt --check, cargo clippy -D warnings (cargo with --locked: a
#      Cargo.lock that Cargo.toml has outgrown fails here, as it would fail
#      the Dockerfile's --locked build, instead of being rewritten quietly)
#   2. Rust tests (solver, validation, HTTP over loopback, OpenAPI freshness)
#   3. Python client tests against the real release binary
#   4. hadolint on the Dockerfile
#   5. schemathesis against the running release binary
#   6. malformed raw HTTP requests against it (fuzz/http/raw_requests.py)
#   7. the fuzz targets compile and lint clean (running them is manual)
#   8. Swagger UI in headless Chromium against the release binary
#      (scripts/browser_check.sh: installs Debian's chromium with apt-get
#      and playwright-core with npm; needs Node.js 20 or newer)
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n==> %s\n' "$*"; }
# shellcheck source=scripts/lib.sh
. scripts/lib.sh

step "Python tools (.venv)"
if [ ! -x .venv/bin/python ]; then
  python3 -m venv .venv
fi
.venv/bin/python -m pip install --quiet --disable-pip-version-check \
  -r scripts/requirements-test.txt -e 'clients/python[test,plot,fast]'

step "cargo fmt --check"
cargo fmt --all -- --check

step "cargo clippy -D warnings"
cargo clippy --locked --workspace --all-targets --release -- -D warnings

step "Rust tests (release: the numbers and time budgets are the shipped ones)"
cargo test --locked --workspace --release

step "release binary"
cargo build --locked --release --bin ilqr-service
TARGET_DIR=$(target_dir)
BIN="$TARGET_DIR/release/ilqr-service"

step "OpenAPI freshness (the CLI prints the same document)"
"$BIN" openapi | diff -u openapi/openapi.json - \
  || { echo "openapi/openapi.json is stale: run UPDATE_OPENAPI=1 cargo test --release --test openapi"; exit 1; }

step "Python client tests against the release binary"
ILQR_SERVICE_BIN="$BIN" .venv/bin/python -m pytest clients/python/tests -q

step "mypy --strict: the Python client's types, numpy arrays included"
(cd clients/python && ../../.venv/bin/mypy --strict src/ilqr_client tests/test_typing.py)

step "hadolint Dockerfile"
.venv/bin/hadolint Dockerfile && echo "hadolint: clean"

SERVER=""
SERVER_LOG=""
trap 'stop_server; if [ -n "$SERVER_LOG" ]; then echo "server log: $SERVER_LOG"; fi' EXIT

step "schemathesis against the running release binary"
# Short budgets: generated problems may ask for 10000 steps and iterations.
SERVER_LOG=$(mktemp -t ilqr-schemathesis-server.XXXXXX.log)
start_server "$BIN" "$SERVER_LOG" --default-time-limit-ms 200 --max-time-limit-ms 500 \
  --queue-capacity 64
# Every check but one: positive_data_acceptance would demand a 2xx for any
# schema-valid problem, but one rule cannot be written in JSON Schema:
# initial_controls must have exactly `horizon` rows (a 422 with its pointer).
.venv/bin/schemathesis run openapi/openapi.json --url "http://127.0.0.1:$PORT" \
  --checks all --exclude-checks positive_data_acceptance \
  --max-examples 40 --seed 1 --no-color
stop_server

step "malformed raw HTTP requests (framing, headers, methods, paths): no 5xx, no hang"
SERVER_LOG=$(mktemp -t ilqr-raw-http-server.XXXXXX.log)
start_server "$BIN" "$SERVER_LOG" --read-timeout-secs 2 --workers 1
.venv/bin/python fuzz/http/raw_requests.py "$PORT"
stop_server
trap - EXIT

step "fuzz targets compile, lint clean (running them: docs/testing.md, Fuzzing)"
# With the root's release settings (Cargo.toml [profile.release]) instead of
# fuzz/'s own, which differ for symbolised crash reports: the lint then
# reuses most of what the root's clippy step above already checked and
# compiled (about 50 s instead of 2 min from a cold target directory). A change to the root's profile
# that is not made here costs time, nothing else.
(cd fuzz && cargo fmt -- --check \
  && CARGO_PROFILE_RELEASE_DEBUG=line-tables-only CARGO_PROFILE_RELEASE_LTO=thin \
     CARGO_PROFILE_RELEASE_CODEGEN_UNITS=1 CARGO_TARGET_DIR="$TARGET_DIR" \
     cargo clippy --locked --release -- -D warnings)

step "Swagger UI in headless Chromium (/docs, directly and behind a path prefix)"
scripts/browser_check.sh "$BIN"

echo
echo "all suites passed"
