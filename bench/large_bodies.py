#!/usr/bin/env python3
"""Latency of small requests while other clients send megabytes of JSON.

For each binary: starts `BINARY serve --bind 127.0.0.1:PORT --workers 2`
(one runtime thread, the default on this machine), then for SECONDS has
four clients post a 3.8 MB invalid body (`{"foo": [0, 0, ...]}`, 1.9
million numbers, answered 422) back to back, while a fifth times
`GET /healthz` and a lean seed solve every 20 ms. Prints the large bodies
answered, the percentiles of both probes and the server's peak RSS
(VmHWM). The binaries take turns, so a change in the machine's speed hits
them alike.

    .venv/bin/python bench/large_bodies.py [--seconds S] [--rounds R] BINARY [BINARY ...]

Needs `requests` (the repository's .venv has it).
"""

import argparse
import statistics
import threading
import time

import requests
from _serve import serving, vmhwm_mib

BODY = ('{"foo":[' + ",".join(["0"] * 1_900_000) + "]}").encode()
LEAN = {"solver": {"multi_start": False}, "output": {"gains": False, "trace": False}}


def percentile(xs, p):
    return sorted(xs)[int(p * (len(xs) - 1))] * 1e3


def round_of(binary: str, seconds: float) -> str:
    with serving(binary, "--workers", "2") as (url, pid):
        stop = time.time() + seconds
        big = []

        def hammer():
            with requests.Session() as s:
                while time.time() < stop:
                    t = time.perf_counter()
                    r = s.post(url + "/solve", data=BODY, headers={"content-type": "application/json"})
                    big.append((r.status_code, time.perf_counter() - t))

        senders = [threading.Thread(target=hammer) for _ in range(4)]
        for t in senders:
            t.start()
        time.sleep(0.5)
        health, solve = [], []
        with requests.Session() as s:
            while time.time() < stop - 0.5:
                t = time.perf_counter()
                s.get(url + "/healthz").raise_for_status()
                health.append(time.perf_counter() - t)
                t = time.perf_counter()
                s.post(url + "/solve", json=LEAN).raise_for_status()
                solve.append(time.perf_counter() - t)
                time.sleep(0.02)
        for t in senders:
            t.join()
        hwm = vmhwm_mib(pid)
    statuses = sorted({c for c, _ in big})
    return (
        f"{len(big)} large bodies answered {statuses}, median "
        f"{statistics.median(d for _, d in big) * 1e3:.0f} ms | "
        f"/healthz n={len(health)} p50 {percentile(health, .5):.1f} p90 {percentile(health, .9):.1f} "
        f"max {max(health) * 1e3:.1f} ms | "
        f"seed solve p50 {percentile(solve, .5):.1f} p90 {percentile(solve, .9):.1f} "
        f"max {max(solve) * 1e3:.1f} ms | VmHWM {hwm:.0f} MiB"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("binaries", nargs="+")
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--rounds", type=int, default=2)
    args = parser.parse_args()
    for r in range(args.rounds):
        for binary in args.binaries:
            print(f"round {r + 1} {binary}: {round_of(binary, args.seconds)}", flush=True)


if __name__ == "__main__":
    main()
