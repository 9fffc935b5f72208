"""Hard constraints and obstacle shapes: control, state and goal bounds,
circles and rectangles with a clearance, the constraint report, warnings,
the ``infeasible`` status, and their typed models."""

from __future__ import annotations

import copy
import json
from typing import Any, Dict

import pytest
from conftest import REPO_ROOT, ServiceProcess
from ilqr_client import (
    SOLVE_STATUSES,
    Bounds,
    Client,
    ConstraintReport,
    Constraints,
    ConstraintStatus,
    Obstacle,
    ObstacleStatus,
    Problem,
    SolveResult,
    SolverOptions,
    SolveWarning,
    TraceEntry,
    ValidationError,
    Warning,
)

DUBINS = REPO_ROOT / "examples" / "dubins_three_obstacles.json"


def dubins_problem() -> Dict[str, Any]:
    return dict(json.loads(DUBINS.read_text()))


@pytest.fixture(scope="module")
def dubins_result(service: ServiceProcess) -> SolveResult:
    """The answer for examples/dubins_three_obstacles.json, solved once."""
    with Client(service.url, timeout=30.0) as c:
        return c.solve(dubins_problem())


def test_the_dubins_example_meets_its_hard_constraints(dubins_result: SolveResult) -> None:
    result = dubins_result
    assert result.status == "converged" and result.converged and not result.infeasible
    assert result.constraint_violation is not None and result.constraint_violation <= 1e-6
    for v, omega in result.controls:
        assert 0.0 <= v <= 3.0 and -3.0 <= omega <= 3.0
    report = result.constraint_report
    assert isinstance(report, ConstraintReport)
    assert report.outer_iterations >= 1
    assert [status.obstacle for status in report.obstacles] == [0, 1, 2]
    assert all(isinstance(status, ObstacleStatus) for status in report.obstacles)
    assert all(status.smallest_distance >= -1e-6 for status in report.obstacles)
    assert isinstance(report.control, ConstraintStatus) and report.control.max_violation == 0.0
    assert report.goal is not None and report.state is None
    assert result.warnings == []
    # The trace says which outer iteration each row belongs to.
    assert result.trace is not None
    assert all(entry.outer_iteration is not None and entry.penalty is not None for entry in result.trace)
    assert result.trace[-1].outer_iteration == report.outer_iterations


def test_the_typed_dubins_problem_posts_the_same_document(client: Client, dubins_result: SolveResult) -> None:
    raw = dubins_problem()
    problem = Problem.from_dict(raw)
    assert isinstance(problem.constraints, Constraints)
    assert problem.constraints.control == Bounds(lower=[0.0, -3.0], upper=[3.0, 3.0])
    assert problem.constraints.goal_tolerance == [0.0, 0.0, 0.0]
    assert problem.obstacles is not None
    first = problem.obstacles[0]
    assert (first.shape, first.radius, first.clearance, first.weight) == ("circle", 0.425, 0.0, 0.0)
    assert first.hard and problem.extra == {} and first.extra == {}
    assert problem.to_dict() == raw
    assert client.solve(problem).cost == dubins_result.cost


def test_the_seed_result_warns_of_negative_thrust(seed_result: SolveResult) -> None:
    codes = [warning.code for warning in seed_result.warnings]
    assert "negative_thrust" in codes
    assert all(isinstance(w, SolveWarning) and w.message for w in seed_result.warnings)
    # No hard constraints: a violation of 0 and no report.
    assert seed_result.constraint_violation == 0.0 and seed_result.constraint_report is None
    assert Warning is SolveWarning


def test_a_goal_inside_a_hard_circle_is_infeasible(client: Client) -> None:
    assert "infeasible" in SOLVE_STATUSES
    result = client.solve({
        "model": {"type": "unicycle"},
        "obstacles": [{"shape": "circle", "center": [4.0, 0.0], "radius": 0.5, "clearance": 0, "weight": 0}],
        "constraints": {"goal_tolerance": [0.01, 0.01, 0.1]},
    })
    assert result.status == "infeasible" and result.infeasible and not result.converged
    assert result.constraint_violation is not None and result.constraint_violation > 1e-6
    assert result.constraint_report is not None and len(result.constraint_report.obstacles) == 1


def test_a_lower_bound_above_its_upper_bound_is_named_by_pointer(client: Client) -> None:
    problem = Problem(
        constraints=Constraints(control=Bounds(lower=[5.0, None], upper=[1.0, None])),
        solver=SolverOptions(constraint_tolerance=1e-6),
    )
    with pytest.raises(ValidationError) as info:
        client.solve(problem)
    assert "/constraints/control/lower/0" in [error.pointer for error in info.value.errors]


def test_problem_members_round_trip() -> None:
    raw: Dict[str, Any] = {
        "obstacles": [
            {"center": [1.0, 2.0]},
            {"shape": "rectangle", "center": [3.0, 1.0], "size": [1.0, 0.5], "angle": 0.3,
             "clearance": 0.1, "weight": 0.0, "future": True},
        ],
        "constraints": {
            "control": {"lower": [0.0, None], "upper": [None, 12.0]},
            "state": {"lower": [None, None, -0.5, None, None, None], "upper": [None, None, 0.5, None, None, None]},
            "goal_tolerance": [0.1] * 6,
            "later": {"x": 1},
        },
        "solver": {"constraint_tolerance": 1e-5},
    }
    problem = Problem.from_dict(copy.deepcopy(raw))
    assert problem.to_dict() == raw
    assert problem.constraints is not None and problem.constraints.extra == {"later": {"x": 1}}
    assert problem.obstacles is not None and problem.obstacles[1].extra == {"future": True}
    assert problem.constraints.state is not None and problem.constraints.state.lower == raw["constraints"]["state"]["lower"]
    # None fields are left out; an Obstacle keeps its positional fields.
    assert Obstacle([0.0, 0.0], 5.0).to_dict() == {"center": [0.0, 0.0], "weight": 5.0}
    assert Constraints().to_dict() == {} and Bounds(upper=[1.0, None]).to_dict() == {"upper": [1.0, None]}
    with pytest.raises(AttributeError, match="clearance"):
        Obstacle([0.0, 0.0]).clearence = 1.0  # type: ignore[attr-defined]


def test_result_members_round_trip(dubins_result: SolveResult, seed_result: SolveResult) -> None:
    from test_errors import _answer_of

    for result in (dubins_result, seed_result):
        answer = _answer_of(result)
        assert SolveResult.from_dict(answer) == result
    report = dubins_result.constraint_report
    assert report is not None
    assert ConstraintReport.from_dict(report.to_dict()) == report
    partial = {"outer_iterations": 2, "obstacles": [], "state": {"max_violation": 0.5, "active_steps": 3}}
    assert ConstraintReport.from_dict(partial).to_dict() == partial
    warning = {"code": "inside_obstacle", "message": "m"}
    assert SolveWarning.from_dict(warning).to_dict() == warning
    with pytest.raises(ValueError, match=r"^/constraint_report/obstacles/0/active_steps: expected an integer"):
        ConstraintReport.from_dict({"outer_iterations": 1, "obstacles": [
            {"obstacle": 0, "max_violation": 0.0, "active_steps": 1.5, "smallest_distance": 0.1}]})
    with pytest.raises(ValueError, match=r"^/warnings/0/code: expected a string"):
        SolveResult.from_dict({**_answer_of(seed_result), "warnings": [{"code": 1, "message": "m"}]})
    # An older service sends none of the new members.
    old = _answer_of(seed_result)
    for key in ("constraint_violation", "warnings"):
        del old[key]
    parsed = SolveResult.from_dict(old)
    assert (parsed.constraint_violation, parsed.constraint_report, parsed.warnings) == (None, None, [])
    row = TraceEntry.from_dict({**vars(seed_result.trace[0])} if seed_result.trace else {})
    assert row.outer_iteration is None and row.penalty is None


def test_plot_draws_shapes_clearances_and_bounds(dubins_result: SolveResult, tmp_path: Any) -> None:
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from ilqr_client.plot import plot_angle, plot_controls, plot_solution, save_figure

    problem = dubins_problem()
    problem["obstacles"] = problem["obstacles"][:2] + [
        {"shape": "rectangle", "center": [2.25, 2.25], "size": [0.6, 0.3], "angle": 0.5, "clearance": 0.1, "weight": 0},
    ]
    ax = Figure().subplots()
    plot_solution(dubins_result, problem, ax=ax)
    shapes = [patch for patch in ax.patches if patch.get_gid() == "obstacle shape"]
    outlines = [patch for patch in ax.patches if patch.get_gid() == "clearance"]
    assert len(shapes) == 3 and len(outlines) == 3
    assert shapes[0].get_radius() == pytest.approx(0.425)
    corners = shapes[2].get_xy()
    assert max(x for x, _ in corners) < 2.25 + 0.35 and min(x for x, _ in corners) > 2.25 - 0.35
    assert outlines[0].get_radius() == pytest.approx(0.425) and outlines[0].get_linestyle() == "--"
    labels = ax.get_legend_handles_labels()[1]
    assert {"obstacle shape", "clearance", "closest approach"} <= set(labels)

    ax = plot_controls(dubins_result, Problem.from_dict(dubins_problem()), ax=Figure().subplots())
    bounds = sorted(line.get_ydata()[0] for line in ax.lines if "bound" in str(line.get_label()))
    assert bounds == [-3.0, 0.0, 3.0, 3.0]
    assert ax.get_xlabel() == "t [s]"
    assert {"v", "ω"} <= set(ax.get_legend_handles_labels()[1])

    theta = {"constraints": {"state": {"lower": [None, None, -0.3, None, None, None],
                                       "upper": [None, None, 0.3, None, None, None]}}}
    seedless = SolveResult.from_dict({**_seedless_answer(dubins_result), "model": "quadrotor_2d"})
    ax = plot_angle(seedless, theta, ax=Figure().subplots())
    assert sorted(line.get_ydata()[0] for line in ax.lines if "bound" in str(line.get_label())) == [-0.3, 0.3]

    path = tmp_path / "dubins.png"
    save_figure(dubins_result, problem, path)
    assert path.read_bytes().startswith(b"\x89PNG")


def _seedless_answer(result: SolveResult) -> Dict[str, Any]:
    """A quadrotor-shaped answer (6-wide states) built from a result, for drawing only."""
    from test_errors import _answer_of

    answer = _answer_of(result)
    answer["states"] = [row + [0.0] * (6 - len(row)) for row in answer["states"]]
    answer.pop("gains")
    return answer
