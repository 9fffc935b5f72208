#!/usr/bin/env bash
# iLQR (Rust) against CasADi + IPOPT on the seed problem, in one run.
#
#   bash bench/compare_ipopt.sh            # from anywhere in the repository
#   REPEAT=20 bash bench/compare_ipopt.sh  # more IPOPT solves (default 10)
#
# 1. Rust time: the divan seed benchmarks (`cargo bench -p ilqr --bench
#    solver -- seed_solve`), median of 100 solves each: `reused_solver`
#    (warm workspace) and `new_solver` (a fresh Solver per solve, as the
#    service does).
# 2. Rust cost: `ilqr-service solve -o FILE` (the seed; the release binary
#    in the cargo target directory, which follows CARGO_TARGET_DIR).
# 3. IPOPT: `bench/casadi_ipopt.py --json --repeat $REPEAT` in the venv
#    .venv-bench (created from bench/requirements.txt if missing): median
#    wall time of opti.solve() and the cost of its controls re-rolled out.
# Then prints both times, both costs, the time ratio (IPOPT / iLQR), IPOPT's
# cold time (building the NLP + its first solve, what a per-request service
# would pay) against a new-Solver iLQR solve, and the relative cost
# difference |J_ilqr - J_ipopt| / |J_ipopt|.
#
# The two solvers run back to back so that they see the same machine load;
# on a shared machine compare the ratio, not the absolute times.
set -euo pipefail

cd "$(git -C "$(dirname "$0")" rev-parse --show-toplevel)"
# shellcheck source=scripts/lib.sh
. scripts/lib.sh
BIN="$(target_dir)/release/ilqr-service" # honours CARGO_TARGET_DIR
REPEAT="${REPEAT:-10}"
VENV=.venv-bench
tmp="$(mktemp -d)"
trap 'rm -rf "$tmp"' EXIT

if [[ ! -x "$VENV/bin/python" ]]; then
    echo "creating $VENV from bench/requirements.txt" >&2
    python3 -m venv "$VENV"
    "$VENV/bin/pip" install --quiet -r bench/requirements.txt
fi

echo "building (release)" >&2
cargo build --release --quiet --bin ilqr-service
cargo bench -p ilqr --bench solver --no-run --quiet 2>/dev/null

echo "running: cargo bench -p ilqr --bench solver -- seed_solve" >&2
cargo bench -p ilqr --bench solver --quiet -- seed_solve >"$tmp/divan.txt" 2>/dev/null
cat "$tmp/divan.txt" >&2
"$BIN" solve -o "$tmp/rust.json" >/dev/null

echo "running: $VENV/bin/python bench/casadi_ipopt.py --json --repeat $REPEAT" >&2
"$VENV/bin/python" bench/casadi_ipopt.py --json --repeat "$REPEAT" >"$tmp/ipopt.json"

warm="$(python3 bench/divan_times.py --field median seed_solve/reused_solver <"$tmp/divan.txt")"
cold="$(python3 bench/divan_times.py --field median seed_solve/new_solver <"$tmp/divan.txt")"

python3 - "$warm" "$cold" "$tmp/rust.json" "$tmp/ipopt.json" <<'EOF'
import json, sys

warm, cold = float(sys.argv[1]), float(sys.argv[2])
rust = json.load(open(sys.argv[3]))
ipopt = json.load(open(sys.argv[4]))
ip_ms = ipopt["median_ms"]
j_r, j_i = rust["cost"], ipopt["cost"]
print(f"iLQR   seed solve, median of 100  {warm * 1e3:9.4f} ms (reused Solver)"
      f"   {cold * 1e3:9.4f} ms (new Solver)")
print(f"IPOPT  seed solve, median of {ipopt['repeat']:<3d}  {ip_ms:9.4f} ms"
      f" (best {ipopt['best_ms']:.4f} ms, {ipopt['iterations']} iterations, {ipopt['status']})")
print(f"iLQR   cost  {j_r:.9f}  ({rust['status']}, {rust['iterations']} iterations)")
print(f"IPOPT  cost  {j_i:.9f}")
print(f"time ratio IPOPT / iLQR   {ip_ms / (warm * 1e3):8.1f}x (reused Solver)"
      f"   {ip_ms / (cold * 1e3):8.1f}x (new Solver)")
print(f"IPOPT  cold (build the NLP + first solve)  {ipopt['cold_ms']:9.4f} ms:"
      f" {ipopt['cold_ms'] / (cold * 1e3):8.1f}x a new-Solver iLQR solve")
print(f"relative cost difference  {abs(j_r - j_i) / abs(j_i):.3e}")
EOF
