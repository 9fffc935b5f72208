"""Solution quality of the search over routes, against IPOPT's best of several starts.

What it measures
    iLQR returns the local optimum nearest its start; with obstacles there
    is one per way around them. This benchmark builds a fixed set of
    problems (seeded random generators) in groups, and solves each

      * with this project's default (the search, `solver.multi_start`
        true) and with a single local solve (`multi_start: false`), through
        the release binary's `solve` command;
      * with IPOPT (bench/casadi_ipopt.py's transcription) from several
        starts: the rest controls' rollout, the straight line from the
        initial to the goal position, for every obstacle a path through a
        point beside it on either side, and, for a problem of 2 to
        --side-combinations obstacles, a path through a point beside every
        obstacle for each combination of sides. A resampled problem (below)
        is also started from the coarse problem's IPOPT answers, the
        cheapest of each route, each control held over the finer steps and
        the states interpolated. The cheapest answer that IPOPT solved (and
        that meets the hard constraints to 1e-6) is the reference.

    The groups, by (model, variant):

      * "base" (--problems, alternating models, `random.Random(--seed)`):
        the seed's quadrotor to a goal about 9 m north, 1-5 obstacles near
        the straight path (soft points, in a third of the problems one a
        hard circle), a third with thrust in [0, 20]; the unicycle to a
        goal 3-5 m away, 1-5 soft points or hard circles.
      * "dt/4" and "dt/10": the first --fine quadrotor problems of the base
        set, the same flight resampled: dt divided by 4 (10), the horizon
        multiplied by it, weights unchanged (so costs are about 4 (10)
        times the base's), as a user who changes only dt would. Does the
        search still reach the best route?
      * "constrained" (--constrained problems, their own generator): the
        quadrotor flight with thrust in [0, 12, 15 or 20], a tilt bound
        |theta| <= 0.35 or 0.5, and 1-2 hard shapes (circles, rotated
        rectangles) near the straight path, most with no soft term.

    It reports, per problem, the relative gap of each of ours to the
    reference and the side each answer passes each obstacle on (L or R,
    facing along the path: the sign of the angle that the vector from the
    obstacle's centre to the position sweeps from x_0 to x_N); in all, as
    before, the share within 1e-3 (an answer that misses a hard
    constraint by more than 1e-6 is not within), the worst gap and how
    often the search is worse than the single solve (never, by
    construction: the single solve is its first start); and per group the
    share within 1e-3 and the worst gap, and every miss with its sides
    against IPOPT's.

Usage
    .venv-bench/bin/python bench/route_quality.py [--problems 24] [--seed 35]
        [--groups base,dt/4,dt/10,constrained] [--fine 6] [--constrained 8]
        [--side-combinations 3] [--binary target/release/ilqr-service]
        [--json out.json]

    `--groups base --side-combinations 0` is the original benchmark (a
    minute or two); every group, the default, took 6.5 minutes on two
    shared cores, most of it IPOPT at dt/4 and dt/10. `--groups
    constrained` or `--groups dt/4 --fine 2` is a quick look at one group.
    Run it niced on a shared machine.
"""

from __future__ import annotations

import argparse
import copy
import itertools
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
import casadi_ipopt as ci

GAP = 1e-3
# Hard constraints an answer may miss by and still count (IPOPT's and ours).
FEASIBLE = 1e-6
GROUPS = ("base", "dt/4", "dt/10", "constrained")
FACTORS = {"dt/4": 4, "dt/10": 10}


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


def constrained_problem(rng: random.Random) -> dict:
    """The quadrotor flight of quadrotor_problem under the kinds of
    constraint a vehicle has: thrust in [0, 12, 15 or 20] N per rotor
    (hover is 4.9), |theta| <= 0.35 or 0.5 rad, and one or two hard
    circles or rotated rectangles near the straight path, most with no
    soft term. Each shape keeps 0.3 m clear of the start and the goal."""
    start = [rng.uniform(0.0, 8.0), 0.0]
    goal = [rng.uniform(0.0, 8.0), rng.uniform(7.0, 10.0)]
    obstacles = []
    count = rng.randint(1, 2)
    for j in range(count):
        while True:
            t = (j + 1) / (count + 1) + rng.uniform(-0.1, 0.1)
            c = along(start, goal, t, rng.uniform(-1.0, 1.0))
            o = {"center": c, "weight": rng.choice([0.0, 0.0, 1000.0]),
                 "clearance": rng.choice([0.0, 0.2, 0.5])}
            if rng.random() < 0.5:
                o.update(shape="circle", radius=round(rng.uniform(0.5, 2.0), 3))
                reach = o["radius"]
            else:
                size = [round(rng.uniform(0.5, 2.0), 3), round(rng.uniform(0.5, 2.0), 3)]
                o.update(shape="rectangle", size=size, angle=round(rng.uniform(-0.6, 0.6), 3))
                reach = math.hypot(*size) / 2.0
            reach += o["clearance"] + 0.3
            if min(math.dist(c, start), math.dist(c, goal)) > reach:
                break
        obstacles.append(o)
    upper, tilt = rng.choice([12.0, 15.0, 20.0]), rng.choice([0.35, 0.5])
    return {
        "initial_state": [start[0], start[1], 0, 0, 0, 0],
        "goal_state": [goal[0], goal[1], 0, 0, 0, 0],
        "obstacles": obstacles,
        "constraints": {
            "control": {"lower": [0, 0], "upper": [upper, upper]},
            "state": {"lower": [None, None, -tilt, None, None, None],
                      "upper": [None, None, tilt, None, None, None]},
        },
        "output": {"gains": False, "trace": False},
    }


def finer(problem: dict, factor: int) -> dict:
    """`problem` with dt divided by `factor` and the horizon multiplied by
    it (the same flight, sampled finer); weights unchanged."""
    coarse = ci.Problem()  # the defaults, where the problem is silent
    body = copy.deepcopy(problem)
    body["dt"] = problem.get("dt", coarse.dt) / factor
    body["horizon"] = problem.get("horizon", coarse.horizon) * factor
    return body


def along(a, b, t, off):
    """The point a fraction t from a to b, moved off the line by `off` m
    (positive: to the left, facing b)."""
    dx, dy = b[0] - a[0], b[1] - a[1]
    n = math.hypot(dx, dy)
    return [round(a[0] + t * dx - off * dy / n, 3), round(a[1] + t * dy + off * dx / n, 3)]


def load(problem: dict) -> ci.Problem:
    """casadi_ipopt's reading of the request `problem`."""
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as fh:
        json.dump(problem, fh)
        path = fh.name
    try:
        return ci.load_problem(path)
    finally:
        os.unlink(path)


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


def sides(p: ci.Problem, xs) -> str:
    """For each obstacle, the side the positions xs[:, 0:2] pass it on,
    facing along the path: R when the vector from its centre to the
    position turns counter-clockwise from x_0 to x_N (the obstacle is on
    the path's left), else L."""
    xs = np.asarray(xs, dtype=float)
    out = ""
    for o in p.obstacles:
        angle = np.unwrap(np.arctan2(xs[:, 1] - o.center[1], xs[:, 0] - o.center[0]))
        out += "R" if angle[-1] > angle[0] else "L"
    return out


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


def ipopt_starts(p: ci.Problem, combinations: int = 0, spreads: tuple = (1.0,)) -> list:
    """(label, x_guess, u_guess): the rest rollout, the straight line, a
    point beside each obstacle on either side, and with 2 to
    `combinations` obstacles a point beside every one of them (in their
    order along the line) for each combination of sides, labelled by the
    sides ("sides LR": left of the first, right of the second). A via-point
    is `spread` times the default distance beside the obstacle, for each
    spread (labels "x2" and so on for the others)."""
    us = np.tile(p.rest_controls(), (p.horizon, 1)).astype(float)
    if p.has_control_bounds():
        us = np.clip(us, *p.control_bounds())
    out = [("rest", ci.rollout(p, us), us)]
    a, b = np.array(p.x0[:2], dtype=float), np.array(p.goal[:2], dtype=float)
    out.append(("straight", *path_guess(p, [a, b])))
    d = (b - a) / np.linalg.norm(b - a)
    left = np.array([-d[1], d[0]])
    beside = []  # per obstacle: (centre, distance of its via-points)
    for o in p.obstacles:
        reach = (o.radius or 0.0) + (o.clearance or 0.0)
        beside.append((np.array(o.center, dtype=float),
                       reach + max(0.5, math.log1p(o.weight) / 2.0 if o.weight > 0 else 0.5)))
    order = sorted(range(len(beside)), key=lambda j: float(np.dot(beside[j][0] - a, d)))
    for spread in spreads:
        tag = "" if spread == 1.0 else f" x{spread:g}"
        for j, (c, dist) in enumerate(beside):
            for name, s in (("left", 1.0), ("right", -1.0)):
                out.append((f"{name} of {j}{tag}", *path_guess(p, [a, c + s * spread * dist * left, b])))
        if 2 <= len(beside) <= combinations:
            for signs in itertools.product((1.0, -1.0), repeat=len(beside)):
                via = [beside[j][0] + signs[j] * spread * beside[j][1] * left for j in order]
                label = "".join("L" if s > 0 else "R" for s in signs)
                out.append((f"sides {label}{tag}", *path_guess(p, [a, *via, b])))
    return out


def resampled_starts(coarse: ci.Problem, runs: list, fine: ci.Problem) -> list:
    """(label, x_guess, u_guess) for `fine`, the flight of `coarse` at a
    finer dt: the cheapest feasible IPOPT answer of `coarse` of each route
    (side pattern), each control held over the finer steps, the states
    interpolated in time."""
    factor = fine.horizon // coarse.horizon
    t_coarse = np.arange(coarse.horizon + 1) * coarse.dt
    t_fine = np.arange(fine.horizon + 1) * fine.dt
    routes = {}
    for r in sorted(feasible(runs), key=lambda r: r["cost"]):
        routes.setdefault(r["sides"], r)
    out = []
    for r in routes.values():
        xs = np.column_stack([np.interp(t_fine, t_coarse, r["xs"][:, i]) for i in range(coarse.nx)])
        out.append((f"coarse {r['label']}", xs, np.repeat(r["us"], factor, axis=0)))
    return out


def ipopt_run(p: ci.Problem, label: str, xg: np.ndarray, ug: np.ndarray) -> dict:
    """One IPOPT solve from (xg, ug): its status, whether it solved, the
    cost and constraint violation of the rollout of its (clamped)
    controls, the sides it passes the obstacles on, the solve's wall time
    (ms), and the rollout itself ("xs", "us"). A failed solve reports its
    last iterate."""
    opti, _, U = ci.build_nlp(p, xg, ug)
    t0 = time.perf_counter()
    try:
        sol = opti.solve()
        solved, status, value = True, sol.stats()["return_status"], sol.value
    except RuntimeError:
        solved = False
        status, value = opti.debug.stats().get("return_status", "unknown"), opti.debug.value
    ms = (time.perf_counter() - t0) * 1e3
    us = np.array(value(U), dtype=float).reshape(p.nu, p.horizon).T
    if p.has_control_bounds():
        us = np.clip(us, *p.control_bounds())
    xs = ci.rollout(p, us)
    return {"label": label, "status": status, "solved": solved, "cost": ci.total_cost(p, xs, us),
            "violation": ci.constraint_violation(p, xs), "sides": sides(p, xs), "ms": ms,
            "xs": xs, "us": us}


def ipopt_runs(p: ci.Problem, starts: list) -> list:
    """ipopt_run from each of `starts` ((label, x_guess, u_guess))."""
    return [ipopt_run(p, *s) for s in starts]


def feasible(runs: list) -> list:
    """The runs that IPOPT solved and that meet the hard constraints."""
    return [r for r in runs if r["solved"] and r["violation"] <= FEASIBLE
            and math.isfinite(r["cost"])]


def reference(runs: list) -> dict | None:
    """The cheapest feasible run (the first of those within 1e-9 of the
    least cost, so that a tie names the earliest start), or None."""
    ok = feasible(runs)
    if not ok:
        return None
    least = min(r["cost"] for r in ok)
    return next(r for r in ok if r["cost"] <= least + 1e-9 * abs(least))


def is_within(row: dict, which: str) -> bool:
    """Whether `which` ("searched" or "single") of `row` is within GAP of
    the reference and meets the hard constraints."""
    gap = row["gap" if which == "searched" else "single_gap"]
    return gap <= GAP and row[f"{which}_violation"] <= FEASIBLE


def count_within(rows: list, which: str) -> int:
    return sum(1 for r in rows if is_within(r, which))


def summary(rows: list) -> None:
    """The original benchmark's summary, over `rows`."""
    n = len(rows)
    within, single_within = count_within(rows, "searched"), count_within(rows, "single")
    worse = sum(1 for r in rows if r["searched"] > r["single"] * (1 + 1e-9))
    worst = max(rows, key=lambda r: worst_first(r["gap"]))
    print(f"search within {GAP:g} of IPOPT's best: {within}/{n} ({100 * within / n:.0f}%)")
    print(f"single solve within {GAP:g}: {single_within}/{n} ({100 * single_within / n:.0f}%)")
    print(f"worst gap: {worst['gap']:+.3e} (problem {worst['name']})")
    print(f"search worse than the single solve: {worse}")
    cpu_ratio = [r["cpu_ms"] / r["single_ms"] for r in rows]
    print(f"search CPU / single solve: median {np.median(cpu_ratio):.2f}, max {max(cpu_ratio):.2f}")
    ipopt_ratio = [statistics_median(r["ipopt_ms"]) / r["wall_ms"] for r in rows]
    print(f"IPOPT (one solve, median over its starts) / search wall: median {np.median(ipopt_ratio):.1f}x, "
          f"min {min(ipopt_ratio):.2f}x")


def worst_first(gap: float) -> float:
    """A gap as a sort key: no reference (NaN) counts as the worst."""
    return math.inf if math.isnan(gap) else gap


def worst_gap(rows: list, key: str) -> float:
    """The largest gap `key` of `rows`, NaN if one has no reference."""
    return max((r[key] for r in rows), key=worst_first)


def statistics_median(xs):
    return float(np.median(xs)) if xs else math.nan


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", type=int, default=24, help="base problems, alternating models")
    ap.add_argument("--seed", type=int, default=35)
    ap.add_argument("--groups", default=",".join(GROUPS),
                    help=f"comma-separated variants to run, of {', '.join(GROUPS)} (default all)")
    ap.add_argument("--fine", type=int, default=6,
                    help="quadrotor problems of the base set resampled for dt/4 and dt/10")
    ap.add_argument("--constrained", type=int, default=8, help="problems of the constrained group")
    ap.add_argument("--side-combinations", type=int, default=3,
                    help="start IPOPT from every combination of sides up to this many obstacles")
    ap.add_argument("--binary", default="target/release/ilqr-service")
    ap.add_argument("--json", help="write every problem and figure here")
    args = ap.parse_args()
    groups = args.groups.split(",")
    unknown = sorted(set(groups) - set(GROUPS))
    if unknown:
        ap.error(f"unknown groups {unknown}; choose from {', '.join(GROUPS)}")

    rng = random.Random(args.seed)
    base = [quadrotor_problem(rng) if i % 2 == 0 else unicycle_problem(rng)
            for i in range(args.problems)]
    cases = []  # (name, variant, problem, index of the base problem it resamples)
    if "base" in groups:
        cases += [(str(i), "base", problem, None) for i, problem in enumerate(base)]
    fine = [i for i, problem in enumerate(base) if "model" not in problem][:args.fine]
    for variant, factor in FACTORS.items():
        if variant in groups:
            cases += [(f"{i} {variant}", variant, finer(base[i], factor), i) for i in fine]
    if "constrained" in groups:
        crng = random.Random(f"constrained {args.seed}")
        cases += [(f"c{i}", "constrained", constrained_problem(crng), None)
                  for i in range(args.constrained)]

    solved = {}  # base index: (its ci.Problem, its IPOPT runs), for resampled starts
    rows = []
    for name, variant, problem, i in cases:
        p = load(problem)
        starts = ipopt_starts(p, args.side_combinations)
        if i is not None:
            if i not in solved:
                q = load(base[i])
                solved[i] = (q, ipopt_runs(q, ipopt_starts(q, args.side_combinations)))
            starts += resampled_starts(*solved[i], p)
        runs = ipopt_runs(p, starts)
        if variant == "base":
            solved[int(name)] = (p, runs)
        best = reference(runs)
        ref = best["cost"] if best else math.nan
        searched = ours(args.binary, problem, True)
        single = ours(args.binary, problem, False)
        ipopt_ms = [r["ms"] for r in runs]
        cpu = sum(s["solve_time_ms"] for s in searched["starts"])
        chosen = next(s["label"] for s in searched["starts"] if s["chosen"])
        rows.append({
            "name": name, "variant": variant,
            "problem": problem, "model": problem.get("model", {}).get("type", "quadrotor_2d"),
            "obstacles": len(problem["obstacles"]),
            "hard": "constraints" in problem or any("clearance" in o for o in problem["obstacles"]),
            "reference": ref, "reference_start": best["label"] if best else None,
            "reference_sides": best["sides"] if best else None,
            "searched": searched["cost"], "searched_status": searched["status"],
            "searched_violation": searched["constraint_violation"],
            "searched_sides": sides(p, searched["states"]),
            "single": single["cost"], "single_status": single["status"],
            "single_violation": single["constraint_violation"],
            "gap": (searched["cost"] - ref) / ref, "single_gap": (single["cost"] - ref) / ref,
            "starts": len(searched["starts"]),
            "chosen": chosen, "cpu_ms": cpu, "wall_ms": searched["solve_time_ms"],
            "single_ms": single["solve_time_ms"], "ipopt_ms": ipopt_ms,
            "ipopt_starts": [{k: v for k, v in r.items() if k not in ("xs", "us")} for r in runs],
        })
        r = rows[-1]
        print(f"{name:>8s} {r['model']:12s} obs={r['obstacles']} hard={int(r['hard'])} "
              f"ref={ref:12.4f} ({r['reference_start']}) search={r['searched']:12.4f} "
              f"[{r['searched_status']}] gap={r['gap']:+.2e} single_gap={r['single_gap']:+.2e} "
              f"sides={r['searched_sides']}/{r['reference_sides']} starts={r['starts']} "
              f"chosen={chosen!r} cpu={cpu:.2f}ms single={r['single_ms']:.2f}ms "
              f"ipopt={statistics_median(ipopt_ms):.0f}ms",
              flush=True)

    print()
    summary(rows)
    print()
    print(f"{'group':28s} {'problems':>8s} {'search within':>14s} {'single within':>14s} "
          f"{'worst gap, search / single':>28s}")
    for key in dict.fromkeys((r["model"], r["variant"]) for r in rows):
        group = [r for r in rows if (r["model"], r["variant"]) == key]
        n = len(group)
        within, single_within = count_within(group, "searched"), count_within(group, "single")
        print(f"{' '.join(key):28s} {n:8d} {within:5d} ({100 * within / n:3.0f}%) "
              f"{single_within:5d} ({100 * single_within / n:3.0f}%) "
              f"{worst_gap(group, 'gap'):+13.3e} / {worst_gap(group, 'single_gap'):+.3e}")
    misses = [r for r in rows if not is_within(r, "searched")]
    if misses:
        print("\nsearch misses (sides: ours / IPOPT's, per obstacle, L or R facing along the path):")
    for r in misses:
        print(f"  {r['name']:>8s} {r['model']:12s} gap {r['gap']:+.3e} [{r['searched_status']}, "
              f"violation {r['searched_violation']:.1e}] sides {r['searched_sides']} / "
              f"{r['reference_sides']} chosen {r['chosen']!r}, IPOPT's from {r['reference_start']!r}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
