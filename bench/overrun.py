#!/usr/bin/env python3
"""How late a solve ends after its time budget, for one or more binaries.

Solves long-horizon problems (N = 10000, dt = 0.0005, tolerance 0 so only
the budget can stop them) with 1 and 100 obstacles under several budgets,
through `ilqr-service solve FILE -o RESULT`, and prints the overrun
(`solve_time_ms` minus the budget) as min / median / max per binary, and
how many answers carried gains about the previous iterate (a budget that
falls between an accepted step and the backward pass about it). The
binaries take turns run by run, so a change in the machine's speed hits
them alike.

    python3 bench/overrun.py [--runs R] BINARY [BINARY ...]

Standard library only. Obstacles are drawn uniformly in [-5, 10]^2 with
weight 10 from random.seed(1), the set BENCHMARKS.md's figures use.
"""

import argparse
import json
import random
import statistics
import subprocess
import tempfile
from pathlib import Path


def problem(obstacles: int, budget_ms: int) -> dict:
    rng = random.Random(1)
    return {
        "horizon": 10000,
        "dt": 0.0005,
        "obstacles": [
            {"center": [rng.uniform(-5, 10), rng.uniform(-5, 10)], "weight": 10}
            for _ in range(obstacles)
        ],
        "solver": {"tolerance": 0, "max_iterations": 10000, "time_limit_ms": budget_ms,
                   "multi_start": False},
        "output": {"gains": True, "trace": False},
    }


def solve(binary: str, path: Path, out: Path) -> dict:
    subprocess.run(
        [binary, "solve", str(path), "-o", str(out)],
        check=True,
        stdout=subprocess.DEVNULL,
    )
    return json.loads(out.read_text())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=6)
    ap.add_argument("binaries", nargs="+")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        print(f"{'obstacles':>9} {'budget':>7}  {'binary':<40} "
              f"{'overrun min / median / max (ms)':<32} {'iterations':<10} stale gains")
        for obstacles in (1, 100):
            for budget in (10, 50):
                path = Path(tmp) / f"p{obstacles}_{budget}.json"
                path.write_text(json.dumps(problem(obstacles, budget)))
                late: dict[str, list[float]] = {b: [] for b in args.binaries}
                iters: dict[str, list[int]] = {b: [] for b in args.binaries}
                stale: dict[str, int] = {b: 0 for b in args.binaries}
                for _ in range(args.runs):
                    for b in args.binaries:
                        r = solve(b, path, Path(tmp) / "r.json")
                        if r["status"] != "time_limit":
                            raise SystemExit(f"{b}: expected time_limit, got {r['status']}")
                        late[b].append(r["solve_time_ms"] - budget)
                        iters[b].append(r["iterations"])
                        gains = r.get("gains")
                        stale[b] += bool(gains and gains["about_previous_iterate"])
                for b in args.binaries:
                    o = late[b]
                    print(f"{obstacles:>9} {budget:>5}ms  {b:<40} "
                          f"{min(o):6.2f} / {statistics.median(o):6.2f} / {max(o):6.2f}"
                          f"{'':<11} {min(iters[b]):>3}-{max(iters[b]):<6} "
                          f"{stale[b]} of {args.runs}")


if __name__ == "__main__":
    main()
