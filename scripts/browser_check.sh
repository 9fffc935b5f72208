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
# shellcheck source=scripts/lib.sh
. scripts/lib.sh
BIN="${1:-$(target_dir)/release/ilqr-service}"
[ -x "$BIN" ] || { echo "no binary at $BIN (cargo build --release first)"; exit 1; }

if [ -n "${CHROMIUM:-}" ]; then
  [ -x "$CHROMIUM" ] || { echo "CHROMIUM=$CHROMIUM is not an executable"; exit 1; }
else
  CHROMIUM=/usr/bin/chromium
  if [ ! -x "$CHROMIUM" ]; then
    echo "installing chromium (apt-get)"
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO=sudo
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get install -y -qq chromium >/dev/null 2>&1 \
      || { $SUDO apt-get update -qq && $SUDO apt-get install -y -qq chromium >/dev/null; }
  fi
fi
command -v node >/dev/null || { echo "Node.js 20 or newer is needed (node not found)"; exit 1; }
node -e 'process.exit(+process.versions.node.split(".")[0] >= 20 ? 0 : 1)' \
  || { echo "Node.js 20 or newer is needed (found $(node --version))"; exit 1; }
npm ci --prefix tests/browser --no-audit --no-fund --loglevel=error >/dev/null

LOG=$(mktemp -t ilqr-browser-server.XXXXXX.log)
SERVER=""
trap stop_server EXIT
start_server "$BIN" "$LOG"

SHOTS=$(mktemp -d -t ilqr-docs-shots.XXXXXX)
status=0
node tests/browser/docs_check.mjs "http://127.0.0.1:$PORT" --chromium "$CHROMIUM" \
  --shots "$SHOTS" || status=1
node tests/browser/docs_check.mjs "http://127.0.0.1:$PORT" --behind-prefix /ilqr \
  --resolve ilqr.test --chromium "$CHROMIUM" --shots "$SHOTS" || status=1
if [ $status -eq 0 ]; then
  rm -rf "$SHOTS" "$LOG"
else
  echo "screenshots of each step: $SHOTS; server log: $LOG"
fi
exit $status
