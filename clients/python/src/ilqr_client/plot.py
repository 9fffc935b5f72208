"""Plots of solve results, drawn with matplotlib (an optional dependency).

Install it with ``pip install 'ilqr-client[plot]'``. matplotlib is imported
only when a function here is called, so ``import ilqr_client.plot`` works
without it; the call then raises an :class:`ImportError` that says what to
install.

* :func:`plot_solution`: the (x, y) path of any model (the state entries
  of its position), start, end and goal markers, obstacle centres, shapes
  (circles, rotated rectangles), the clearance outline of hard obstacles
  (dashed) and circles at the closest approach; for the unicycle, heading
  arrows.
* :func:`plot_cost`: cost per iteration from the trace, on a log scale.
* :func:`plot_controls`: the controls against time, with the problem's
  control bounds as horizontal lines.
* :func:`plot_angle`: the heading or pitch θ against time, with the
  problem's state bounds on it.
* :func:`save_figure`: the four panels, written as a PNG (uses no
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

__all__ = ["plot_solution", "plot_cost", "plot_controls", "plot_angle", "save_figure"]

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

#: Each built-in model's default time step dt (s), its controls' names and
#: the state entry of its angle θ (``GET /models``; a test checks them
#: against the service). A problem of another model that omits ``dt`` is
#: drawn against the step index, with generic control names.
_TIMING: Mapping[str, Tuple[float, Tuple[str, ...], int]] = {
    "quadrotor_2d": (0.05, ("u1", "u2"), 2),
    "unicycle": (0.1, ("v", "ω"), 2),
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
) -> Tuple[Optional[Sequence[float]], List[Mapping[str, Any]]]:
    """The goal state and obstacles (as JSON objects, ``weight`` filled in)
    the service solved for.

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
        return goal, [{"center": center, "weight": weight} for center, weight in default_obstacles]
    obstacles: List[Mapping[str, Any]] = []
    for obstacle in raw_obstacles:
        if not isinstance(obstacle, Mapping):  # an Obstacle dataclass
            obstacle = obstacle.to_dict()
        weight = obstacle.get("weight")
        obstacles.append({**obstacle, "weight": _DEFAULT_OBSTACLE_WEIGHT if weight is None else float(weight)})
    return goal, obstacles


def _rectangle_outline(obstacle: Mapping[str, Any], offset: float) -> List[Tuple[float, float]]:
    """The outline of a rotated rectangle grown by ``offset`` (m): its
    corners rounded with quarter circles for ``offset > 0``, a smaller
    rectangle for ``offset < 0``, in the plane's coordinates."""
    cx, cy = float(obstacle["center"][0]), float(obstacle["center"][1])
    width, height = (float(v) for v in obstacle.get("size") or (0.0, 0.0))
    angle = float(obstacle.get("angle") or 0.0)
    hw, hh = width / 2, height / 2
    local: List[Tuple[float, float]] = []
    if offset > 0:
        # Corners counter-clockwise from (+, +), each with its quarter arc.
        for k, (sx, sy) in enumerate(((1, 1), (-1, 1), (-1, -1), (1, -1))):
            for i in range(9):
                a = (k + i / 8) * math.pi / 2
                local.append((sx * hw + offset * math.cos(a), sy * hh + offset * math.sin(a)))
    else:
        hw, hh = max(hw + offset, 0.0), max(hh + offset, 0.0)
        local = [(hw, hh), (-hw, hh), (-hw, -hh), (hw, -hh)]
    c, s = math.cos(angle), math.sin(angle)
    return [(cx + c * x - s * y, cy + s * x + c * y) for x, y in local]


def _draw_obstacle(ax: Axes, obstacle: Mapping[str, Any], first: bool, first_hard: bool) -> None:
    """Draw an obstacle's shape (a circle or a rectangle; nothing for a
    point) and, for a hard one, its clearance outline, dashed."""
    from matplotlib.patches import Circle, Polygon

    shape = obstacle.get("shape") or "point"
    center = (float(obstacle["center"][0]), float(obstacle["center"][1]))
    style = dict(facecolor="tab:red", edgecolor="tab:red", alpha=0.25)
    if shape == "circle":
        radius = float(obstacle.get("radius") or 0.0)
        ax.add_patch(Circle(center, radius, gid="obstacle shape",
                            label="obstacle shape" if first else None, **style))
    elif shape == "rectangle":
        ax.add_patch(Polygon(_rectangle_outline(obstacle, 0.0), closed=True, gid="obstacle shape",
                             label="obstacle shape" if first else None, **style))
    else:
        radius = 0.0
    clearance = obstacle.get("clearance")
    if clearance is None:
        return
    clearance = float(clearance)
    outline = dict(fill=False, linestyle="--", edgecolor="black", linewidth=1.0, gid="clearance",
                   label="clearance" if first_hard else None)
    if shape == "rectangle":
        ax.add_patch(Polygon(_rectangle_outline(obstacle, clearance), closed=True, **outline))
    elif radius + clearance > 0:
        ax.add_patch(Circle(center, radius + clearance, **outline))


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
    document = _document(problem)
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
    hard = [j for j, obstacle in enumerate(obstacles) if obstacle.get("clearance") is not None]
    shaped = [j for j, obstacle in enumerate(obstacles) if (obstacle.get("shape") or "point") != "point"]
    for j, obstacle in enumerate(obstacles):
        center, weight = obstacle["center"], obstacle["weight"]
        _draw_obstacle(ax, obstacle, first=bool(shaped) and j == shaped[0], first_hard=bool(hard) and j == hard[0])
        ax.plot(center[0], center[1], "x", color="tab:red", markersize=9, mew=2,
                label="obstacle" if j == 0 else None)
        note = f"q={weight:g}" if obstacle.get("clearance") is None else f"q={weight:g}, d≥{obstacle['clearance']:g}"
        ax.annotate(note, (center[0], center[1]), textcoords="offset points",
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


def _document(problem: Union[Problem, Mapping[str, Any], None]) -> Optional[Mapping[str, Any]]:
    """The problem as its JSON document (``None`` stays ``None``)."""
    return problem.to_dict() if isinstance(problem, Problem) else problem


def _times(result: SolveResult, problem: Optional[Mapping[str, Any]], model: str, count: int) -> Tuple[List[float], str]:
    """``count`` knot times k·dt (dt the problem's, else the model's
    default) and the axis label; the step index for an unknown dt."""
    dt = problem.get("dt") if problem is not None else None
    if dt is None and model in _TIMING:
        dt = _TIMING[model][0]
    if dt is None:
        return [float(k) for k in range(count)], "step k"
    return [k * float(dt) for k in range(count)], "t [s]"


def _bounds(problem: Optional[Mapping[str, Any]], part: str, entry: int) -> List[Tuple[str, float]]:
    """The lower and upper bounds of ``constraints.<part>`` on one entry
    (``("lower", value)``, ``("upper", value)``; those given and not null)."""
    constraints = problem.get("constraints") if problem is not None else None
    if constraints is not None and not isinstance(constraints, Mapping):
        constraints = constraints.to_dict()
    bounds = constraints.get(part) if constraints else None
    if bounds is not None and not isinstance(bounds, Mapping):
        bounds = bounds.to_dict()
    found = []
    for side in ("lower", "upper"):
        values = bounds.get(side) if bounds else None
        if values is not None and entry < len(values) and values[entry] is not None:
            found.append((side, float(values[entry])))
    return found


def plot_controls(
    result: SolveResult,
    problem: Union[Problem, Mapping[str, Any], None] = None,
    ax: Optional[Axes] = None,
) -> Axes:
    """Draw each control against time (held over its step), with the
    problem's ``constraints.control`` bounds as dashed horizontal lines in
    the control's colour.

    Args:
        result: The solve result.
        problem: The problem that was solved, for ``dt`` (else the model's
            default) and the bounds; without it no bounds are drawn.
        ax: Axes to draw on; a new pyplot figure when omitted.

    Returns:
        The axes drawn on.

    Raises:
        ImportError: if matplotlib is not installed.
    """
    _require_matplotlib()
    if ax is None:
        ax = _new_axes()
    document = _document(problem)
    model = _model_of(result, document)
    times, xlabel = _times(result, document, model, len(result.controls) + 1)
    names = _TIMING[model][1] if model in _TIMING else ()
    width = len(result.controls[0]) if result.controls else 0
    for i in range(width):
        name = names[i] if i < len(names) else f"u[{i}]"
        values = [u[i] for u in result.controls]
        (line,) = ax.step(times, values + values[-1:], where="post", label=name)
        for side, value in _bounds(document, "control", i):
            ax.axhline(value, linestyle="--", color=line.get_color(), linewidth=1.0, alpha=0.8,
                       label=f"{name} {side} bound")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("control")
    ax.set_title(f"{model}: controls")
    ax.grid(True, alpha=0.3)
    if width:
        ax.legend(loc="best", fontsize="small")
    return ax


def plot_angle(
    result: SolveResult,
    problem: Union[Problem, Mapping[str, Any], None] = None,
    ax: Optional[Axes] = None,
) -> Axes:
    """Draw the angle θ (the quadrotor's pitch, the unicycle's heading)
    against time, with the problem's ``constraints.state`` bounds on it as
    dashed horizontal lines.

    Args:
        result: The solve result, of a model whose θ entry this client
            version knows (``quadrotor_2d``, ``unicycle``).
        problem: The problem that was solved, for ``dt`` and the bounds.
        ax: Axes to draw on; a new pyplot figure when omitted.

    Returns:
        The axes drawn on.

    Raises:
        ValueError: for a model whose θ entry is unknown.
        ImportError: if matplotlib is not installed.
    """
    document = _document(problem)
    model = _model_of(result, document)
    if model not in _TIMING:
        raise ValueError(f"which state entry is θ of model {model!r} is not known")
    _require_matplotlib()
    if ax is None:
        ax = _new_axes()
    entry = _TIMING[model][2]
    times, xlabel = _times(result, document, model, len(result.states))
    ax.plot(times, [state[entry] for state in result.states], "-", color="tab:blue", label="θ")
    for side, value in _bounds(document, "state", entry):
        ax.axhline(value, linestyle="--", color="tab:red", linewidth=1.0, label=f"θ {side} bound")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("θ [rad]")
    ax.set_title(f"{model}: θ")
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
    """Write a four-panel figure: the trajectory and the cost history (top),
    the controls and θ against time (bottom; θ only for the models whose θ
    entry this client version knows).

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

    figure = Figure(figsize=(12, 9))
    (left, right), (controls, angle) = figure.subplots(2, 2)
    plot_solution(result, problem, ax=left)
    plot_controls(result, problem, ax=controls)
    if _model_of(result, _document(problem)) in _TIMING:
        plot_angle(result, problem, ax=angle)
    else:
        angle.set_axis_off()
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
