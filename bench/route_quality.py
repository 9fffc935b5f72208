"""Solution quality of the search over routes, against IPOPT's best of several starts.

What it measures
    iLQR returns the local optimum nearest its start; with obstacles there
    is one per way around them. This benchmark builds a fixed set of
    problems (a seeded random generator: both models, one to five obstacles
    near the straight path, some hard) and solves each

      * with this project's default (the search, `solver.multi_start`
        true) and with a single local solve (`multi_start: false`), through
        the release binary's `solve` command;
      * with IPOPT (bench/casadi_ipopt.py's transcription) from several
        starts: the rest controls' rollout, the straight line from the
        initial to the goal position, and for every obstacle near the
        straight line a path through a point beside it on either side. The
        cheapest answer that IPOPT solved (and that meets the hard
        constraints to 1e-6) is the reference.

    It reports, per problem and in all, the relative gap of each of ours to
    the reference, the share within 1e-3, the worst gap, and how often the
    search is worse than the single solve (never, by construction: the
    single solve is its first start).

Usage
    .venv-bench/bin/python bench/route_quality.py [--problems 24] [--seed 35]
        [--binary target/release/ilqr-service] [--json out.json]

    The IPOPT solves take most of the time (a minute or two at 24 problems).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import casadi_ipopt as ci  # noqa: E402

GAP = 1e-3


def quadrotor_problem(rng: random.Random) -> dict:
    """The seed's quadrotor (Euler, 0.05 s x 100, its weights) from a start
    on the x axis to a goal about 9 m north, obstacles along the way."""
    start = [rng.uniform(0.0, 8.0), 0.0]
    goal = [rng.uniform(0.0, 8.0), rng.uniform(7.0, 10.0)]
    obstacles = []
    count = rng.randint(1, 5)
    hard = rng.random() < 0.3
    for j in range(count):
        t = (j + 1) / (count + 1) + rng.uniform(-0.05, 0.05)
        off = rng.uniform(-1.0, 1.0)
        c = along(start, goal, t, off)
        if hard and j == 0:
            obstacles.append({"shape": "circle", "center": c, "radius": rng.uniform(0.3, 0.8),
                              "weight": 0.0, "clearance": 0.2})
        else:
            obstacles.append({"center": c, "weight": rng.choice([200.0, 500.0, 1000.0])})
    problem = {
        "initial_state": [start[0], start[1], 0, 0, 0, 0],
        "goal_state": [goal[0], goal[1], 0, 0, 0, 0],
        "obstacles": obstacles,
        "output": {"gains": False, "trace": False},
    }
    if rng.random() < 0.3:
        problem["constraints"] = {"control": {"lower": [0, 0], "upper": [20, 20]}}
    return problem


def unicycle_problem(rng: random.Random) -> dict:
    """The unicycle's default (0.1 s x 60) to a goal 3-5 m away, obstacles
    along the way, soft circles or hard ones."""
    goal = [rng.uniform(3.0, 5.0), rng.uniform(-1.0, 1.0)]
    obstacles = []
    count = rng.randint(1, 5)
    for j in range(count):
        t = (j + 1) / (count + 1) + rng.uniform(-0.05, 0.05)
        c = along([0.0, 0.0], goal, t, rng.uniform(-0.3, 0.3))
        if rng.random() < 0.3:
            obstacles.append({"shape": "circle", "center": c, "radius": rng.uniform(0.1, 0.3),
                              "weight": 0.0, "clearance": 0.05})
        else:
            obstacles.append({"center": c, "weight": rng.choice([5.0, 10.0, 20.0])})
    return {
        "model": {"type": "unicycle"},
        "dt": 0.1,
        "horizon": 60,
        "initial_state": [0, 0, 0],
        "goal_state": [goal[0], goal[1], 0],
        "weights": {"state": [0, 0, 0], "control": [1, 1], "terminal": [1000, 1000, 1000]},
        "obstacles": obstacles,
        "output": {"gains": False, "trace": False},
    }


def along(a, b, t, off):
    """The point a fraction t from a to b, moved off the line by `off` m
    (positive: to the left, facing b)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    n = math.hypot(dx, dy)
    return [round(a[0] + t * dx - off * dy / n, 3), round(a[1] + t * dy + off * dx / n, 3)]


def ours(binary: str, problem: dict, multi_start: bool) -> dict:
    """Solve with the release binary's CLI; the result JSON."""
    body = dict(problem)
    body["solver"] = dict(problem.get("solver", {}), multi_start=multi_start)
    with tempfile.TemporaryDirectory() as d:
        src, out = os.path.join(d, "p.json"), os.path.join(d, "r.json")
        with open(src, "w") as fh:
            json.dump(body, fh)
        subprocess.run([binary, "solve", src, "-o", out], check=True, stdout=subprocess.DEVNULL)
        with open(out) as fh:
            return json.load(fh)


def path_guess(p: ci.Problem, waypoints: list) -> tuple:
    """States along straight segments through `waypoints` at constant speed,
    arriving at 60% of the horizon and holding there; rest controls."""
    n = p.horizon
    pts = np.array(waypoints, dtype=float)
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    total = float(seg.sum())
    arrive = max(1, int(0.6 * n))
    xs = np.zeros((n + 1, p.nx))
    for k in range(n + 1):
        s = min(k / arrive, 1.0) * total
        i = 0
        while i < len(seg) - 1 and s > seg[i]:
            s -= seg[i]
            i += 1
        f = 0.0 if seg[i] == 0 else min(s / seg[i], 1.0)
        xs[k, 0:2] = pts[i] + f * (pts[i + 1] - pts[i])
    xs[0] = p.x0
    vel = np.diff(xs[:, 0:2], axis=0) / p.dt
    if p.model == "unicycle":
        heading = np.arctan2(vel[:, 1], vel[:, 0])
        xs[1:, 2] = heading
        us = np.zeros((n, 2))
        us[:, 0] = np.linalg.norm(vel, axis=1)
    else:
        xs[1:, 3:5] = vel
        us = np.tile(p.rest_controls(), (n, 1)).astype(float)
    if p.has_control_bounds():
        us = np.clip(us, *p.control_bounds())
    return xs, us


def ipopt_starts(p: ci.Problem) -> list:
    """(label, x_guess, u_guess): rest rollout, straight line, and a point
    beside each obstacle near the line on either side."""
    us = np.tile(p.rest_controls(), (p.horizon, 1)).astype(float)
    if p.has_control_bounds():
        us = np.clip(us, *p.control_bounds())
    out = [("rest", ci.rollout(p, us), us)]
    a, b = np.array(p.x0[:2], dtype=float), np.array(p.goal[:2], dtype=float)
    out.append(("straight", *path_guess(p, [a, b])))
    d = (b - a) / np.linalg.norm(b - a)
    left = np.array([-d[1], d[0]])
    for j, o in enumerate(p.obstacles):
        c = np.array(o.center, dtype=float)
        reach = (o.radius or 0.0) + (o.clearance or 0.0)
        beside = reach + max(0.5, math.log1p(o.weight) / 2.0 if o.weight > 0 else 0.5)
        for name, s in (("left", 1.0), ("right", -1.0)):
            out.append((f"{name} of {j}", *path_guess(p, [a, c + s * beside * left, b])))
    return out


def ipopt_best(p: ci.Problem) -> tuple:
    """The cheapest IPOPT answer over the starts, its start, and the time
    of each solve (ms)."""
    best, label, times = math.inf, None, []
    for name, xg, ug in ipopt_starts(p):
        opti, X, U = ci.build_nlp(p, xg, ug)
        t0 = time.perf_counter()
        try:
            sol = opti.solve()
        except RuntimeError:
            times.append((time.perf_counter() - t0) * 1e3)
            continue
        times.append((time.perf_counter() - t0) * 1e3)
        us = np.array(sol.value(U), dtype=float).reshape(p.nu, p.horizon).T
        if p.has_control_bounds():
            us = np.clip(us, *p.control_bounds())
        xs = ci.rollout(p, us)
        if ci.constraint_violation(p, xs) > 1e-6:
            continue
        cost = ci.total_cost(p, xs, us)
        if cost < best:
            best, label = cost, name
    return best, label, times


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", type=int, default=24)
    ap.add_argument("--seed", type=int, default=35)
    ap.add_argument("--binary", default="target/release/ilqr-service")
    ap.add_argument("--json", help="write every problem and figure here")
    args = ap.parse_args()

    rng = random.Random(args.seed)
    rows = []
    for i in range(args.problems):
        problem = quadrotor_problem(rng) if i % 2 == 0 else unicycle_problem(rng)
        with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as fh:
            json.dump(problem, fh)
            path = fh.name
        try:
            p = ci.load_problem(path)
        finally:
            os.unlink(path)
        searched = ours(args.binary, problem, True)
        single = ours(args.binary, problem, False)
        ref, ref_label, ipopt_ms = ipopt_best(p)
        gap = (searched["cost"] - ref) / ref
        single_gap = (single["cost"] - ref) / ref
        cpu = sum(s["solve_time_ms"] for s in searched["starts"])
        chosen = next(s["label"] for s in searched["starts"] if s["chosen"])
        rows.append({
            "problem": problem, "model": problem.get("model", {}).get("type", "quadrotor_2d"),
            "obstacles": len(problem["obstacles"]),
            "hard": "constraints" in problem or any("clearance" in o for o in problem["obstacles"]),
            "reference": ref, "reference_start": ref_label,
            "searched": searched["cost"], "searched_status": searched["status"],
            "single": single["cost"], "single_status": single["status"],
            "gap": gap, "single_gap": single_gap, "starts": len(searched["starts"]),
            "chosen": chosen, "cpu_ms": cpu, "wall_ms": searched["solve_time_ms"],
            "single_ms": single["solve_time_ms"], "ipopt_ms": ipopt_ms,
        })
        r = rows[-1]
        print(f"{i:2d} {r['model']:12s} obs={r['obstacles']} hard={int(r['hard'])} "
              f"ref={ref:12.4f} ({ref_label:10s}) search={r['searched']:12.4f} [{r['searched_status']}] "
              f"gap={gap:+.2e} single_gap={single_gap:+.2e} starts={r['starts']} chosen={chosen!r} "
              f"cpu={cpu:.2f}ms single={r['single_ms']:.2f}ms ipopt={statistics_median(ipopt_ms):.0f}ms",
              flush=True)

    within = sum(1 for r in rows if r["gap"] <= GAP)
    worse = sum(1 for r in rows if r["searched"] > r["single"] * (1 + 1e-9))
    single_within = sum(1 for r in rows if r["single_gap"] <= GAP)
    worst = max(rows, key=lambda r: r["gap"])
    print()
    print(f"search within {GAP:g} of IPOPT's best: {within}/{len(rows)} ({100 * within / len(rows):.0f}%)")
    print(f"single solve within {GAP:g}: {single_within}/{len(rows)} ({100 * single_within / len(rows):.0f}%)")
    print(f"worst gap: {worst['gap']:+.3e} (problem {rows.index(worst)})")
    print(f"search worse than the single solve: {worse}")
    cpu_ratio = [r["cpu_ms"] / r["single_ms"] for r in rows]
    print(f"search CPU / single solve: median {np.median(cpu_ratio):.2f}, max {max(cpu_ratio):.2f}")
    ipopt_ratio = [statistics_median(r["ipopt_ms"]) / r["wall_ms"] for r in rows]
    print(f"IPOPT (one solve, median over its starts) / search wall: median {np.median(ipopt_ratio):.1f}x, "
          f"min {min(ipopt_ratio):.2f}x")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


def statistics_median(xs):
    return float(np.median(xs)) if xs else math.nan


if __name__ == "__main__":
    sys.exit(main())
