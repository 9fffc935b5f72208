#!/usr/bin/env python3
"""Solve a problem over HTTP and fly its feedback policy from a perturbed start.

The service returns, besides the optimised trajectory (x̄_k, ū_k), the
time-varying feedback gains K_k of the last backward pass. This script

1. solves ``examples/seed.json`` (or the problem file given, of the planar
   quadrotor or the unicycle) with :class:`ilqr_client.Client` and prints
   status, cost and iterations;
2. simulates the vehicle itself (the same model and integrator, explicit
   Euler or RK4, that the service used) from a perturbed initial state,
   twice:

   * open loop:   u_k = ū_k
   * closed loop: u_k = ū_k + K_k (x_k − x̄_k)

3. prints how far each rollout ends from the goal position.

Usage (with a service running; see ``README.md`` for how to start one)::

    pip install ./clients/python
    ILQR_URL=http://127.0.0.1:8080 python3 examples/solve.py
    python3 examples/solve.py examples/three_obstacles.json --perturb 0.3 -0.2 0.05
    python3 examples/solve.py examples/unicycle.json

Exit status: 0 on success, 2 if the service rejected the problem
(``ValidationError``), 3 if it stayed overloaded (``OverloadedError``),
1 on other failures.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Callable, Dict, List, Mapping, Sequence

HERE = Path(__file__).resolve().parent

try:
    import ilqr_client
except ImportError:  # not installed: use the client from this repository
    sys.path.insert(0, str(HERE.parent / "clients" / "python" / "src"))
    import ilqr_client

import requests
from ilqr_client import ApiError, Client, OverloadedError, SolveResult, ValidationError

State = List[float]


# --------------------------------------------------------------------------- #
# The models and integrators, written out here independently of the service
# --------------------------------------------------------------------------- #

Derivative = Callable[[Sequence[float], Sequence[float], Mapping[str, float]], State]


def quadrotor(x: Sequence[float], u: Sequence[float], p: Mapping[str, float]) -> State:
    """ẋ = f(x, u) for the state [x, y, θ, ẋ, ẏ, θ̇] and rotor thrusts [u1, u2]."""
    m, inertia = p["mass"], p["inertia"]
    r, g = p["arm_length"], p["gravity"]
    thrust = u[0] + u[1]
    return [
        x[3],
        x[4],
        x[5],
        -thrust * math.sin(x[2]) / m,
        thrust * math.cos(x[2]) / m - g,
        r * (u[0] - u[1]) / inertia,
    ]


def unicycle(x: Sequence[float], u: Sequence[float], p: Mapping[str, float]) -> State:
    """ẋ = f(x, u) for the state [x, y, θ] and controls [v, ω]."""
    return [u[0] * math.cos(x[2]), u[0] * math.sin(x[2]), u[1]]


MODELS: Dict[str, Derivative] = {"quadrotor_2d": quadrotor, "unicycle": unicycle}


def euler(f: Derivative, x: Sequence[float], u: Sequence[float], p: Mapping[str, float], dt: float) -> State:
    """x_{k+1} = x_k + dt · f(x_k, u_k)."""
    return [xi + dt * fi for xi, fi in zip(x, f(x, u, p))]


def rk4(f: Derivative, x: Sequence[float], u: Sequence[float], p: Mapping[str, float], dt: float) -> State:
    """The classical Runge–Kutta step, u held over the step."""
    def shifted(k: State, h: float) -> State:
        return [xi + h * ki for xi, ki in zip(x, k)]

    k1 = f(x, u, p)
    k2 = f(shifted(k1, dt / 2), u, p)
    k3 = f(shifted(k2, dt / 2), u, p)
    k4 = f(shifted(k3, dt), u, p)
    return [xi + dt / 6 * (a + 2 * b + 2 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4)]


INTEGRATORS = {"euler": euler, "rk4": rk4}


def rollout(result: SolveResult, x0: Sequence[float], step: Callable[[Sequence[float], Sequence[float]], State],
            closed_loop: bool) -> List[State]:
    """Simulate N steps from x0, applying ū_k (open loop) or ū_k + K_k (x_k − x̄_k)."""
    if closed_loop and result.gains is None:
        raise ValueError("the result has no gains: solve with output.gains = true")
    states = [list(x0)]
    for k, u_bar in enumerate(result.controls):
        x = states[-1]
        u = result.gains.control(k, x, result.states[k], u_bar) if closed_loop else u_bar
        states.append(step(x, u))
    return states


# --------------------------------------------------------------------------- #


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("problem", nargs="?", type=Path, default=HERE / "seed.json",
                        help="problem JSON (default: examples/seed.json)")
    parser.add_argument("--url", default=os.environ.get("ILQR_URL", "http://127.0.0.1:8080"),
                        help="service base URL (default: $ILQR_URL or http://127.0.0.1:8080)")
    parser.add_argument("--perturb", nargs=3, type=float, metavar=("DX", "DY", "DTHETA"),
                        default=(0.3, -0.2, 0.05),
                        help="offset of the initial position x [m], y [m] and heading or attitude θ [rad] "
                             "(default: 0.3 -0.2 0.05)")
    args = parser.parse_args()

    try:
        problem = json.loads(args.problem.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        print(f"cannot read {args.problem}: {exc}", file=sys.stderr)
        return 1
    if not isinstance(problem, dict):
        print(f"{args.problem}: expected a JSON object (a problem), got {type(problem).__name__}",
              file=sys.stderr)
        return 1
    # Gains are needed for the closed loop; the trace is not.
    problem["output"] = {"gains": True, "trace": False}

    given_model = problem.get("model") or {}
    model_type = given_model.get("type", "quadrotor_2d") if isinstance(given_model, dict) else "quadrotor_2d"
    with Client(args.url, timeout=(5.0, 70.0), retries=3) as client:
        try:
            # What the service says of the model (the order of its state
            # and where its position is), and its defaults for the fields
            # the file leaves out (the local simulation needs the
            # parameters, dt, the integrator and the goal).
            info = {m.type: m for m in client.models()}.get(model_type)
            defaults = client.default_problem(model=model_type) if info is not None else None
            result = client.solve(problem)
        except ValidationError as err:
            print(f"the service rejected {args.problem}:", file=sys.stderr)
            for e in err.errors:
                print(f"  {e.pointer}: {e.detail}", file=sys.stderr)
            return 2
        except OverloadedError as err:
            wait = f"; it asked to retry after {err.retry_after:g} s" if err.retry_after is not None else ""
            print(f"the service is still overloaded after {client.retries} retries{wait}", file=sys.stderr)
            return 3
        except ApiError as err:  # any other problem+json answer
            print(f"solve failed: {err}", file=sys.stderr)
            return 1
        except requests.RequestException as exc:
            print(f"cannot reach {args.url}: {exc}", file=sys.stderr)
            return 1

        print(f"problem     {args.problem}")
        print(f"model       {result.model}, {result.integrator} integrator")
        print(f"status      {result.status}")
        print(f"cost        {result.cost:.6f} (initial {result.initial_cost:.6f})")
        print(f"iterations  {result.iterations}")
        print(f"solve time  {result.solve_time_ms:.2f} ms, request id {result.request_id}")

        derivative = MODELS.get(result.model or "")
        integrate = INTEGRATORS.get(result.integrator or "")
        if info is None or defaults is None or derivative is None or integrate is None:
            print(f"\n(no local simulation of model {result.model!r} with {result.integrator!r})")
        else:
            assert defaults.model is not None and defaults.dt is not None
            parameters = {**defaults.model.parameters, **{k: v for k, v in given_model.items() if k != "type"}}
            dt = problem.get("dt", defaults.dt)
            goal = problem.get("goal_state", defaults.goal_state)
            ix, iy = info.position
            names = [q.name for q in info.state]
            itheta = names.index("θ")

            def step(x: Sequence[float], u: Sequence[float]) -> State:
                return integrate(derivative, x, u, parameters, dt)

            def miss(state: Sequence[float]) -> float:
                """Distance (m) between a state's position and the goal position."""
                return math.hypot(state[ix] - goal[ix], state[iy] - goal[iy])

            # Replaying ū_k from the nominal x0 must reproduce the service's trajectory.
            replay = rollout(result, result.states[0], step, closed_loop=False)
            drift = max(abs(a - b) for xa, xb in zip(replay, result.states) for a, b in zip(xa, xb))
            print(f"replay      max |x_k - x̄_k| = {drift:.2e} (local {result.integrator} vs service)")

            dx, dy, dtheta = args.perturb
            x0 = list(result.states[0])
            x0[ix] += dx
            x0[iy] += dy
            x0[itheta] += dtheta
            open_loop = rollout(result, x0, step, closed_loop=False)
            closed_loop = rollout(result, x0, step, closed_loop=True)
            print(f"\nperturbed start: dx = {dx:+g} m, dy = {dy:+g} m, dθ = {dtheta:+g} rad")
            print(f"  nominal      final miss {miss(result.states[-1]):8.4f} m")
            print(f"  open loop    final miss {miss(open_loop[-1]):8.4f} m   (u = ū)")
            print(f"  closed loop  final miss {miss(closed_loop[-1]):8.4f} m   (u = ū + K (x − x̄))")

        # What an invalid problem looks like: a ValidationError with a JSON pointer per field.
        try:
            client.solve({"dt": -1, "weights": {"state": [1, 1, -1, 1, 1, 1]}})
        except ValidationError as err:
            print(f"\nan invalid problem is rejected: {err.status} {err.title}")
            for e in err.errors:
                print(f"  {e.pointer}: {e.detail}")
        except ApiError as err:
            print(f"\nthe invalid-problem demo got another error: {err}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
