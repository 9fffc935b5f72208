#!/usr/bin/env python3
"""How soon, and with how much memory, solves whose budget runs out in the queue are answered.

Starts `BINARY serve --workers 1 --queue-capacity Q`, occupies the worker
with a 6 s solve (N = 10000, dt = 0.0005, 100 distant obstacles,
tolerance 0: the problem tests/http.rs calls `slow`), then posts Q copies
of that problem at once with `time_limit_ms: 1` and gains and trace in the
answer. Prints the statuses, when the last was answered, and the server's
peak RSS (VmHWM).

    .venv/bin/python bench/queued_budgets.py BINARY [BINARY ...] [--queue Q ...]

Needs `requests` (the repository's .venv has it).
"""

import argparse
import threading
import time

import requests
from _serve import serving, vmhwm_mib


def slow(ms: int, full: bool) -> dict:
    return {
        "horizon": 10000,
        "dt": 0.0005,
        "obstacles": [{"center": [1000.0 + j, 1000.0], "weight": 1.0} for j in range(100)],
        "solver": {"tolerance": 0, "max_iterations": 10000, "time_limit_ms": ms},
        "output": {"gains": full, "trace": full},
    }


def run(binary: str, queue: int) -> str:
    with serving(binary, "--workers", "1", "--queue-capacity", str(queue)) as (url, pid):
        busy = threading.Thread(target=lambda: requests.post(url + "/solve", json=slow(6000, False)))
        busy.start()
        time.sleep(0.3)
        answers = []

        def one() -> None:
            answers.append(requests.post(url + "/solve", json=slow(1, True)).status_code)

        clients = [threading.Thread(target=one) for _ in range(queue)]
        start = time.perf_counter()
        for c in clients:
            c.start()
        for c in clients:
            c.join()
        took = time.perf_counter() - start
        busy.join()
        hwm = vmhwm_mib(pid)
    return f"{queue} expired: statuses {sorted(set(answers))}, the last answered after {took:.2f} s; VmHWM {hwm:.0f} MiB"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("binaries", nargs="+")
    parser.add_argument("--queue", type=int, nargs="+", default=[16, 100])
    args = parser.parse_args()
    for queue in args.queue:
        for binary in args.binaries:
            print(f"{binary}: {run(binary, queue)}", flush=True)


if __name__ == "__main__":
    main()
