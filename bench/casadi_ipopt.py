"""Reference benchmark: the ilqr-service problem solved with CasADi + IPOPT.

What it is for
    Solving the *same discrete problem* as the Rust iLQR solver with a
    general-purpose NLP solver, so that the two can be compared in one run:
    the optimal cost (they must agree) and the wall-clock time to solve.

    The default problem is the planar ("2-D") quadrotor of the seed
    scenario, discretised with explicit Euler, x_{k+1} = x_k + dt f(x_k, u_k),
    with

        J = sum_{k=0}^{N-1} [ (x_k-g)'Q(x_k-g) + u_k'R u_k
                              + sum_obstacles q exp(-d(p_k)) ]
            + (x_N-g)'Qf(x_N-g)

    (no 1/2 factors, no dt; the k = 0 stage keeps its constant x0 terms;
    p_k is the position, state entries 0 and 1, of x_k; d is the signed
    distance from p_k to the obstacle, ||p_k - c|| for a point obstacle,
    see "Obstacles and hard constraints" below). On the seed the optimum is
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
    for every step of the chosen integrator, and the problem's hard
    constraints (below) as NLP constraints. The initial guess is the same
    as iLQR's: the problem's "initial_controls", or else the model's rest
    controls (hover thrust m g / 2 on both rotors; zero for the unicycle),
    clamped into the control bounds if there are any (as ilqr clamps its
    initial controls), and the states of their rollout, so both solvers
    start from the same point.

Obstacles and hard constraints
    The same constrained problem as ilqr's solve_constrained (the service's
    "constraints" and obstacle shapes):
      * an obstacle is a "point" (the default), a "circle" ("radius") or a
        "rectangle" ("size" [width, height], turned by "angle" rad
        counter-clockwise, width along the turned x axis). d(p) is the
        signed distance to it, as ilqr::Region::distance: ||p - c|| for a
        point, ||p - c|| - radius for a circle; for a rectangle, with
        q = R(angle)'(p - c) and a = |q| - size/2 componentwise,
        d = ||max(a, 0)|| + min(max(a_x, a_y), 0). Negative inside.
      * its soft term q exp(-d(p_k)) is in every stage cost, k = 0..N-1
        ("weight" q, default 1000; 0 for none);
      * with a "clearance", d(p_k) >= clearance for k = 1..N. In the NLP a
        point or circle's is (p - c)'(p - c) >= (radius + clearance)^2
        (smooth; dropped where radius + clearance <= 0, as it then always
        holds); a rectangle's is the exact d, written with fmax/fmin and a
        root guarded by if_else so its derivatives are 0, not NaN, at 0
        (no epsilon);
      * "constraints": {"control": {"lower", "upper"}, "state": {"lower",
        "upper"}, "goal_tolerance"}, every member optional, null entries
        unbounded: lower <= u_k <= upper for k = 0..N-1; lower <= x_k <=
        upper for k = 1..N (x_0 is given); |x_N[i] - g[i]| <= tol[i], an
        equality x_N[i] = g[i] where tol[i] = 0 (a null tolerance is no
        constraint).

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
         "obstacles": [{"center": [2], "weight", "shape", "radius", "size",
                        "angle", "clearance"}],
         "constraints": {"control": {"lower": [nu], "upper": [nu]},
                         "state": {"lower": [nx], "upper": [nx]},
                         "goal_tolerance": [nx]},
         "initial_controls": [[nu] x N]}
    Other keys ("solver", "output", ...) are ignored. For the quadrotor
    ("type" "quadrotor_2d", the default) every field is optional and
    defaults to the seed. For the unicycle ("type" "unicycle"), whose seed
    there is none, initial_state, goal_state and all three weights are
    required; a missing "obstacles" means none; dt and horizon default to
    0.05 and 100 as for the quadrotor. A missing "constraints" means none,
    for either model. --integrator, when given, overrides the problem's
    "integrator" (default euler). examples/dubins_three_obstacles.json is
    ALTRO's three-obstacle Dubins car in this shape (hard circles, control
    bounds, an exact goal); like the seed it has several local optima, and
    which one IPOPT reaches depends on the initial guess.

    --controls-out FILE writes IPOPT's optimal controls (clamped into the
    control bounds, see below) as JSON,
    {"initial_controls": [[nu] x N], "cost", "model", "integrator", "dt",
    "horizon", "status", "iterations"}, so that a caller can warm-start
    this project's solver with them (the "initial_controls" member is the
    service request's field of that name).

What it reports
    The cost is recomputed in NumPy from a fresh rollout of IPOPT's optimal
    controls with the same integrator, so it is the cost of an exactly
    feasible trajectory, the quantity iLQR reports, not IPOPT's objective
    at a point that satisfies the dynamics only up to its tolerance. It is
    the base cost J above: hard constraints add nothing to it. With control
    bounds, IPOPT's controls are first clamped into them (IPOPT meets bounds
    only to within its tolerance and bound relaxation, ~1e-8 relative;
    ilqr's controls are inside them exactly), and by how much they were
    outside is reported as "control_bound_violation". "constraint_violation"
    is the largest violation of the other hard constraints along that
    rollout, in their own units (max(0, c) for an inequality c <= 0, |c|
    for an equality; clearances with the exact signed distance), as ilqr's
    Summary::constraint_violation; both are 0 without constraints, and the
    text output shows them only when there are some. "closest_approach" is
    the least d(p_k) over k = 0..N for each obstacle.

    Time is the wall clock of opti.solve(), best and median over --repeat
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
class Obstacle:
    """One entry of "obstacles": a soft term weight exp(-d(p)) in every
    stage cost and, with a clearance, the hard constraint d(p) >= clearance."""

    center: tuple
    weight: float = 1000.0
    shape: str = "point"  # "point", "circle" or "rectangle"
    radius: float = 0.0  # circle
    size: tuple = (0.0, 0.0)  # rectangle: (width, height)
    angle: float = 0.0  # rectangle: rad, counter-clockwise
    clearance: float | None = None  # None: no hard constraint


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
    obstacles: list = field(default_factory=lambda: [Obstacle((4.5, 4.5), 1000.0)])
    initial_controls: list | None = None  # N x nu; None means rest controls
    # Hard constraints ("constraints"); None means none of that kind, and
    # infinite entries are no bound.
    u_lower: list | None = None  # nu, for u_0..u_{N-1}
    u_upper: list | None = None
    x_lower: list | None = None  # nx, for x_1..x_N
    x_upper: list | None = None
    goal_tolerance: list | None = None  # nx, for x_N; 0 is an equality

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

    def has_control_bounds(self) -> bool:
        return self.u_lower is not None or self.u_upper is not None

    def control_bounds(self) -> tuple:
        """(lower, upper) on the controls as arrays, +-inf where unbounded."""
        lower = self.u_lower if self.u_lower is not None else [-math.inf] * self.nu
        upper = self.u_upper if self.u_upper is not None else [math.inf] * self.nu
        return np.array(lower, dtype=float), np.array(upper, dtype=float)

    def has_hard_constraints(self) -> bool:
        """Whether there is any hard constraint besides the control bounds."""
        return (self.x_lower is not None or self.x_upper is not None
                or self.goal_tolerance is not None
                or any(o.clearance is not None for o in self.obstacles))


def _floats(value, n, name):
    """`value` as a list of `n` floats, or exit with a message naming the field."""
    if not isinstance(value, list) or len(value) != n:
        sys.exit(f"problem: {name} must be a list of {n} numbers, got {value!r}")
    return [float(v) for v in value]


def _bounds(value, n, name, unbounded):
    """`value` as a list of `n` floats, `unbounded` for its nulls; None if
    `value` is missing or null (no bounds at all)."""
    if value is None:
        return None
    if not isinstance(value, list) or len(value) != n:
        sys.exit(f"problem: {name} must be a list of {n} numbers or nulls, got {value!r}")
    return [unbounded if v is None else float(v) for v in value]


def _check_order(lower, upper, name):
    """Exit unless lower <= upper wherever both are given."""
    if lower is not None and upper is not None:
        for i, (lo, hi) in enumerate(zip(lower, upper)):
            if not lo <= hi:
                sys.exit(f"problem: {name}.lower[{i}] = {lo} exceeds upper[{i}] = {hi}")


def load_obstacle(o: dict) -> Obstacle:
    """One entry of "obstacles"."""
    ob = Obstacle(tuple(_floats(o["center"], 2, "obstacles[].center")))
    if o.get("weight") is not None:
        ob.weight = float(o["weight"])
    ob.shape = o.get("shape") or "point"
    if ob.shape not in ("point", "circle", "rectangle"):
        sys.exit(f"problem: obstacles[].shape must be point, circle or rectangle, got {ob.shape!r}")
    if ob.shape == "circle" and o.get("radius") is not None:
        ob.radius = float(o["radius"])
    if ob.shape == "rectangle":
        ob.size = tuple(_floats(o.get("size"), 2, "obstacles[].size"))
        if o.get("angle") is not None:
            ob.angle = float(o["angle"])
    if ob.radius < 0.0 or min(ob.size) < 0.0:
        sys.exit("problem: obstacles[].radius and size must not be negative")
    if o.get("clearance") is not None:
        ob.clearance = float(o["clearance"])
    return ob


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
        p.obstacles = [load_obstacle(o) for o in raw["obstacles"]]
    constraints = raw.get("constraints") or {}
    control = constraints.get("control") or {}
    p.u_lower = _bounds(control.get("lower"), nu, "constraints.control.lower", -math.inf)
    p.u_upper = _bounds(control.get("upper"), nu, "constraints.control.upper", math.inf)
    _check_order(p.u_lower, p.u_upper, "constraints.control")
    state = constraints.get("state") or {}
    p.x_lower = _bounds(state.get("lower"), nx, "constraints.state.lower", -math.inf)
    p.x_upper = _bounds(state.get("upper"), nx, "constraints.state.upper", math.inf)
    _check_order(p.x_lower, p.x_upper, "constraints.state")
    p.goal_tolerance = _bounds(constraints.get("goal_tolerance"), nx,
                               "constraints.goal_tolerance", math.inf)
    if p.goal_tolerance is not None and not all(t >= 0.0 for t in p.goal_tolerance):
        sys.exit("problem: constraints.goal_tolerance must not be negative")
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


def _root(r2, lib):
    """sqrt(r2) for r2 >= 0. For CasADi it is guarded so that its derivatives
    are 0, not NaN, where r2 = 0 (the inner if_else keeps 0 out of the root,
    the outer one picks the value): the same value, no epsilon."""
    if lib is ca:
        return ca.if_else(r2 > 0, ca.sqrt(ca.if_else(r2 > 0, r2, 1.0)), 0.0)
    return np.sqrt(r2)


def signed_distance(o: Obstacle, px, py, lib):
    """d from the position (px, py) (scalars or arrays) to the obstacle's
    shape, as ilqr::Region::distance: positive outside, negative inside."""
    dx, dy = px - o.center[0], py - o.center[1]
    if o.shape != "rectangle":
        # The exact Euclidean norm, no epsilon under the root: an epsilon
        # would shift every obstacle term and so the cost we compare. The
        # root is only non-smooth at the centre itself, which no trajectory
        # here comes near (closest approach ~3 on the seed).
        rho = lib.sqrt(dx ** 2 + dy ** 2)
        return rho if o.shape == "point" else rho - o.radius
    # In the rectangle's frame, q = R(angle)' (p - c); a = |q| - size/2.
    c, s = math.cos(o.angle), math.sin(o.angle)
    ax = lib.fabs(c * dx + s * dy) - o.size[0] / 2.0
    ay = lib.fabs(-s * dx + c * dy) - o.size[1] / 2.0
    outside = _root(lib.fmax(ax, 0.0) ** 2 + lib.fmax(ay, 0.0) ** 2, lib)
    return outside + lib.fmin(lib.fmax(ax, ay), 0.0)


def stage_cost(p: Problem, x, u, lib):
    """l(x, u) = (x-g)'Q(x-g) + u'Ru + sum q exp(-d(p)), no 1/2 factors."""
    l = sum(p.q[i] * (x[i] - p.goal[i]) ** 2 for i in range(p.nx))
    l += sum(p.r[j] * u[j] ** 2 for j in range(p.nu))
    for o in p.obstacles:
        if o.weight != 0.0:  # a zero weight adds exactly nothing
            l += o.weight * lib.exp(-signed_distance(o, x[0], x[1], lib))
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


def constraint_violation(p: Problem, xs: np.ndarray) -> float:
    """The largest violation along the states `xs` (N+1 x nx) of the hard
    constraints other than control bounds, in their own units: max(0, c) for
    the inequalities c <= 0, |c| for the equalities (zero goal tolerances);
    clearances with the exact signed distance."""
    worst = 0.0
    later = xs[1:]  # x_1..x_N: x_0 is given
    if p.x_lower is not None:
        worst = max(worst, float(np.max(np.array(p.x_lower) - later)))
    if p.x_upper is not None:
        worst = max(worst, float(np.max(later - np.array(p.x_upper))))
    if p.goal_tolerance is not None:
        for i, tol in enumerate(p.goal_tolerance):
            if math.isfinite(tol):
                worst = max(worst, abs(xs[-1, i] - p.goal[i]) - tol)
    for o in p.obstacles:
        if o.clearance is not None:
            d = signed_distance(o, later[:, 0], later[:, 1], np)
            worst = max(worst, float(np.max(o.clearance - d)))
    return worst


def control_bound_violation(p: Problem, us: np.ndarray) -> float:
    """The largest violation of the control bounds by `us` (N x nu)."""
    lower, upper = p.control_bounds()
    return max(0.0, float(np.max(lower - us)), float(np.max(us - upper)))


def build_nlp(p: Problem, x_guess: np.ndarray, u_guess: np.ndarray, expand: bool = True):
    """The multiple-shooting NLP as a ready-to-solve casadi.Opti, and its X, U."""
    opti = ca.Opti()
    X = opti.variable(p.nx, p.horizon + 1)
    U = opti.variable(p.nu, p.horizon)

    opti.subject_to(X[:, 0] == ca.DM(p.x0))
    for k in range(p.horizon):
        opti.subject_to(X[:, k + 1] == discrete_step(p, X[:, k], U[:, k], ca))

    # Hard constraints, at the knots where ilqr's apply: controls at every
    # step, states from x_1 on, the goal tolerance at x_N.
    lower, upper = p.control_bounds()
    for j in range(p.nu):
        if math.isfinite(lower[j]):
            opti.subject_to(U[j, :] >= lower[j])
        if math.isfinite(upper[j]):
            opti.subject_to(U[j, :] <= upper[j])
    for i in range(p.nx):
        if p.x_lower is not None and math.isfinite(p.x_lower[i]):
            opti.subject_to(X[i, 1:] >= p.x_lower[i])
        if p.x_upper is not None and math.isfinite(p.x_upper[i]):
            opti.subject_to(X[i, 1:] <= p.x_upper[i])
    if p.goal_tolerance is not None:
        for i, tol in enumerate(p.goal_tolerance):
            if tol == 0.0:
                opti.subject_to(X[i, p.horizon] == p.goal[i])
            elif math.isfinite(tol):
                opti.subject_to(opti.bounded(p.goal[i] - tol, X[i, p.horizon], p.goal[i] + tol))
    for o in p.obstacles:
        if o.clearance is None:
            continue
        px, py = X[0, 1:], X[1, 1:]
        if o.shape == "rectangle":
            opti.subject_to(signed_distance(o, px, py, ca) >= o.clearance)
        elif o.radius + o.clearance > 0.0:
            # ||p - c|| - radius >= clearance, squared: smooth everywhere.
            # (With radius + clearance <= 0 it holds everywhere.)
            reach = o.radius + o.clearance
            opti.subject_to((px - o.center[0]) ** 2 + (py - o.center[1]) ** 2 >= reach ** 2)

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
    if p.has_control_bounds():
        # As ilqr clamps its initial controls into the bounds.
        u_guess = np.clip(u_guess, *p.control_bounds())
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

    # IPOPT meets the control bounds to its tolerance; ilqr's controls are
    # inside them exactly, so clamp (and report by how much IPOPT's were out).
    bound_violation = control_bound_violation(p, us)
    if p.has_control_bounds():
        us = np.clip(us, *p.control_bounds())

    # The reported cost: an exact rollout of the optimal controls (see
    # the docstring). The NLP's own objective and the largest dynamics defect
    # are kept to show the two agree.
    xs = rollout(p, us)
    cost = total_cost(p, xs, us)
    violation = constraint_violation(p, xs)
    nlp_cost = float(sol.value(opti.f))
    defect = float(np.max(np.abs(xs_nlp - xs)))

    goal_distance = float(np.hypot(xs[-1, 0] - p.goal[0], xs[-1, 1] - p.goal[1]))
    closest = [float(np.min(signed_distance(o, xs[:, 0], xs[:, 1], np))) for o in p.obstacles]
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
            "constraint_violation": violation,
            "control_bound_violation": bound_violation,
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
        for o, d in zip(p.obstacles, closest):
            shape = "" if o.shape == "point" else f"{o.shape} "
            print(f"  closest to {shape}({o.center[0]:g}, {o.center[1]:g})   {d:.6f}")
        if p.has_hard_constraints():
            print(f"  constraint violation      {violation:.3e}   (state bounds, goal tolerance,"
                  f" clearances; of the rollout)")
        if p.has_control_bounds():
            print(f"  control bound violation   {bound_violation:.3e}   (IPOPT's controls,"
                  f" clamped before the rollout)")
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
