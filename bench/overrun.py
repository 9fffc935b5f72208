#!/usr/bin/env python3
"""How late answers leave their worker after the time budget, and how soon a
worker is free after its client leaves.

Against `BINARY serve --workers W` (release build), with issue 40's problems:

* `points`: N = 10000, dt 0.5 ms, 40 soft points in a row across the way,
  no tolerance, 445 ms; searched (the default);
* `rectangles`: N = 10000, 100 hard rectangles (clearance 0.1, no weight)
  from random.Random(1), budgets 1 ms (with max_starts 32), 100, 300 and
  1000 ms, searched and single (`multi_start: false`);
* each over HTTP with and without gzip.

The overrun is the answer's own `Server-Timing` total (queue, solve and
encoding) minus the budget; printed as min / median / p90 / max over the
runs, with the share within the service's promise (the budget plus 5%, at
least 5 ms). A 503 (a budget too short to start in) is counted apart.

Then, on one worker: a search of the rectangles with a 10 s budget whose
client leaves after a random 50-400 ms; a tiny solve posted right after
reports how long it waited for the worker (`Server-Timing`'s queue): the
time from the client leaving to a free worker.

    python3 bench/overrun.py BINARY [--runs 10] [--workers 2]

Needs `requests` (the repository's .venv has it).
"""

import argparse
import json
import random
import socket
import statistics
import time

import requests
from _serve import serving


def points(budget_ms: int) -> dict:
    return {
        "horizon": 10000,
        "dt": 0.0005,
        "obstacles": [{"center": [4 + 0.1 * i, 4.5]} for i in range(40)],
        "solver": {"tolerance": 0, "max_iterations": 10000, "time_limit_ms": budget_ms},
    }


def rectangles(budget_ms: int, search: bool) -> dict:
    rng = random.Random(1)
    obstacles = [
        {"shape": "rectangle", "center": [rng.uniform(0, 9), rng.uniform(1, 8)],
         "size": [rng.uniform(0.1, 0.5), rng.uniform(0.1, 0.5)],
         "angle": rng.uniform(0, 3), "clearance": 0.1, "weight": 0}
        for _ in range(100)
    ]
    solver = {"time_limit_ms": budget_ms, "max_starts": 32}
    if not search:
        solver["multi_start"] = False
    return {"horizon": 10000, "dt": 0.0005, "obstacles": obstacles, "solver": solver}


def server_timing(res: requests.Response) -> dict:
    out = {}
    for metric in res.headers["server-timing"].split(", "):
        name, dur = metric.split(";dur=")
        out[name] = float(dur)
    return out


def overruns(url: str, runs: int) -> None:
    cases = [("points, search", points(445), 445)]
    for budget in (1, 100, 300, 1000):
        cases.append(("rectangles, search", rectangles(budget, True), budget))
        cases.append(("rectangles, single", rectangles(budget, False), budget))
    print(f"{'problem':<20} {'budget':>7} {'encoding':<9} "
          f"{'overrun min / median / p90 / max (ms)':<40} within promise  starts")
    for name, doc, budget in cases:
        for gzip in (False, True):
            headers = {"accept-encoding": "gzip" if gzip else "identity"}
            late, starts, refused = [], [], []
            for _ in range(runs):
                res = requests.post(url + "/solve", json=doc, headers=headers, timeout=60)
                if res.status_code != 200:
                    # A budget too small to start in: 503 expired-in-queue.
                    refused.append(res.json()["type"].rsplit(":", 1)[-1])
                    continue
                late.append(sum(server_timing(res).values()) - budget)
                starts.append(len(res.json()["starts"]))
            if not late:
                print(f"{name:<20} {budget:>5}ms refused: {refused}")
                continue
            late.sort()
            promise = max(0.05 * budget, 5.0)
            within = sum(x <= promise for x in late)
            p90 = late[int(0.9 * (len(late) - 1))]
            print(f"{name:<20} {budget:>5}ms {'gzip' if gzip else 'identity':<9} "
                  f"{late[0]:8.2f} / {statistics.median(late):8.2f} / {p90:8.2f} / {late[-1]:8.2f}"
                  f"      {within:>2}/{len(late)}       {min(starts)}-{max(starts)}"
                  + (f"  (503: {', '.join(refused)})" if refused else ""))


def cancellations(binary: str, runs: int) -> None:
    body = json.dumps(rectangles(10_000, True)).encode()
    rng = random.Random(2)
    waits = []
    with serving(binary, "--workers", "1", "--queue-capacity", "4") as (url, _):
        port = int(url.rsplit(":", 1)[1])
        for _ in range(runs):
            s = socket.create_connection(("127.0.0.1", port))
            s.sendall(b"POST /solve HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                      b"Content-Length: %d\r\n\r\n" % len(body) + body)
            time.sleep(rng.uniform(0.05, 0.4))
            s.close()
            res = requests.post(url + "/solve", json={"solver": {"multi_start": False}}, timeout=60)
            res.raise_for_status()
            waits.append(server_timing(res)["queue"])
    waits.sort()
    print(f"\nclient gone -> worker free (1 worker, 100 rectangles, N = 10000, {runs} runs): "
          f"min / median / max {waits[0]:.2f} / {statistics.median(waits):.2f} / {waits[-1]:.2f} ms")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("binary")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    with serving(args.binary, "--workers", str(args.workers)) as (url, _):
        overruns(url, args.runs)
    cancellations(args.binary, args.runs)


if __name__ == "__main__":
    main()
