"""How often the solver ends each way on random, badly scaled problems.

    python3 bench/robustness.py target/release/ilqr-service 300 1 [METHOD]

Draws COUNT problems with seed SEED (dt 0.01-1 s, horizon 50/100/200,
random start, goal and 0-4 obstacles with weights 1-1e8, state, control and
terminal weights over several decades; in 30% of them the start sits
within 1 mm of the first obstacle's centre), solves each with
`BINARY solve - -o FILE` (with `"solver": {"method": METHOD}` when METHOD,
`ilqr` or `ddp`, is given), and prints the count of each status and the
iterations of all solves together, plus the
solves that ended `converged` with a last regularisation above 1: a heavily
damped step is small, so it could look converged without being so; and
those that fell back to the convex model of the cost
(`convexified_after_iteration`, the solver's `Options::convex_fallback`).

BENCHMARKS.md ("DDP versus iLQR") has the counts for seed 1, for both
methods. The script does not pass a method unless asked: it measures the
service's default.

A change to the convergence test, the regularisation schedule or the
convex fallback is judged on these problems one by one (statuses and
costs, not only the totals): it is worse if it takes `converged` from
genuine local optima, or calls converged a point that a restart of the
solver, IPOPT (bench/casadi_ipopt.py's NLP) or a plain descent from it
still lowers. Where the counts favour the current rules:

* a full step's small gain counts as convergence up to mu = 1e6
  (`Options::mu_converged_max`), not only at mu_min: requiring mu_min
  would end genuine optima `no_progress` or `max_iterations`, while the
  steps that only look converged come at mu of 8e15 and more;
* it counts only when the model about the new iterate agrees: one poor
  full step in a slow descent otherwise ends it early;
* a partial step's small gain never counts (iLQG.m's dcost < tolFun takes
  any step size): it stops solves above where they would go on to;
* mu comes down after every accepted step (Tassa's schedule), not only
  after steps with alpha > 0.5 (Crocoddyl's rule), which converges fewer;
* the convex fallback starts only past mu_max = 1e20: switching at 1e6 to
  1e10 ends about as many solves higher as lower, at other local optima.

The limit these counts show: a converged solve in a stiff, narrow valley,
where damped steps crawl, can stop a few hundred tolerances above the
optimum (docs/solver.md, "What `converged` means").
"""

import collections
import json
import os
import random
import subprocess
import sys
import tempfile


def problem(rng: random.Random) -> dict:
    p = {
        "dt": 10 ** rng.uniform(-2, 0),
        "horizon": rng.choice([50, 100, 200]),
        "initial_state": [rng.uniform(0, 9), rng.uniform(0, 9), rng.uniform(-1, 1), 0, 0, 0],
        "goal_state": [rng.uniform(0, 9), rng.uniform(0, 9), 0, 0, 0, 0],
        "obstacles": [
            {"center": [rng.uniform(0, 9), rng.uniform(0, 9)], "weight": 10 ** rng.uniform(0, 8)}
            for _ in range(rng.randint(0, 4))
        ],
        "weights": {
            "state": [10 ** rng.uniform(-3, 2)] * 6,
            "control": [10 ** rng.uniform(-3, 1)] * 2,
            "terminal": [10 ** rng.uniform(0, 6)] * 6,
        },
    }
    if rng.random() < 0.3 and p["obstacles"]:
        c = p["obstacles"][0]["center"]
        p["initial_state"][:2] = [c[0] + rng.uniform(-1e-3, 1e-3), c[1] + rng.uniform(-1e-3, 1e-3)]
    return p


def main() -> int:
    binary, count, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    method = sys.argv[4] if len(sys.argv) > 4 else None
    iterations = 0
    rng = random.Random(seed)
    statuses = collections.Counter()
    suspicious = []
    convexified = []
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "result.json")
        for i in range(count):
            p = problem(rng)
            # Each method's own single local solve, not the search over
            # routes.
            p["solver"] = {"multi_start": False}
            if method:
                p["solver"]["method"] = method
            run = subprocess.run([binary, "solve", "-", "-o", out], input=json.dumps(p),
                                 capture_output=True, text=True)
            if run.returncode != 0:
                statuses["error"] += 1
                continue
            with open(out) as f:
                r = json.load(f)
            statuses[r["status"]] += 1
            iterations += r["iterations"]
            mus = [row["regularization"] for row in r["trace"]]
            if r["status"] == "converged" and mus and mus[-1] > 1:
                suspicious.append((i, round(mus[-1], 3), r["iterations"]))
            if r.get("convexified_after_iteration") is not None:
                convexified.append((i, r["status"], r["convexified_after_iteration"], r["iterations"],
                                    f"{r['cost'] / r['initial_cost']:.2e}"))
    print(dict(statuses), "iterations", iterations)
    print("converged with a last regularisation above 1 (problem, mu, iterations):", suspicious)
    print("fell back to the convex model (problem, status, after iteration, iterations, cost/initial):",
          convexified)
    return 0


if __name__ == "__main__":
    sys.exit(main())
