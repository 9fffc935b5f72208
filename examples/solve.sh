#!/usr/bin/env bash
# Calling ilqr-service with curl.
#
#   examples/solve.sh                                  # service on http://127.0.0.1:8080
#   ILQR_URL=http://127.0.0.1:9000 examples/solve.sh   # elsewhere
#
# With jq installed, solve answers are summarised (status, cost, iterations,
# ...); without it the raw JSON is printed, cut to its first 600 bytes (a full
# answer with gains and trace is tens of kilobytes).
set -euo pipefail

ILQR_URL="${ILQR_URL:-http://127.0.0.1:8080}"
ILQR_URL="${ILQR_URL%/}"
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

have_jq=false
command -v jq >/dev/null 2>&1 && have_jq=true

section() { printf '\n== %s\n' "$*"; }

# POST a body to /solve; $1 is curl's --data-binary argument (`@file` or a JSON
# literal). The answer goes to $tmp/answer.json; a non-200 answer is printed and
# ends the script.
solve() {
    local status
    status="$(curl -sS -o "$tmp/answer.json" -w '%{http_code}' \
        -X POST -H 'Content-Type: application/json' \
        --data-binary "$1" "$ILQR_URL/solve")"
    if [ "$status" != 200 ]; then
        echo "POST $ILQR_URL/solve answered $status:" >&2
        cat "$tmp/answer.json" >&2
        echo >&2
        exit 1
    fi
}

# Print the answer in $tmp/answer.json: a summary with jq, else the raw JSON.
show() {
    if $have_jq; then
        jq '{model, integrator, status, cost, initial_cost, iterations, goal_distance, closest_approach,
             solve_time_ms, queue_time_ms,
             steps: (.controls | length),
             gains: (.gains != null),
             trace_entries: (.trace // [] | length)}' "$tmp/answer.json"
    else
        head -c 600 "$tmp/answer.json"
        echo " ... ($(wc -c < "$tmp/answer.json") bytes; install jq for a summary)"
    fi
}

section "GET $ILQR_URL/healthz"
if ! curl -sS --fail "$ILQR_URL/healthz" -o /dev/null; then
    # The address to serve on: the URL's host and port (no path prefix).
    # --bind takes an IP address, not a name: a named host becomes 127.0.0.1.
    hostport="${ILQR_URL#*://}"
    hostport="${hostport%%/*}"
    default_port=80
    [[ "$ILQR_URL" == https://* ]] && default_port=443
    case "$hostport" in
        \[*\]:*) ;;
        \[*\]) hostport="$hostport:$default_port" ;;
        *:*) [[ "${hostport%:*}" =~ ^[0-9.]+$ ]] || hostport="127.0.0.1:${hostport##*:}" ;;
        *) [[ "$hostport" =~ ^[0-9.]+$ ]] || hostport=127.0.0.1
           hostport="$hostport:$default_port" ;;
    esac
    echo "no ilqr-service at $ILQR_URL (start one from the repository with:" \
        "cargo run --release -- serve --bind $hostport)" >&2
    exit 1
fi
echo "ok"

section "POST /solve with examples/seed.json (the seed problem, every field spelled out)"
solve "@$here/seed.json"
show
full_size="$(wc -c < "$tmp/answer.json")"

section "POST /solve with {} (omitted fields take the seed problem's values: same answer)"
solve '{}'
show

section "POST /solve with gains and trace switched off in \`output\` (a smaller answer)"
solve '{"output": {"gains": false, "trace": false}}'
show
echo "answer size: $(wc -c < "$tmp/answer.json") bytes, against $full_size with gains and trace"

section "POST /solve with examples/three_obstacles.json"
solve "@$here/three_obstacles.json"
show

section "GET /models (each model's state, controls and parameters)"
curl -sS --fail "$ILQR_URL/models" -o "$tmp/models.json"
if $have_jq; then
    jq -c '.models[] | {type, state: [.state[].name], control: [.control[].name],
                        parameters: [.parameters[].name], position}' "$tmp/models.json"
else
    head -c 600 "$tmp/models.json"
    echo " ... (install jq for a summary)"
fi

section "POST /solve with examples/unicycle.json (the unicycle, RK4)"
solve "@$here/unicycle.json"
show

section "POST /solve with {\"model\": {\"type\": \"unicycle\"}} (the unicycle's default problem)"
solve '{"model": {"type": "unicycle"}}'
show

section "An invalid problem: 422 with an application/problem+json body, one JSON pointer per bad field"
curl -sS -i -X POST -H 'Content-Type: application/json' \
    --data-binary '{"dt": -1, "weights": {"state": [1, 1, -1, 1, 1, 1]}}' \
    "$ILQR_URL/solve"
echo
