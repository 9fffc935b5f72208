#!/usr/bin/env python3
"""The Python client in a receding-horizon loop: round trip against the service's own time.

Starts `BINARY serve --workers 1`, then re-solves the seed problem CALLS
times through `ilqr_client.Client(compress=False, retries=0)`, each from
the previous answer's second state, warm-started with its
`shifted_controls()`, lean (no gains, no trace); every 50 calls it starts
again from the seed, so that the loop does not settle at the goal. Prints
the median and p90 round trip (`time.perf_counter` around `solve`) after
100 warm-up calls, and the median of the service's queue + solve + encode
from `Server-Timing`: the difference is `requests`, JSON and building the
result in Python. Whether answers are decoded with orjson (the client's
`fast` extra) or the standard library's `json` is printed too;
`--no-orjson` forces the latter.

    .venv/bin/python bench/client_loop.py target/release/ilqr-service [--calls 600] [--no-orjson]

Needs the client installed (`pip install -e 'clients/python[fast]'`; the
repository's .venv has it).
"""

import argparse
import json
import statistics
import time

import ilqr_client.client as client_module
from _serve import serving
from ilqr_client import Client

LEAN = {"gains": False, "trace": False}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("binary")
    parser.add_argument("--calls", type=int, default=600)
    parser.add_argument("--no-orjson", action="store_true")
    args = parser.parse_args()
    if args.no_orjson:
        client_module._loads = json.loads
    decoder = getattr(client_module._loads, "__module__", "?")
    with serving(args.binary, "--workers", "1") as (url, _pid):
        with Client(url, compress=False, retries=0) as client:
            # The seed's single solve: the re-solves are warm starts, which
            # do not search either.
            result = client.solve({"output": LEAN, "solver": {"multi_start": False}})
            trips, served = [], []
            for k in range(args.calls):
                problem = {
                    "initial_state": result.states[1],
                    "initial_controls": result.shifted_controls(),
                    "output": LEAN,
                }
                started = time.perf_counter()
                answer = client.solve(problem)
                trips.append(time.perf_counter() - started)
                timing = answer.server_timing or {}
                served.append(sum(timing.get(part, 0.0) for part in ("queue", "solve", "encode")))
                result = client.solve({"output": LEAN, "solver": {"multi_start": False}}) if k % 50 == 49 else answer
    trips, served = trips[100:], served[100:]
    trips.sort()
    print(
        f"decoder {decoder}: round trip median {statistics.median(trips) * 1e3:.3f} ms, "
        f"p90 {trips[int(0.9 * len(trips))] * 1e3:.3f} ms; service (queue + solve + encode) "
        f"median {statistics.median(served):.3f} ms; {len(trips)} calls"
    )


if __name__ == "__main__":
    main()
