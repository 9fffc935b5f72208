"""Crocoddyl's native unicycle against this project's iLQR, on identical problems.

What it compares
    crocoddyl.ActionModelUnicycle (calc and calcDiff in C++) solved by
    crocoddyl.SolverDDP, and the same discrete problem solved in process by
    this project's `ilqr::Solver` (crates/ilqr/examples/unicycle_timing.rs).
    Crocoddyl's model (include/crocoddyl/core/actions/unicycle.hxx):

        x+ = [x + v cos(th) dt,  y + v sin(th) dt,  th + w dt]   (explicit Euler)
        running cost  1/2 (w_x^2 |x|^2 + w_u^2 |u|^2)   per knot, not times dt
        terminal cost 1/2  w_x^2 |x_N|^2

    with goal the origin, cost weights (w_x, w_u) = (10, 1) and dt = 0.1 by
    default. In this project's terms (no 1/2 factors) that is
    Q = Qf = w_x^2/2 I, R = w_u^2/2 I, goal 0, Euler. Before solving, the
    script checks that correspondence numerically on every problem: the
    Euler rollout and the cost of one random control sequence computed by
    Crocoddyl (ShootingProblem.rollout and .calc) and by the formulas above
    in NumPy; and after solving, Crocoddyl's cost of this project's optimal
    trajectory against the cost this project reported for it.

    Both start from the same guess: zero controls and their rollout (the
    unicycle standing at x0). Convergence settings are each solver's
    defaults, which are not the same test: Crocoddyl stops when
    sum_k |Q_u,k|^2 < th_stop = 1e-9 (an absolute gradient test), this
    project when a full step gains less than 1e-9 of the cost (relative),
    so they can stop a few iterations apart; both costs are also compared
    with a tight reference (Crocoddyl with th_stop 1e-20, untimed).

How to run it
    python3 -m venv .venv-bench
    .venv-bench/bin/pip install -r bench/requirements-crocoddyl.txt
    .venv-bench/bin/python bench/crocoddyl_unicycle.py              # all problems
    .venv-bench/bin/python bench/crocoddyl_unicycle.py --repeat 200 --rounds 5 --json

    It builds and runs the Rust side with
    `cargo run --release -p ilqr --example unicycle_timing` (from the
    repository root, whatever the working directory).

How it times
    Crocoddyl: the ShootingProblem and SolverDDP are built once; each timed
    call is solver.solve(xs, us, maxiter) on fresh copies of the initial
    guess made before the clock starts. The call includes eigenpy's
    conversion of the Python lists to std::vector<VectorXd>; that overhead
    is measured separately as solve(xs, us, 0) (which converts and returns
    before the first iteration) and reported, not subtracted.
    ShootingProblem.nthreads is set to 1 (default; --threads to change it):
    this project's solver is single-threaded.
    This project: one Problem and one Solver, Solver::solve alone timed,
    the solver reused across solves as the service does.
    Each of --rounds rounds runs --repeat timed solves of each side back to
    back (after untimed warm-up solves), so that both see the same machine
    load; the medians are over all rounds' solves.

What it reports
    Per problem: both costs and their relative difference |J_ilqr - J_croc|
    / |J_croc|, each one's distance from the tight reference, iterations of
    each (Crocoddyl's counted by a callback: one per backward pass and line
    search, as this project counts them), both median and minimum solve
    times in microseconds, Crocoddyl's call overhead, and the time ratios
    (Crocoddyl / iLQR) of the medians and of the minima. On a loaded
    machine the minima are the fairer pair: a solve of several ms is
    preempted more often than one of tenths of a ms, which inflates the
    longer solve's median more. The correspondence checks print their
    largest discrepancies; a check beyond 1e-12 relative stops the script.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import crocoddyl
import numpy as np

ROOT = Path(__file__).resolve().parent.parent


@dataclass
class Case:
    """One problem: Crocoddyl's unicycle with these settings."""

    name: str
    x0: tuple
    w_x: float = 10.0
    w_u: float = 1.0
    dt: float = 0.1
    horizon: int = 100


CASES = [
    Case("default, N=100", (-1.0, -1.0, 1.0)),
    Case("default, N=1000", (-1.0, -1.0, 1.0), horizon=1000),
    Case("second, N=100", (2.0, -1.5, -2.5), w_x=3.0, w_u=2.0),
    Case("second, N=1000", (2.0, -1.5, -2.5), w_x=3.0, w_u=2.0, horizon=1000),
    Case("reverse, N=100", (0.5, 1.0, 0.0), w_x=1.0, w_u=0.5, dt=0.05),
]


class CountIterations(crocoddyl.CallbackAbstract):
    """Counts SolverDDP's iterations (its callbacks run once per iteration)."""

    def __init__(self):
        crocoddyl.CallbackAbstract.__init__(self)
        self.count = 0

    def __call__(self, solver):
        self.count += 1


def model(case: Case) -> crocoddyl.ActionModelUnicycle:
    m = crocoddyl.ActionModelUnicycle()
    m.costWeights = np.array([case.w_x, case.w_u])
    m.dt = case.dt
    return m


def shooting_problem(case: Case, threads: int) -> crocoddyl.ShootingProblem:
    m = model(case)
    problem = crocoddyl.ShootingProblem(np.array(case.x0), [m] * case.horizon, m)
    problem.nthreads = threads
    return problem


def guess(case: Case):
    """Zero controls and their rollout (fresh arrays each call)."""
    x0 = np.array(case.x0)
    return [x0.copy() for _ in range(case.horizon + 1)], [np.zeros(2) for _ in range(case.horizon)]


def numpy_rollout(case: Case, us: np.ndarray) -> np.ndarray:
    xs = np.empty((case.horizon + 1, 3))
    xs[0] = case.x0
    for k in range(case.horizon):
        x, u = xs[k], us[k]
        xs[k + 1] = x + case.dt * np.array([u[0] * math.cos(x[2]), u[0] * math.sin(x[2]), u[1]])
    return xs


def numpy_cost(case: Case, xs: np.ndarray, us: np.ndarray) -> float:
    """This project's cost: Q = Qf = w_x^2/2 I, R = w_u^2/2 I, goal 0."""
    q, r = case.w_x**2 / 2, case.w_u**2 / 2
    stages = math.fsum(q * float(xs[k] @ xs[k]) + r * float(us[k] @ us[k]) for k in range(case.horizon))
    return stages + q * float(xs[-1] @ xs[-1])


def rel(a: float, b: float) -> float:
    return abs(a - b) / abs(b)


def check_formulas(case: Case, threads: int) -> dict:
    """Crocoddyl's rollout and cost against the NumPy formulas, on random controls."""
    rng = np.random.default_rng(7)
    us = rng.uniform(-2.0, 2.0, size=(case.horizon, 2))
    problem = shooting_problem(case, threads)
    xs_croc = np.array(problem.rollout(list(us)))
    xs_np = numpy_rollout(case, us)
    croc = problem.calc(list(xs_croc), list(us))
    ours = numpy_cost(case, xs_np, us)
    out = {"state_max_abs_diff": float(np.max(np.abs(xs_croc - xs_np))),
           "cost_croc": croc, "cost_formula": ours, "cost_rel_diff": rel(ours, croc)}
    if out["cost_rel_diff"] > 1e-12 or out["state_max_abs_diff"] > 1e-12 * max(1.0, np.max(np.abs(xs_np))):
        sys.exit(f"{case.name}: Crocoddyl's model does not match the formulas: {out}")
    return out


def run_ilqr(case: Case, repeat: int, extra: list[str]) -> dict:
    cmd = ["cargo", "run", "--quiet", "--release", "-p", "ilqr", "--example", "unicycle_timing", "--",
           "--horizon", str(case.horizon), "--dt", repr(case.dt), "--wx", repr(case.w_x),
           "--wu", repr(case.w_u), "--x0=" + ",".join(repr(float(v)) for v in case.x0),
           "--repeat", str(repeat), "--times", *extra]
    run = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if run.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{run.stderr}")
    return json.loads(run.stdout)


def time_crocoddyl(solver, case: Case, maxiter: int, repeat: int, warmup: int) -> list[float]:
    for _ in range(warmup):
        xs, us = guess(case)
        solver.solve(xs, us, maxiter)
    times = []
    for _ in range(repeat):
        xs, us = guess(case)
        t0 = time.perf_counter()
        solver.solve(xs, us, maxiter)
        times.append((time.perf_counter() - t0) * 1e6)
    return times


def compare(case: Case, args) -> dict:
    formulas = check_formulas(case, args.threads)

    problem = shooting_problem(case, args.threads)
    solver = crocoddyl.SolverDDP(problem)
    counter = CountIterations()
    solver.setCallbacks([counter])

    # One untimed solve for the result, counting iterations.
    xs, us = guess(case)
    converged = solver.solve(xs, us, args.maxiter)
    croc_cost, croc_iters, croc_stop = solver.cost, counter.count, solver.stop
    croc_us = np.array(solver.us)
    solver.setCallbacks([])

    # A tight reference optimum, untimed, on a separate solver.
    tight = crocoddyl.SolverDDP(shooting_problem(case, args.threads))
    tight.th_stop = 1e-20
    xs, us = guess(case)
    tight.solve(xs, us, 1000)
    reference = tight.cost

    croc_times, ilqr_times, overhead = [], [], []
    ilqr = None
    for _ in range(args.rounds):
        ilqr = run_ilqr(case, args.repeat, [])
        ilqr_times += ilqr["times_us"]
        croc_times += time_crocoddyl(solver, case, args.maxiter, args.repeat, args.warmup)
        overhead += time_crocoddyl(solver, case, 0, args.repeat, 0)

    # Crocoddyl's cost of this project's optimal trajectory, and its rollout
    # of those controls, against what this project reported.
    traj = run_ilqr(case, 1, ["--warmup", "0", "--trajectory"])
    ilqr_us = np.array(traj["controls"])
    ilqr_xs = np.array(traj["states"])
    check = shooting_problem(case, args.threads)
    croc_of_ilqr = check.calc(list(ilqr_xs), list(ilqr_us))
    rollout_diff = float(np.max(np.abs(np.array(check.rollout(list(ilqr_us))) - ilqr_xs)))

    croc_median = statistics.median(croc_times)
    ilqr_median = statistics.median(ilqr_times)
    return {
        "problem": case.name,
        "x0": list(case.x0), "w_x": case.w_x, "w_u": case.w_u, "dt": case.dt, "horizon": case.horizon,
        "crocoddyl": {"cost": croc_cost, "iterations": croc_iters, "converged": converged,
                      "stop": croc_stop, "median_us": croc_median, "min_us": min(croc_times),
                      "call_overhead_median_us": statistics.median(overhead)},
        "ilqr": {"cost": ilqr["cost"], "iterations": ilqr["iterations"], "status": ilqr["status"],
                 "median_us": ilqr_median, "min_us": min(ilqr_times)},
        "cost_rel_diff": rel(ilqr["cost"], croc_cost),
        "reference_cost": reference,
        "crocoddyl_rel_to_reference": rel(croc_cost, reference),
        "ilqr_rel_to_reference": rel(ilqr["cost"], reference),
        "control_max_abs_diff": float(np.max(np.abs(croc_us - ilqr_us))),
        "time_ratio": croc_median / ilqr_median,
        "min_time_ratio": min(croc_times) / min(ilqr_times),
        "checks": {"random_controls": formulas,
                   "crocoddyl_cost_of_ilqr_optimum_rel_diff": rel(croc_of_ilqr, traj["cost"]),
                   "crocoddyl_rollout_of_ilqr_controls_max_abs_diff": rollout_diff},
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=100, help="timed solves per side per round (default 100)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    ap.add_argument("--warmup", type=int, default=3, help="untimed Crocoddyl solves per round (default 3)")
    ap.add_argument("--maxiter", type=int, default=500,
                    help="Crocoddyl's iteration cap (default 500, this project's default cap)")
    ap.add_argument("--threads", type=int, default=1, help="ShootingProblem.nthreads (default 1)")
    ap.add_argument("--only", help="run only the problems whose name contains this")
    ap.add_argument("--json", action="store_true", help="print one JSON list instead of the table")
    args = ap.parse_args()
    if min(args.repeat, args.rounds) < 1:
        ap.error("--repeat and --rounds must be at least 1")

    build = subprocess.run(["cargo", "build", "--quiet", "--release", "-p", "ilqr", "--example",
                            "unicycle_timing"], cwd=ROOT)
    if build.returncode != 0:
        return build.returncode

    results = [compare(c, args) for c in CASES if args.only is None or args.only in c.name]
    if args.json:
        print(json.dumps(results, indent=1))
        return 0

    print(f"Crocoddyl {crocoddyl.__version__} SolverDDP (nthreads {args.threads}) against ilqr::Solver; "
          f"Python {platform.python_version()}; {args.rounds} rounds x {args.repeat} solves each")
    head = (f"{'problem':16} {'J crocoddyl':>18} {'J ilqr':>18} {'rel diff':>8} {'it C':>4} {'it I':>4}"
            f" {'C med us':>9} {'I med us':>9} {'ratio':>6} {'C min us':>9} {'I min us':>9} {'ratio':>6}"
            f" {'C call us':>9}")
    print(head)
    for r in results:
        c, i = r["crocoddyl"], r["ilqr"]
        print(f"{r['problem']:16} {c['cost']:18.12f} {i['cost']:18.12f} {r['cost_rel_diff']:8.1e}"
              f" {c['iterations']:4d} {i['iterations']:4d} {c['median_us']:9.1f} {i['median_us']:9.1f}"
              f" {r['time_ratio']:6.2f} {c['min_us']:9.1f} {i['min_us']:9.1f} {r['min_time_ratio']:6.2f}"
              f" {c['call_overhead_median_us']:9.1f}")
    print()
    for r in results:
        c, i, k = r["crocoddyl"], r["ilqr"], r["checks"]
        print(f"{r['problem']}: x0 {r['x0']}, w_x {r['w_x']}, w_u {r['w_u']}, dt {r['dt']}")
        print(f"  crocoddyl converged={c['converged']} stop={c['stop']:.2e}; ilqr {i['status']}")
        print(f"  reference (th_stop 1e-20) {r['reference_cost']:.12f}: crocoddyl"
              f" {r['crocoddyl_rel_to_reference']:.1e} from it, ilqr {r['ilqr_rel_to_reference']:.1e};"
              f" controls differ by at most {r['control_max_abs_diff']:.1e}")
        f = k["random_controls"]
        print(f"  random controls: cost rel diff {f['cost_rel_diff']:.1e}, states {f['state_max_abs_diff']:.1e};"
              f" ilqr optimum: Crocoddyl's cost of it {k['crocoddyl_cost_of_ilqr_optimum_rel_diff']:.1e} rel,"
              f" its rollout {k['crocoddyl_rollout_of_ilqr_controls_max_abs_diff']:.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
