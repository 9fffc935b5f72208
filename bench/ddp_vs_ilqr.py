"""iLQR against DDP (`solver.method`) on the problems where they differ.

    python3 bench/ddp_vs_ilqr.py target/release/ilqr-service [REPEAT]

Solves each problem below with `"method": "ilqr"` and `"method": "ddp"`,
REPEAT times each (default 15, alternating so both see the same machine
load), through `BINARY solve - -o FILE`, and prints per problem and
method: the status, iterations, cost, and the median and best of the
result's `solve_time_ms` (the solve alone, no process start or JSON).

The problems: the seed; the seed with R = 90·I (an optimum with large
costates, where iLQR converges linearly); inertia 1e-4 (r/I = 1e4); and a
30 kg vehicle (mass 30, inertia 2, arm 0.5).
"""

import json
import os
import statistics
import subprocess
import sys
import tempfile

PROBLEMS = {
    "seed": {},
    "seed, R = 90": {"weights": {"control": [90, 90]}},
    "inertia 1e-4": {"model": {"inertia": 1e-4}},
    "30 kg vehicle": {"model": {"mass": 30, "inertia": 2, "arm_length": 0.5}},
}


def solve(binary: str, problem: dict, out: str) -> dict:
    run = subprocess.run([binary, "solve", "-", "-o", out], input=json.dumps(problem),
                         capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"{binary} failed: {run.stderr}")
    with open(out) as f:
        return json.load(f)


def main() -> int:
    binary = sys.argv[1]
    repeat = int(sys.argv[2]) if len(sys.argv) > 2 else 15
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "result.json")
        for name, base in PROBLEMS.items():
            times = {"ilqr": [], "ddp": []}
            last = {}
            for _ in range(repeat):
                for method in times:
                    problem = dict(base, solver={"method": method, "multi_start": False}, output={"trace": False})
                    last[method] = solve(binary, problem, out)
                    times[method].append(last[method]["solve_time_ms"])
            for method, t in times.items():
                r = last[method]
                print(f"{name:15} {method:4}  {r['status']:14} {r['iterations']:4} iterations  "
                      f"cost {r['cost']:.6f}  solve ms median {statistics.median(t):.3f} "
                      f"best {min(t):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
