"""Reference benchmark: the ilqr-service problem solved with CasADi + IPOPT.

What it is for
    Solving the *same discrete problem* as the Rust iLQR solver with a
    general-purpose NLP solver, so that the two can be compared in one run:
    the optimal cost (they must agree) and the wall-clock time to solve.

    The default problem is the planar ("2-D") quadrotor of the seed
    scenario, discretised with explicit Euler, x_{k+1} = x_k + dt f(x_k, u_k),
    with

        J = sum_{k=0}^{N-1} [ (x_k-g)'Q(x_k-g) + u_k'R u_k
                              + sum_obstacles q exp(-||p_k - c||) ]
            + (x_N-g)'Qf(x_N-g)

    (no 1/2 factors; the k = 0 stage keeps its constant x0 terms; p_k is the
    position, state entries 0 and 1, of x_k). On the seed the optimum is
    J = 5520.212.

    Two other discretisations and models are available:
      * --integrator rk4 (or the problem's "integrator": "rk4"): the
        classical Runge-Kutta step of ilqr::Rk4, zero-order hold on u:
        k1 = f(x, u), k2 = f(x + h/2 k1, u), k3 = f(x + h/2 k2, u),
        k4 = f(x + h k3, u), x+ = x + h/6 (k1 + 2 k2 + 2 k3 + k4).
      * "model": {"type": "unicycle"}: ilqr::Unicycle, state [x, y, theta],
        controls [v, omega], xdot = v cos theta, ydot = v sin theta,
        thetadot = omega; no parameters.

    It is transcribed by direct multiple shooting with casadi.Opti: decision
    variables X (nx x N+1) and U (nu x N), equality constraints for x0 and
    for every step of the chosen integrator. The initial guess is the same
    as iLQR's: the problem's "initial_controls", or else the model's rest
    controls (hover thrust m g / 2 on both rotors; zero for the unicycle),
    and the states of their rollout, so both solvers start from the same
    point.

How to run it
    python3 -m venv .venv-bench
    .venv-bench/bin/pip install -r bench/requirements.txt
    .venv-bench/bin/python bench/casadi_ipopt.py                  # the seed, Euler
    .venv-bench/bin/python bench/casadi_ipopt.py --integrator rk4 --controls-out U.json
    .venv-bench/bin/python bench/casadi_ipopt.py --problem P.json --repeat 10 --json

    --problem reads the service's request shape:
        {"model": {"type", "mass", "inertia", "arm_length", "gravity"},
         "integrator": "euler" | "rk4", "dt", "horizon",
         "initial_state": [nx], "goal_state": [nx],
         "weights": {"state": [nx], "control": [nu], "terminal": [nx]},
         "obstacles": [{"center": [2], "weight"}], "initial_controls": [[nu] x N]}
    Other keys ("solver", "output", ...) are ignored. For the quadrotor
    ("type" "quadrotor_2d", the default) every field is optional and
    defaults to the seed. For the unicycle ("type" "unicycle"), whose seed
    there is none, initial_state, goal_state and all three weights are
    required; a missing "obstacles" means none; dt and horizon default to
    0.05 and 100 as for the quadrotor. --integrator, when given, overrides
    the problem's "integrator" (default euler).

    --controls-out FILE writes IPOPT's optimal controls as JSON,
    {"initial_controls": [[nu] x N], "cost", "model", "integrator", "dt",
    "horizon", "status", "iterations"}, so that a caller can warm-start
    this project's solver with them (the "initial_controls" member is the
    service request's field of that name).

What it reports
    The cost is recomputed in NumPy from a fresh rollout of IPOPT's optimal
    controls with the same integrator, so it is the cost of an exactly
    feasible trajectory, the quantity iLQR reports, not IPOPT's objective
    at a point that satisfies the dynamics only up to its tolerance. Time
    is the wall clock of opti.solve(), best and median over --repeat
    solves; the first solve, which also builds the NLP functions and IPOPT
    instance, is done once beforehand and reported separately, together
    with the "cold" time (building the Opti problem plus that first solve:
    what a service would pay for a problem it has not seen). Every timed
    solve starts from the same initial guess (Opti does not warm-start
    from the previous solution).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

# State and control sizes of each model.
DIMENSIONS = {"quadrotor_2d": (6, 2), "unicycle": (3, 2)}
INTEGRATORS = ("euler", "rk4")


@dataclass
class Problem:
    """One discrete problem; the defaults are the seed scenario."""

    model: str = "quadrotor_2d"
    integrator: str = "euler"
    mass: float = 1.0
    inertia: float = 1.0
    arm_length: float = 1.0
    gravity: float = 9.81
    dt: float = 0.05
    horizon: int = 100
    x0: list = field(default_factory=lambda: [5.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    goal: list = field(default_factory=lambda: [4.0, 9.0, 0.0, 0.0, 0.0, 0.0])
    q: list = field(default_factory=lambda: [1.0] * 6)  # diag(Q)
    r: list = field(default_factory=lambda: [0.1] * 2)  # diag(R)
    qf: list = field(default_factory=lambda: [50000.0] * 6)  # diag(Qf)
    # (center, weight) pairs.
    obstacles: list = field(default_factory=lambda: [((4.5, 4.5), 1000.0)])
    initial_controls: list | None = None  # N x nu; None means rest controls

    @property
    def nx(self) -> int:
        return DIMENSIONS[self.model][0]

    @property
    def nu(self) -> int:
        return DIMENSIONS[self.model][1]

    def rest_controls(self) -> list:
        """The model's rest controls: hover thrust, or standing still."""
        if self.model == "unicycle":
            return [0.0, 0.0]
        return [self.mass * self.gravity / 2.0] * 2


def _floats(value, n, name):
    """`value` as a list of `n` floats, or exit with a message naming the field."""
    if not isinstance(value, list) or len(value) != n:
        sys.exit(f"problem: {name} must be a list of {n} numbers, got {value!r}")
    return [float(v) for v in value]


def load_problem(path: str | None, integrator: str | None = None) -> Problem:
    """The problem in the JSON file at `path` (the seed where it is None or
    silent, for the quadrotor); `integrator`, if given, overrides the file's."""
    p = Problem()
    raw = {}
    if path is not None:
        with open(path, encoding="utf-8") as fh:
            raw = json.load(fh)
    model = raw.get("model", {})
    p.model = model.get("type", p.model)
    if p.model not in DIMENSIONS:
        sys.exit(f"problem: model.type must be one of {sorted(DIMENSIONS)}, got {p.model!r}")
    p.integrator = integrator or raw.get("integrator", p.integrator)
    if p.integrator not in INTEGRATORS:
        sys.exit(f"problem: integrator must be one of {list(INTEGRATORS)}, got {p.integrator!r}")
    nx, nu = p.nx, p.nu
    if p.model == "unicycle":
        weights = raw.get("weights", {})
        missing = [k for k in ("initial_state", "goal_state") if k not in raw]
        missing += [f"weights.{k}" for k in ("state", "control", "terminal") if k not in weights]
        if missing:
            sys.exit(f"problem: the unicycle has no defaults for {', '.join(missing)}")
        p.obstacles = []
        unknown = [k for k in ("mass", "inertia", "arm_length", "gravity") if k in model]
        if unknown:
            sys.exit(f"problem: the unicycle has no parameters ({', '.join(unknown)} given)")
    for key in ("mass", "inertia", "arm_length", "gravity"):
        if key in model:
            setattr(p, key, float(model[key]))
    if "dt" in raw:
        p.dt = float(raw["dt"])
    if "horizon" in raw:
        p.horizon = int(raw["horizon"])
        if p.horizon < 1:
            sys.exit("problem: horizon must be at least 1")
    if "initial_state" in raw:
        p.x0 = _floats(raw["initial_state"], nx, "initial_state")
    if "goal_state" in raw:
        p.goal = _floats(raw["goal_state"], nx, "goal_state")
    weights = raw.get("weights", {})
    if "state" in weights:
        p.q = _floats(weights["state"], nx, "weights.state")
    if "control" in weights:
        p.r = _floats(weights["control"], nu, "weights.control")
    if "terminal" in weights:
        p.qf = _floats(weights["terminal"], nx, "weights.terminal")
    # An explicit empty list means "no obstacles"; only a missing key keeps the seed's.
    if "obstacles" in raw:
        p.obstacles = [
            (tuple(_floats(o["center"], 2, "obstacles[].center")), float(o["weight"]))
            for o in raw["obstacles"]
        ]
    if raw.get("initial_controls") is not None:
        ctrl = raw["initial_controls"]
        if len(ctrl) != p.horizon:
            sys.exit(f"problem: initial_controls has {len(ctrl)} rows, horizon is {p.horizon}")
        p.initial_controls = [_floats(u, nu, "initial_controls[]") for u in ctrl]
    return p


# The model, integrator and cost are written once, against a "backend"
# module (numpy or casadi) that supplies sin/cos/exp/sqrt, so the NLP and
# the NumPy check below evaluate literally the same formulas.


def continuous_dynamics(p: Problem, x, u, lib):
    """f(x, u) as a list of nx expressions."""
    if p.model == "unicycle":
        # x = [px, py, theta], u = [v, omega]
        return [u[0] * lib.cos(x[2]), u[0] * lib.sin(x[2]), u[1]]
    # x = [px, py, theta, vx, vy, omega], u = [u1, u2]
    thrust = u[0] + u[1]
    return [
        x[3],
        x[4],
        x[5],
        -thrust * lib.sin(x[2]) / p.mass,
        thrust * lib.cos(x[2]) / p.mass - p.gravity,
        p.arm_length * (u[0] - u[1]) / p.inertia,
    ]


def _vector(items, lib):
    """A list of expressions as the backend's column vector."""
    return ca.vertcat(*items) if lib is ca else np.array(items)


def discrete_step(p: Problem, x, u, lib):
    """x_{k+1} from x_k = x (a vector of the backend) and u_k = u."""
    h = p.dt

    def f(y):
        return _vector(continuous_dynamics(p, y, u, lib), lib)

    if p.integrator == "euler":
        return x + h * f(x)
    k1 = f(x)
    k2 = f(x + (0.5 * h) * k1)
    k3 = f(x + (0.5 * h) * k2)
    k4 = f(x + h * k3)
    return x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)


def stage_cost(p: Problem, x, u, lib):
    """l(x, u) = (x-g)'Q(x-g) + u'Ru + sum q exp(-||p - c||), no 1/2 factors."""
    l = sum(p.q[i] * (x[i] - p.goal[i]) ** 2 for i in range(p.nx))
    l += sum(p.r[j] * u[j] ** 2 for j in range(p.nu))
    for (cx, cy), weight in p.obstacles:
        # The exact Euclidean norm, no epsilon under the root: an epsilon
        # would shift every obstacle term and so the cost we compare. The
        # root is only non-smooth at the centre itself, which no trajectory
        # here comes near (closest approach ~3 on the seed).
        l += weight * lib.exp(-lib.sqrt((x[0] - cx) ** 2 + (x[1] - cy) ** 2))
    return l


def terminal_cost(p: Problem, x):
    return sum(p.qf[i] * (x[i] - p.goal[i]) ** 2 for i in range(p.nx))


def rollout(p: Problem, controls: np.ndarray) -> np.ndarray:
    """States (N+1 x nx) of the rollout of `controls` (N x nu) from x0."""
    xs = np.empty((p.horizon + 1, p.nx))
    xs[0] = p.x0
    for k in range(p.horizon):
        xs[k + 1] = discrete_step(p, xs[k], controls[k], np)
    return xs


def total_cost(p: Problem, xs: np.ndarray, us: np.ndarray) -> float:
    stages = math.fsum(stage_cost(p, xs[k], us[k], np) for k in range(p.horizon))
    return stages + terminal_cost(p, xs[p.horizon])


def build_nlp(p: Problem, x_guess: np.ndarray, u_guess: np.ndarray, expand: bool = True):
    """The multiple-shooting NLP as a ready-to-solve casadi.Opti, and its X, U."""
    opti = ca.Opti()
    X = opti.variable(p.nx, p.horizon + 1)
    U = opti.variable(p.nu, p.horizon)

    opti.subject_to(X[:, 0] == ca.DM(p.x0))
    for k in range(p.horizon):
        opti.subject_to(X[:, k + 1] == discrete_step(p, X[:, k], U[:, k], ca))

    J = sum(stage_cost(p, X[:, k], U[:, k], ca) for k in range(p.horizon))
    opti.minimize(J + terminal_cost(p, X[:, p.horizon]))

    opti.set_initial(X, x_guess.T)
    opti.set_initial(U, u_guess.T)

    plugin_opts = {
        # Expand the MX graph to SX: scalar-only, much cheaper to evaluate in
        # IPOPT's callbacks. This is the usual way to use CasADi for speed and
        # keeps the comparison against a compiled iLQR fair.
        "expand": expand,
        # CasADi's own per-solve timing table would pollute stdout (and --json),
        # but keep the timers so sol.stats() has IPOPT's t_wall_total.
        "print_time": False,
        "record_time": True,
    }
    ipopt_opts = {
        "print_level": 0,
        "sb": "yes",  # suppress IPOPT's banner
        # Tight, so the optimum cost is accurate to ~1e-6 relative or better
        # (the default 1e-8 is on the scaled KKT error, not the cost).
        "tol": 1e-10,
    }
    opti.solver("ipopt", plugin_opts, ipopt_opts)
    return opti, X, U


def solve(opti: ca.Opti):
    """opti.solve(), exiting with IPOPT's status if it did not converge."""
    try:
        return opti.solve()
    except RuntimeError:
        # Opti raises on any status other than success; say which one.
        status = opti.debug.stats().get("return_status", "unknown")
        sys.exit(f"IPOPT did not converge: {status}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problem", help="problem JSON (service request shape); default: the seed")
    ap.add_argument("--repeat", type=int, default=5, help="timed solves (default 5)")
    ap.add_argument("--json", action="store_true", help="print one JSON object instead of text")
    ap.add_argument("--no-expand", action="store_true",
                    help="evaluate the MX graph as built (CasADi's default) instead of expanding it to SX")
    ap.add_argument("--integrator", choices=INTEGRATORS,
                    help="the discretisation (default: the problem's \"integrator\", else euler)")
    ap.add_argument("--controls-out", metavar="FILE",
                    help="write IPOPT's optimal controls as JSON (\"initial_controls\" and metadata)")
    args = ap.parse_args()
    if args.repeat < 1:
        ap.error("--repeat must be at least 1")

    p = load_problem(args.problem, args.integrator)

    # Same starting point as iLQR: the controls, and the states of their rollout.
    if p.initial_controls is not None:
        u_guess = np.array(p.initial_controls, dtype=float)
    else:
        u_guess = np.tile(p.rest_controls(), (p.horizon, 1)).astype(float)
    x_guess = rollout(p, u_guess)
    initial_cost = total_cost(p, x_guess, u_guess)

    t0 = time.perf_counter()
    opti, X, U = build_nlp(p, x_guess, u_guess, expand=not args.no_expand)
    build_ms = (time.perf_counter() - t0) * 1e3

    # Untimed first solve: it also constructs the nlpsol (SX expansion,
    # derivative functions, IPOPT instance), which later solves reuse.
    t0 = time.perf_counter()
    sol = solve(opti)
    first_ms = (time.perf_counter() - t0) * 1e3

    solve_ms, ipopt_ms, iterations = [], [], set()
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        sol = solve(opti)
        solve_ms.append((time.perf_counter() - t0) * 1e3)
        stats = sol.stats()
        iterations.add(stats["iter_count"])
        if "t_wall_total" in stats:
            ipopt_ms.append(stats["t_wall_total"] * 1e3)

    stats = sol.stats()
    status = stats.get("return_status", "unknown")
    us = np.array(sol.value(U), dtype=float).reshape(p.nu, p.horizon).T
    xs_nlp = np.array(sol.value(X), dtype=float).reshape(p.nx, p.horizon + 1).T

    # The reported cost: an exact rollout of the optimal controls (see
    # the docstring). The NLP's own objective and the largest dynamics defect
    # are kept to show the two agree.
    xs = rollout(p, us)
    cost = total_cost(p, xs, us)
    nlp_cost = float(sol.value(opti.f))
    defect = float(np.max(np.abs(xs_nlp - xs)))

    goal_distance = float(np.hypot(xs[-1, 0] - p.goal[0], xs[-1, 1] - p.goal[1]))
    closest = [
        float(np.min(np.hypot(xs[:, 0] - cx, xs[:, 1] - cy))) for (cx, cy), _ in p.obstacles
    ]
    best_ms = min(solve_ms)
    median_ms = statistics.median(solve_ms)
    iters = stats["iter_count"]

    if args.controls_out:
        with open(args.controls_out, "w", encoding="utf-8") as fh:
            json.dump({
                "cost": cost,
                "model": p.model,
                "integrator": p.integrator,
                "dt": p.dt,
                "horizon": p.horizon,
                "status": status,
                "iterations": iters,
                # repr-exact floats, so a reader gets IPOPT's controls bit for bit.
                "initial_controls": us.tolist(),
            }, fh)
            fh.write("\n")

    if args.json:
        out = {
            "solver": "casadi-ipopt",
            "model": p.model,
            "integrator": p.integrator,
            "cost": cost,
            "iterations": iters,
            "best_ms": best_ms,
            "median_ms": median_ms,
            "goal_distance": goal_distance,
            "closest_approach": closest,
            # Extras, for diagnosing a disagreement.
            "status": status,
            "ipopt_wall_best_ms": min(ipopt_ms) if ipopt_ms else None,
            "first_solve_ms": first_ms,
            # What a service that gets a new problem per request would pay:
            # building the Opti problem, then its first solve (which also
            # creates the nlpsol and IPOPT instance).
            "cold_ms": build_ms + first_ms,
            "nlp_cost": nlp_cost,
            "max_defect": defect,
            "repeat": args.repeat,
        }
        print(json.dumps(out))
    else:
        print(f"casadi-ipopt (CasADi {ca.__version__}), {p.model}, {p.integrator}, N={p.horizon}, dt={p.dt}")
        print(f"  status          {status}")
        print(f"  iterations      {iters}")
        print(f"  initial cost    {initial_cost:.6f}")
        print(f"  cost            {cost:.9f}   (NLP objective {nlp_cost:.9f}, max defect {defect:.1e})")
        print(f"  goal distance   {goal_distance:.6f}")
        for ((cx, cy), _), d in zip(p.obstacles, closest):
            print(f"  closest to ({cx:g}, {cy:g})   {d:.6f}")
        print(f"  solve wall ms   best {best_ms:.3f}, median {median_ms:.3f} over {args.repeat}"
              f" (first solve incl. construction {first_ms:.3f})")
        print(f"  cold ms         {build_ms + first_ms:.3f} (building the Opti problem"
              f" {build_ms:.3f} + first solve)")
        if ipopt_ms:
            print(f"  IPOPT t_wall_total ms   best {min(ipopt_ms):.3f},"
                  f" median {statistics.median(ipopt_ms):.3f}")
    if len(iterations) > 1:
        print(f"warning: iteration count varied across repeats: {sorted(iterations)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
