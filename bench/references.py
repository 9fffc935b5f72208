"""Reference costs for named problems: IPOPT's best of several independent starts.

What it measures
    For each problem below, IPOPT (bench/casadi_ipopt.py's transcription:
    the same cost and constraints as the Rust solver) from starts that owe
    nothing to this project's answer, built by bench/route_quality.py's
    ipopt_starts: the rest (hover) rollout, the straight line from the
    initial to the goal position, a path through a point beside each
    obstacle on either side at 0.5, 1 and 2 times route_quality's distance,
    and for 2-3 obstacles one through points beside all of them for each
    combination of sides. The seed resampled at a finer dt is also started
    from the seed's IPOPT answers, the cheapest of each route, held and
    interpolated (route_quality.resampled_starts). Every start's status,
    cost (of the exact rollout of its controls), constraint violation and
    sides (L or R of each obstacle, facing along the path) are kept; the
    reference is the cheapest that IPOPT solved and that meets the hard
    constraints to 1e-6, the second route the cheapest such on other
    sides. Next to it: the release binary's default (the search) on the
    same problem, its cost, status, violation, starts and sides, and its
    relative gap to the reference.

    The problems: the seed (examples/seed.json); the seed at dt 0.025 x
    200, 0.0125 x 400, 0.01 x 500 and 0.005 x 1000 (weights unchanged);
    "p3", the seed with a hard circle r 2.5 (clearance 0.5) at (4.5, 4.5)
    and a hard 1 x 1 square at (7.5, 6) instead of its obstacle, thrust in
    [0, 12] and |theta| <= 0.5; "case4b", the seed's model and weights
    from (0.164, 0.318) to (1.954, 6.492) past a soft point at (0.461,
    2.433); examples/three_obstacles.json; "hard_circle", the seed's
    obstacle as a hard circle r 1, clearance 0.5, weight 1000 (as
    tests/constraints.rs).

Usage
    .venv-bench/bin/python bench/references.py [--binary target/release/ilqr-service]
        [--out bench/references.json]

    About two minutes on one core; it prints each problem's reference,
    second route and our cost, then every start, and writes it all to --out.
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import route_quality as rq

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SPREADS = (0.5, 1.0, 2.0)
COMBINATIONS = 3
# The seed at finer steps: (dt, horizon).
FINER = ((0.025, 200), (0.0125, 400), (0.01, 500), (0.005, 1000))


def example(name: str) -> dict:
    """examples/NAME.json without its output options (no gains, no trace)."""
    with open(os.path.join(ROOT, "examples", f"{name}.json")) as fh:
        problem = json.load(fh)
    problem["output"] = {"gains": False, "trace": False}
    return problem


def problems() -> list:
    """(name, problem JSON); the seed first, as the finer ones start from it."""
    seed = example("seed")
    out = [("seed", seed)]
    out += [(f"seed_dt{dt:g}", dict(copy.deepcopy(seed), dt=dt, horizon=n)) for dt, n in FINER]
    p3 = copy.deepcopy(seed)
    p3["obstacles"] = [
        {"shape": "circle", "center": [4.5, 4.5], "radius": 2.5, "clearance": 0.5, "weight": 0},
        {"shape": "rectangle", "center": [7.5, 6], "size": [1, 1], "clearance": 0, "weight": 0},
    ]
    p3["constraints"] = {
        "control": {"lower": [0, 0], "upper": [12, 12]},
        "state": {"lower": [None, None, -0.5, None, None, None],
                  "upper": [None, None, 0.5, None, None, None]},
    }
    out.append(("p3", p3))
    case4b = copy.deepcopy(seed)
    case4b["initial_state"] = [0.164, 0.318, 0, 0, 0, 0]
    case4b["goal_state"] = [1.954, 6.492, 0, 0, 0, 0]
    case4b["obstacles"] = [{"center": [0.461, 2.433], "weight": 1000}]
    out.append(("case4b", case4b))
    out.append(("three_obstacles", example("three_obstacles")))
    hard = copy.deepcopy(seed)
    hard["obstacles"] = [{"shape": "circle", "center": [4.5, 4.5], "radius": 1.0,
                          "clearance": 0.5, "weight": 1000}]
    out.append(("hard_circle", hard))
    return out


def kept(run: dict | None) -> dict | None:
    """A run's figures for the JSON (no trajectory, no time)."""
    if run is None:
        return None
    return {k: run[k] for k in ("label", "status", "solved", "cost", "violation", "sides")}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--binary", default="target/release/ilqr-service")
    ap.add_argument("--out", default=os.path.join(ROOT, "bench", "references.json"))
    args = ap.parse_args()
    with open(args.binary, "rb") as fh:
        binary_sha = hashlib.sha256(fh.read()).hexdigest()

    coarse = None  # the seed's (ci.Problem, IPOPT runs)
    results = []
    for name, problem in problems():
        p = rq.load(problem)
        starts = rq.ipopt_starts(p, COMBINATIONS, SPREADS)
        if name.startswith("seed_dt"):
            starts += rq.resampled_starts(*coarse, p)
        runs = rq.ipopt_runs(p, starts)
        if name == "seed":
            coarse = (p, runs)
        best = rq.reference(runs)
        other = rq.reference([r for r in runs if r["sides"] != best["sides"]])
        ours = rq.ours(args.binary, problem, True)
        results.append({
            "name": name,
            "problem": problem,
            "reference": kept(best),
            "second_route": kept(other),
            "starts": [kept(r) for r in runs],
            "ours": {
                "cost": ours["cost"], "status": ours["status"],
                "constraint_violation": ours["constraint_violation"],
                "sides": rq.sides(p, ours["states"]),
                "starts": [{k: s.get(k) for k in ("label", "status", "cost", "chosen")}
                           for s in ours["starts"]],
            },
            "gap": (ours["cost"] - best["cost"]) / best["cost"],
        })
        r = results[-1]
        print(f"{name:16s} IPOPT {best['cost']:14.6f} {best['sides']:3s} ({best['label']}), "
              f"second route {other['cost'] if other else float('nan'):14.6f} "
              f"{other['sides'] if other else '-'}; ours {ours['cost']:14.6f} "
              f"{r['ours']['sides']:3s} [{ours['status']}, violation {ours['constraint_violation']:.1e}] "
              f"gap {r['gap']:+.3e}", flush=True)
        for s in runs:
            print(f"    {s['label']:22s} {s['status']:28s} {s['cost']:14.6f} {s['sides']:3s}"
                  f" violation {s['violation']:.1e}", flush=True)

    with open(args.out, "w") as fh:
        json.dump({
            "about": __doc__.split("\n\n")[0],
            "reference_rule": "of the starts that IPOPT solved with a violation <= "
                              f"{rq.FEASIBLE:g}, the first within 1e-9 of the least cost; "
                              "costs are of the exact rollout of its controls",
            "sides": "per obstacle, L or R: the side the trajectory passes it on, facing along the path",
            "binary_sha256": binary_sha,
            "problems": results,
        }, fh, indent=1)
        fh.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
