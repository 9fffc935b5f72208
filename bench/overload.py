#!/usr/bin/env python3
"""What a small server answers under 4x and 20x overload by clients that ignore Retry-After.

Starts `BINARY serve --workers 2 --queue-capacity 4` and, for each factor F,
runs F x 6 clients (6: the server's admission slots, workers plus queue)
for SECONDS each. Every client posts the same problem with a 500 ms budget
over a keep-alive connection and, whatever the answer (a 503 included),
posts again at once. The clients are asyncio streams in one thread, with
HTTP/1.1 written and read by hand: with `requests` in a thread each, the
clients themselves (their GIL, their CPU) added seconds to the latencies
measured at 20x. The problem is the seed scenario over a longer horizon
(`--horizon`, default 8000 steps at the seed's dt: 400 s of flight instead
of 5; gains and trace left out of the answer), which converges on its own
in about 300 ms (86 iterations), 60% of the budget, on an idle core of this
2-core machine: two workers then finish at most about 7 solves a second,
and a solve fourth in the queue would wait past its budget, while the
clients, answered 503 at once, ask for thousands. (`--horizon 10000`
takes about 770 ms, more than the budget: every solve ends `time_limit`.)

Prints, per factor: the answers by status, the share of 200s whose solve
ran at least one iteration, the p50 / p99 / max latency of the 200s (from
sending the request to having the whole answer, as the client measures it
on this same 2-core machine, and as the server does: queue, solve and
encode from Server-Timing), the 503s by problem type and reason, and the
server's peak RSS (VmHWM) at the end of the run.

    .venv/bin/python bench/overload.py BINARY [BINARY ...] [--factors 4 20] [--seconds 20] [--nice N]

With `--nice 10` the clients run below the server's priority, closer to
clients on other machines: at the same priority they take a core of the
two, and their own scheduling shows in the latencies they measure.

Needs `requests` (the repository's .venv has it) for the first solve. Only 127.0.0.1 is used;
each run is bounded by --seconds plus the answers still outstanding.
"""

import argparse
import asyncio
import collections
import json
import os
import re
import statistics
import time

import requests
from _serve import serving, vmhwm_mib

WORKERS = 2
QUEUE = 4


def problem(horizon: int, budget_ms: int) -> dict:
    return {
        "horizon": horizon,
        "solver": {"time_limit_ms": budget_ms, "multi_start": False},
        "output": {"gains": False, "trace": False},
    }


def percentile(values: list, p: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(p * len(ordered)))]


ITERATIONS = re.compile(rb'"iterations":(\d+)')
STATUS = re.compile(rb'"status":"([a-z_]+)"')
PROBLEM_TYPE = re.compile(rb'"type":"urn:ilqr-service:([a-z-]+)"')


async def exchange(reader, writer, request: bytes):
    """One request on a keep-alive connection: (HTTP status, headers, body,
    when its head had arrived)."""
    writer.write(request)
    head = await reader.readuntil(b"\r\n\r\n")
    headed = time.perf_counter()
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split()[1])
    headers = {}
    for line in lines[1:]:
        if ":" in line:
            name, value = line.split(":", 1)
            headers[name.strip().lower()] = value.strip()
    body = await reader.readexactly(int(headers.get("content-length", "0")))
    return status, headers, body, headed


async def clients(port: int, count: int, seconds: float, body: bytes) -> tuple:
    # A transport reads at most 256 KiB per turn of the event loop by
    # default, so a 1.2 MB answer took five turns, each behind every other
    # client's 503: up to hundreds of ms of the latency measured here were
    # the clients' own. (A private attribute: a benchmark's measurement
    # tweak, not an API.)
    asyncio.selector_events._SelectorSocketTransport.max_size = 8 << 20
    request = (f"POST /solve HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
               f"Content-Length: {len(body)}\r\n\r\n").encode() + body
    ok = []  # (latency ms, Server-Timing parts in ms, iterations, solve status)
    refused = collections.Counter()
    other = collections.Counter()
    stop = time.monotonic() + seconds

    async def client() -> None:
        reader = writer = None
        while time.monotonic() < stop:
            if writer is None:
                reader, writer = await asyncio.open_connection("127.0.0.1", port)
            sent = time.perf_counter()
            try:
                status, headers, answer, headed = await exchange(reader, writer, request)
            except (OSError, asyncio.IncompleteReadError, ValueError) as e:
                other[type(e).__name__] += 1
                writer.close()
                writer = None
                continue
            took = (time.perf_counter() - sent) * 1e3
            if status == 200:
                timing = dict(m.split(";dur=") for m in headers["server-timing"].split(", "))
                parts = {k: float(v) for k, v in timing.items()}
                parts["head"] = (headed - sent) * 1e3
                ok.append((took, parts, int(ITERATIONS.search(answer).group(1)),
                           STATUS.search(answer).group(1).decode()))
            elif status == 503:
                # Classified from the bytes: a JSON parse per 503, thousands
                # a second, took the clients' time from reading the 200s.
                kind = PROBLEM_TYPE.search(answer).group(1).decode()
                why = ("queue full" if b"queue is full" in answer
                       else "expected wait" if b"solves queued ahead" in answer
                       else "")
                refused[f"{kind} ({why})" if why else kind] += 1
            else:
                other[str(status)] += 1
            if headers.get("connection") == "close":
                writer.close()
                writer = None
        if writer is not None:
            writer.close()

    await asyncio.gather(*(client() for _ in range(count)))
    return ok, refused, other


def run(binary: str, factor: int, seconds: float, body: dict, nice: int) -> str:
    count = factor * (WORKERS + QUEUE)
    encoded = json.dumps(body).encode()
    with serving(binary, "--workers", str(WORKERS), "--queue-capacity", str(QUEUE)) as (url, pid):
        # One solve first, so that the run starts with a measured service
        # time rather than with a cold cache and an empty estimate.
        requests.post(url + "/solve", json=body, timeout=30)
        port = int(url.rsplit(":", 1)[1])
        # The clients (this process) at a lower priority than the server,
        # as clients on other machines would be; the server runs at ours.
        before = os.nice(0)
        os.nice(nice)
        try:
            ok, refused, other = asyncio.run(clients(port, count, seconds, encoded))
        finally:
            # Lowering a niceness back needs privileges; where it fails,
            # later runs keep this one's.
            try:
                os.setpriority(os.PRIO_PROCESS, 0, before)
            except PermissionError:
                pass
        hwm = vmhwm_mib(pid)
    lines = [f"{binary}, {factor}x overload ({count} clients at nice {nice}, {seconds:g} s):"]
    total = len(ok) + sum(refused.values()) + sum(other.values())
    lines.append(f"  answers {total}: 200 = {len(ok)}, 503 = {sum(refused.values())}, other = {dict(other)}")
    if ok:
        iterated = sum(1 for _, _, iterations, _ in ok if iterations >= 1)
        statuses = collections.Counter(status for _, _, _, status in ok)
        lines.append(f"  200s with >= 1 iteration: {iterated} of {len(ok)} ({100 * iterated / len(ok):.1f}%); "
                     f"solve statuses {dict(statuses)}")
        for name, values in (
            ("client", [t for t, _, _, _ in ok]),
            ("client, to the answer's head", [p["head"] for _, p, _, _ in ok]),
            ("server", [p["queue"] + p["solve"] + p["encode"] for _, p, _, _ in ok]),
            ("  of which queue + solve", [p["queue"] + p["solve"] for _, p, _, _ in ok]),
            ("  of which encode", [p["encode"] for _, p, _, _ in ok]),
        ):
            lines.append(f"  latency of 200s, {name} p50 / p99 / max: {statistics.median(values):.0f} / "
                         f"{percentile(values, 0.99):.0f} / {max(values):.0f} ms")
    lines.append(f"  503s by type: {dict(refused)}")
    lines.append(f"  server peak RSS (VmHWM): {hwm:.1f} MiB")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("binaries", nargs="+")
    parser.add_argument("--factors", type=int, nargs="+", default=[4, 20])
    parser.add_argument("--seconds", type=float, default=20)
    parser.add_argument("--budget-ms", type=int, default=500)
    parser.add_argument("--horizon", type=int, default=8000)
    parser.add_argument("--nice", type=int, default=0,
                        help="run the clients this much below the server's priority (0 to 19)")
    args = parser.parse_args()
    body = problem(args.horizon, args.budget_ms)
    for factor in args.factors:
        for binary in args.binaries:
            print(run(binary, factor, args.seconds, body, args.nice), flush=True)


if __name__ == "__main__":
    main()
