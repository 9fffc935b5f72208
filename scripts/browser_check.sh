#!/usr/bin/env bash
# Swagger UI (/docs) in a real headless Chromium against the release
# binary (tests/browser/docs_check.mjs): once directly on 127.0.0.1, once
# behind a path-prefix proxy under a made-up host name (Swagger UI treats
# localhost and 127.0.0.1 specially). Called by scripts/test.sh.
#
#   scripts/browser_check.sh [PATH/TO/ilqr-service]
#
# Installs what it needs: Debian's chromium (apt-get, as root or through
# sudo; about 155 MB to download, once) unless CHROMIUM names one, and
# playwright-core into tests/browser/node_modules (npm ci, from the lock).
# Needs Node.js 20 or newer.
set -euo pipefail
cd "$(dirname "$0")/.."
BIN="${1:-target/release/ilqr-service}"
CHROMIUM="${CHROMIUM:-/usr/bin/chromium}"

if [ ! -x "$CHROMIUM" ]; then
  echo "installing chromium (apt-get)"
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
  $SUDO apt-get install -y -qq chromium >/dev/null 2>&1 \
    || { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq chromium >/dev/null; }
fi
command -v node >/dev/null || { echo "Node.js 20 or newer is needed (node not found)"; exit 1; }
node -e 'process.exit(+process.versions.node.split(".")[0] >= 20 ? 0 : 1)' \
  || { echo "Node.js 20 or newer is needed (found $(node --version))"; exit 1; }
npm ci --prefix tests/browser --no-audit --no-fund --loglevel=error >/dev/null

LOG=$(mktemp -t ilqr-browser-server.XXXXXX.log)
SERVER=""
trap 'if [ -n "$SERVER" ]; then kill $SERVER 2>/dev/null || true; fi' EXIT
# The port was free when picked; if another process takes it first, the
# server exits: pick another (three tries).
for _ in 1 2 3; do
  PORT=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  "$BIN" serve --bind "127.0.0.1:$PORT" >"$LOG" 2>&1 &
  SERVER=$!
  HEALTHY=""
  for _ in $(seq 100); do
    if "$BIN" healthcheck --addr "127.0.0.1:$PORT" 2>/dev/null; then HEALTHY=1; break; fi
    kill -0 $SERVER 2>/dev/null || break
    sleep 0.1
  done
  [ -n "$HEALTHY" ] && break
  kill $SERVER 2>/dev/null || true
  wait $SERVER 2>/dev/null || true
done
[ -n "$HEALTHY" ] || { echo "the server never became healthy:"; cat "$LOG"; exit 1; }

SHOTS=$(mktemp -d -t ilqr-docs-shots.XXXXXX)
status=0
node tests/browser/docs_check.mjs "http://127.0.0.1:$PORT" --chromium "$CHROMIUM" \
  --shots "$SHOTS" || status=1
node tests/browser/docs_check.mjs "http://127.0.0.1:$PORT" --behind-prefix /ilqr \
  --resolve ilqr.test --chromium "$CHROMIUM" --shots "$SHOTS" || status=1
[ $status -eq 0 ] || echo "screenshots of each step: $SHOTS; server log: $LOG"
exit $status
