"""Plots of solve results, drawn with matplotlib (an optional dependency).

Install it with ``pip install 'ilqr-client[plot]'``. matplotlib is imported
only when a function here is called, so ``import ilqr_client.plot`` works
without it; the call then raises an :class:`ImportError` that says what to
install.

* :func:`plot_solution`: the (x, y) path of any model (the state entries
  of its position), start, end and goal markers, obstacle centres and
  circles at the closest approach; for the unicycle, heading arrows.
* :func:`plot_cost`: cost per iteration from the trace, on a log scale.
* :func:`save_figure`: both panels side by side, written as a PNG (uses no
  pyplot state, so it is safe in scripts, servers and threads).
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any, List, Mapping, Optional, Sequence, Tuple, Union

from .models import DEFAULT_MODEL, Problem, SolveResult

# matplotlib is optional, so its Axes type exists only for type checkers; at
# run time the name is Any, so typing.get_type_hints resolves these
# functions' annotations without matplotlib.
if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes
else:
    Axes = Any

__all__ = ["plot_solution", "plot_cost", "save_figure"]

# What the service gives an obstacle that sets no weight (the seed's), for every model.
_DEFAULT_OBSTACLE_WEIGHT = 1000.0

_Obstacles = Tuple[Tuple[Tuple[float, float], float], ...]

#: Each built-in model's default goal state and obstacles: what the service
#: uses when a problem omits them (``GET /models``' default problems; a test
#: checks them against the service). A problem of a model not named here
#: that omits them has them drawn only when it gives them.
_DEFAULTS: Mapping[str, Tuple[Tuple[float, ...], _Obstacles]] = {
    "quadrotor_2d": ((4.0, 9.0, 0.0, 0.0, 0.0, 0.0), (((4.5, 4.5), _DEFAULT_OBSTACLE_WEIGHT),)),
    "unicycle": ((4.0, 0.0, 0.0), (((2.0, 0.3), 5.0),)),
}

#: The state entry of the heading θ (counter-clockwise from the x axis) of
#: the models whose path gets heading arrows.
_HEADING = {"unicycle": 2}

#: How many heading arrows a path gets at most.
_ARROWS = 12

PathLike = Union[str, "os.PathLike[str]"]


def _require_matplotlib() -> Any:
    """Import matplotlib, or explain how to install it."""
    try:
        import matplotlib
    except ImportError as exc:
        raise ImportError(
            "ilqr_client.plot needs matplotlib; install it with: pip install 'ilqr-client[plot]'"
        ) from exc
    return matplotlib


def _new_axes() -> Axes:
    """A fresh pyplot figure's axes (only used when the caller passes none)."""
    _require_matplotlib()
    import matplotlib.pyplot as plt

    _, ax = plt.subplots()
    return ax


def _model_of(result: SolveResult, problem: Optional[Mapping[str, Any]]) -> str:
    """The model solved for: the result's, else the problem's, else the default."""
    if result.model is not None:
        return result.model
    model = problem.get("model") if problem is not None else None
    kind = model.get("type") if isinstance(model, Mapping) else None
    return kind if isinstance(kind, str) else DEFAULT_MODEL


def _goal_and_obstacles(
    problem: Optional[Mapping[str, Any]], model: str,
) -> Tuple[Optional[Sequence[float]], List[Tuple[Sequence[float], float]]]:
    """The goal state and obstacles the service solved for.

    With no problem nothing is known (``None, []``). A problem that omits the
    goal or the obstacles was solved with the model's defaults, so those are
    used (none for a model this module does not know).
    """
    if problem is None:
        return None, []
    default_goal, default_obstacles = _DEFAULTS.get(model, (None, ()))
    goal = problem.get("goal_state")
    if goal is None:
        goal = default_goal
    raw_obstacles = problem.get("obstacles")
    if raw_obstacles is None:
        return goal, list(default_obstacles)
    obstacles = []
    for obstacle in raw_obstacles:
        if not isinstance(obstacle, Mapping):  # an Obstacle dataclass
            obstacle = obstacle.to_dict()
        weight = obstacle.get("weight")
        obstacles.append((obstacle["center"], _DEFAULT_OBSTACLE_WEIGHT if weight is None else float(weight)))
    return goal, obstacles


def plot_solution(
    result: SolveResult,
    problem: Union[Problem, Mapping[str, Any], None] = None,
    ax: Optional[Axes] = None,
) -> Axes:
    """Draw the optimised path in the plane, for any model.

    The position is read from the state entries the model keeps it in
    (:attr:`SolveResult.position_entries`). Draws the path, a start marker,
    an end marker and, when ``problem`` is given, the goal position and each
    obstacle's centre with a dashed circle whose radius is the trajectory's
    closest approach to it (so the path touches the circle and never enters
    it). A unicycle's path gets arrows along its heading θ.

    Args:
        result: The solve result.
        problem: The problem that was solved (a :class:`Problem` or a dict).
            Fields it omits are taken to be the model's defaults, as the
            service does (for the models this client version knows). Without
            it, goal and obstacles are not drawn.
        ax: Axes to draw on; a new pyplot figure when omitted.

    Returns:
        The axes drawn on.

    Raises:
        ImportError: if matplotlib is not installed.
    """
    _require_matplotlib()
    from matplotlib.patches import Circle

    if ax is None:
        ax = _new_axes()
    document = problem.to_dict() if isinstance(problem, Problem) else problem
    model = _model_of(result, document)
    ix, iy = result.position_entries
    xs = [state[ix] for state in result.states]
    ys = [state[iy] for state in result.states]
    goal, obstacles = _goal_and_obstacles(document, model)
    ax.plot(xs, ys, "-", color="tab:blue", linewidth=1.5, label="trajectory")
    heading = _HEADING.get(model)
    if heading is not None and len(result.states) > 1:
        step = max(1, len(result.states) // _ARROWS)
        knots = result.states[::step]
        # Arrows of one length in data units: 8 % of the path's extent.
        length = 0.08 * (max(max(xs) - min(xs), max(ys) - min(ys)) or 1.0)
        ax.quiver(
            [state[ix] for state in knots], [state[iy] for state in knots],
            [length * math.cos(state[heading]) for state in knots],
            [length * math.sin(state[heading]) for state in knots],
            color="tab:purple", alpha=0.8, angles="xy", scale_units="xy", scale=1, pivot="tail",
            width=0.004, label="heading",
        )
    ax.plot(xs[0], ys[0], "o", color="tab:green", markersize=8, label="start")
    if goal is not None:  # drawn before the end marker, which usually sits on it
        ax.plot(goal[ix], goal[iy], "*", color="tab:orange", markersize=16, label="goal")
    ax.plot(xs[-1], ys[-1], "s", color="tab:blue", markersize=6, label="end")
    for j, (center, weight) in enumerate(obstacles):
        ax.plot(center[0], center[1], "x", color="tab:red", markersize=9, mew=2,
                label="obstacle" if j == 0 else None)
        ax.annotate(f"q={weight:g}", (center[0], center[1]), textcoords="offset points",
                    xytext=(6, 6), fontsize=8, color="tab:red")
        if j < len(result.closest_approach):
            ax.add_patch(Circle(
                (center[0], center[1]), result.closest_approach[j], fill=False,
                linestyle="--", edgecolor="tab:red", alpha=0.7,
                label="closest approach" if j == 0 else None,
            ))

    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{model}: {result.status}, cost {result.cost:.6g}")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return ax


def plot_cost(result: SolveResult, ax: Optional[Axes] = None) -> Axes:
    """Draw the cost per iteration, on a log scale when every cost is positive.

    Iteration 0 is the initial guess's cost; iterations whose step was
    rejected (``step_size == 0``) are marked with red crosses. A history
    that reaches 0 (every weight 0, say: a valid ``converged`` answer) has no
    log scale and is drawn on a linear one.

    Args:
        result: A solve result with a trace (solved with ``output.trace`` true,
            the default).
        ax: Axes to draw on; a new pyplot figure when omitted.

    Returns:
        The axes drawn on.

    Raises:
        ValueError: if the result has no trace.
        ImportError: if matplotlib is not installed.
    """
    if result.trace is None:
        raise ValueError("the result has no trace: solve with output.trace = true")
    _require_matplotlib()
    if ax is None:
        ax = _new_axes()
    costs = result.cost_history
    ax.plot(range(len(costs)), costs, "o-", color="tab:blue", markersize=3, label="cost")
    rejected = [(entry.iteration, entry.cost) for entry in result.trace if entry.step_size == 0]
    if rejected:
        ax.plot([it for it, _ in rejected], [c for _, c in rejected], "x", color="tab:red",
                markersize=7, label="step rejected")
    if all(c > 0 for c in costs):
        ax.set_yscale("log")
    ax.set_xlabel("iteration")
    from matplotlib.ticker import MaxNLocator  # matplotlib is present: checked above

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))  # no ticks at iteration 2.5
    ax.set_ylabel("cost J")
    ax.set_title(f"cost: {result.iterations} iterations, {result.solve_time_ms:.1f} ms")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(loc="best", fontsize="small")
    return ax


def save_figure(
    result: SolveResult,
    problem: Union[Problem, Mapping[str, Any], None],
    path: PathLike,
    *,
    dpi: int = 100,
) -> None:
    """Write a two-panel figure: the trajectory (left) and the cost history (right).

    The format follows the file's extension (``.png``, ``.pdf``, ``.svg``,
    any matplotlib writes; PNG without one); an unknown one raises
    ``ValueError``.

    Uses :class:`matplotlib.figure.Figure` directly, not pyplot, so it needs
    no GUI backend and leaves pyplot's global state alone. Without a trace
    the right panel says so instead of raising.

    Args:
        result: The solve result.
        problem: The problem that was solved, or ``None`` (see :func:`plot_solution`).
        path: Where to write the figure.
        dpi: Resolution.

    Raises:
        ImportError: if matplotlib is not installed.
        ValueError: if matplotlib cannot write the extension's format.
    """
    _require_matplotlib()
    from matplotlib.figure import Figure

    figure = Figure(figsize=(12, 5))
    left, right = figure.subplots(1, 2)
    plot_solution(result, problem, ax=left)
    if result.trace is not None:
        plot_cost(result, ax=right)
    else:
        right.text(0.5, 0.5, "no trace\n(solve with output.trace = true)",
                   ha="center", va="center", transform=right.transAxes)
        right.set_axis_off()
    figure.tight_layout()
    # Without `format` matplotlib takes it from the extension; a path without
    # one gets PNG, written at the path as given (matplotlib itself would
    # append ".png").
    path = os.fspath(path)
    figure.savefig(path, dpi=dpi, format=None if os.path.splitext(path)[1] else "png")
