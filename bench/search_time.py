"""What the search over routes costs on the seed, in CPU and wall time.

Starts the release server (`serve --workers W`), sends the seed problem
one request at a time, `--requests` times each way, and reports the
medians of what the answers say:

  * single: `{"solver": {"multi_start": false}}`, the paper's one solve;
  * search: `{}` (2 starts: rest, which goes west, and east of the
    obstacle).

The answer's `solve_time_ms` is the wall time of the solve (every start's,
side by side on idle workers); the sum of its starts' `solve_time_ms` is
the CPU time of the starts kept. A lent worker may also have begun a
detour that the plain start then ruled out (dropped, not listed), so the
server process's own CPU time per request is reported too, measured over
blocks of 20 requests of each kind in turn (it includes HTTP's share).
Run with `--workers 2` (idle workers: the search spreads) and `--workers
1` (none idle: its starts run one after another, as under load, and
nothing is begun that is not kept). With `--ipopt`, one cold IPOPT solve of the seed
(bench/casadi_ipopt.py: building the NLP plus its first solve) in the same
run, for the ratio.

Usage (a Python with requests, such as the tests' .venv):
    .venv/bin/python bench/search_time.py [--workers 2] [--requests 300] [--ipopt]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys

import requests

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _serve import serving  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", default="target/release/ilqr-service")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--requests", type=int, default=300)
    ap.add_argument("--ipopt", action="store_true")
    ap.add_argument("--ipopt-python", default=".venv-bench/bin/python",
                    help="a Python with casadi (bench/requirements.txt)")
    args = ap.parse_args()
    light = {"output": {"gains": False, "trace": False}}
    bodies = {
        "single": dict(light, solver={"multi_start": False}),
        "search": dict(light),
    }
    out = {}
    with serving(args.binary, "--workers", str(args.workers)) as (url, pid):
        with requests.Session() as s:
            for _ in range(50):  # warm up both paths
                for body in bodies.values():
                    s.post(url + "/solve", json=body).raise_for_status()
            walls = {k: [] for k in bodies}
            cpus = {k: [] for k in bodies}
            process = {k: 0.0 for k in bodies}
            costs = {}
            # Interleaved in blocks, so that both see the same machine.
            block = 20  # --requests is rounded up to a multiple of this
            for _ in range(-(-args.requests // block)):
                for name, body in bodies.items():
                    before = process_cpu_ms(pid)
                    for _ in range(block):
                        r = s.post(url + "/solve", json=body)
                        r.raise_for_status()
                        a = r.json()
                        walls[name].append(a["solve_time_ms"])
                        cpus[name].append(sum(st["solve_time_ms"] for st in a["starts"]))
                        costs[name] = (a["cost"], len(a["starts"]))
                    process[name] += process_cpu_ms(pid) - before
    for name in bodies:
        out[name] = {
            "wall_ms": statistics.median(walls[name]),
            "cpu_ms": statistics.median(cpus[name]),
            "cost": costs[name][0],
            "starts": costs[name][1],
            "process_cpu_ms": process[name] / len(walls[name]),
        }
        print(f"{name:7s} cost {costs[name][0]:.6f} ({costs[name][1]} starts): "
              f"wall median {out[name]['wall_ms']:.3f} ms, CPU median {out[name]['cpu_ms']:.3f} ms, "
              f"server process CPU {out[name]['process_cpu_ms']:.3f} ms/request")
    wall = out["search"]["wall_ms"] / out["single"]["wall_ms"]
    cpu = out["search"]["cpu_ms"] / out["single"]["cpu_ms"]
    proc = out["search"]["process_cpu_ms"] / out["single"]["process_cpu_ms"]
    print(f"search / single with {args.workers} workers: wall {wall:.2f}x, CPU {cpu:.2f}x "
          f"(server process {proc:.2f}x)")
    if args.ipopt:
        here = os.path.dirname(os.path.abspath(__file__))
        res = subprocess.run(
            [args.ipopt_python, os.path.join(here, "casadi_ipopt.py"), "--repeat", "1", "--json"],
            check=True, capture_output=True, text=True,
        )
        cold = json.loads(res.stdout)["cold_ms"]
        print(f"IPOPT cold (build + first solve): {cold:.1f} ms = "
              f"{cold / out['search']['wall_ms']:.0f}x the search's wall time")
    return 0


def process_cpu_ms(pid: int) -> float:
    """User plus system time of a process so far, ms (/proc/PID/stat)."""
    with open(f"/proc/{pid}/stat") as f:
        # Fields after the command (which may hold spaces), from field 3.
        fields = f.read().rsplit(")", 1)[1].split()
    ticks = int(fields[11]) + int(fields[12])  # utime, stime: fields 14, 15
    return ticks * 1000.0 / os.sysconf("SC_CLK_TCK")


if __name__ == "__main__":
    sys.exit(main())
