"""The matplotlib helpers (skipped when matplotlib is not installed)."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import pytest
from ilqr_client import Client, Model, Problem, SolveResult
from ilqr_client.plot import plot_cost, plot_solution, save_figure


@pytest.fixture
def figure() -> Any:
    """A pyplot-free matplotlib figure on the Agg backend."""
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    return Figure()


def test_save_figure_writes_a_png(seed_result: SolveResult, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    path = tmp_path / "solution.png"
    save_figure(seed_result, {}, path)
    data = path.read_bytes()
    assert data.startswith(b"\x89PNG\r\n\x1a\n")
    assert len(data) > 10_000


def test_save_figure_writes_the_format_of_the_extension(seed_result: SolveResult, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    for name, magic in [("a.pdf", b"%PDF"), ("a.svg", b"<?xml"), ("a", b"\x89PNG")]:
        save_figure(seed_result, {}, tmp_path / name)
        assert (tmp_path / name).read_bytes().startswith(magic), name
    with pytest.raises(ValueError, match="xyz"):
        save_figure(seed_result, {}, tmp_path / "a.xyz")


def test_save_figure_without_trace(seed_result: SolveResult, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    import dataclasses

    path = tmp_path / "no-trace.png"
    save_figure(dataclasses.replace(seed_result, trace=None), None, path)
    assert path.read_bytes().startswith(b"\x89PNG")


def test_plot_solution_draws_obstacle_circles(seed_result: SolveResult, figure: Any) -> None:
    ax = figure.subplots()
    assert plot_solution(seed_result, Problem(), ax=ax) is ax
    circles = [patch for patch in ax.patches if hasattr(patch, "get_radius")]
    assert len(circles) == 1
    assert circles[0].get_radius() == pytest.approx(seed_result.closest_approach[0])
    assert tuple(circles[0].center) == (4.5, 4.5)
    labels = ax.get_legend_handles_labels()[1]
    assert {"trajectory", "start", "end", "goal", "obstacle", "closest approach"} <= set(labels)


def test_plot_solution_labels_an_obstacle_without_a_weight_with_the_default(seed_result: SolveResult, figure: Any) -> None:
    ax = figure.subplots()
    plot_solution(seed_result, {"obstacles": [{"center": [4.5, 4.5]}]}, ax=ax)
    assert [text.get_text() for text in ax.texts] == ["q=1000"]


def test_plot_solution_draws_a_unicycle_path(unicycle_result: SolveResult, figure: Any) -> None:
    ax = figure.subplots()
    plot_solution(unicycle_result, Problem(model=Model("unicycle")), ax=ax)
    lines = {line.get_label(): line for line in ax.lines}
    path = lines["trajectory"]
    assert list(path.get_xdata()) == [state[0] for state in unicycle_result.states]
    assert list(path.get_ydata()) == [state[1] for state in unicycle_result.states]
    # The unicycle's defaults: goal (4, 0), one obstacle at (2, 0.3) of weight 5.
    assert (list(lines["goal"].get_xdata()), list(lines["goal"].get_ydata())) == ([4.0], [0.0])
    circles = [patch for patch in ax.patches if hasattr(patch, "get_radius")]
    assert len(circles) == 1 and tuple(circles[0].center) == (2.0, 0.3)
    assert circles[0].get_radius() == pytest.approx(unicycle_result.closest_approach[0])
    assert [text.get_text() for text in ax.texts] == ["q=5"]
    # Heading arrows along θ, the third state entry.
    (arrows,) = [c for c in ax.collections if c.get_label() == "heading"]
    assert len(arrows.U) == len(unicycle_result.states[::5]) == 13
    theta = unicycle_result.states[5][2]
    assert math.atan2(arrows.V[1], arrows.U[1]) == pytest.approx(math.atan2(math.sin(theta), math.cos(theta)))
    assert ax.get_title().startswith("unicycle: converged")


def test_plot_solution_reads_the_position_entries(unicycle_result: SolveResult, figure: Any) -> None:
    # A model with its position elsewhere in the state (GET /models says
    # where): the path and the goal are read from those entries.
    import dataclasses

    swapped = dataclasses.replace(unicycle_result, model_position=(1, 0))
    ax = figure.subplots()
    plot_solution(swapped, {"model": {"type": "unicycle"}, "goal_state": [1.0, 2.0, 0.0]}, ax=ax)
    lines = {line.get_label(): line for line in ax.lines}
    assert list(lines["trajectory"].get_xdata()) == [state[1] for state in unicycle_result.states]
    assert (list(lines["goal"].get_xdata()), list(lines["goal"].get_ydata())) == ([2.0], [1.0])


def test_the_plot_s_defaults_are_the_service_s(client: Client) -> None:
    # plot_solution draws a problem's omitted goal and obstacles from its
    # own table of the built-in models' defaults: it must match the service.
    from ilqr_client.plot import _DEFAULTS

    infos = client.models()
    assert sorted(_DEFAULTS) == sorted(info.type for info in infos)
    for info in infos:
        problem = info.default_problem
        goal, obstacles = _DEFAULTS[info.type]
        assert problem.goal_state == list(goal), info.type
        assert problem.obstacles is not None
        assert [(tuple(o.center), o.weight) for o in problem.obstacles] == list(obstacles), info.type
    # And its table of each model's default dt, control names and θ entry.
    from ilqr_client.plot import _TIMING

    assert sorted(_TIMING) == sorted(info.type for info in infos)
    for info in infos:
        dt, controls, theta = _TIMING[info.type]
        assert info.default_problem.dt == dt, info.type
        assert tuple(q.name for q in info.control) == controls, info.type
        assert info.state[theta].name == "θ", info.type


def test_save_figure_of_a_unicycle(unicycle_result: SolveResult, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    path = tmp_path / "unicycle.png"
    save_figure(unicycle_result, {"model": {"type": "unicycle"}}, path)
    assert path.read_bytes().startswith(b"\x89PNG")


def test_plot_cost_is_log_scale(seed_result: SolveResult, figure: Any) -> None:
    ax = plot_cost(seed_result, ax=figure.subplots())
    assert ax.get_yscale() == "log"
    assert len(ax.lines[0].get_ydata()) == seed_result.iterations + 1
    # Iterations are whole numbers; so are the ticks, also when zoomed in
    # (on a few iterations matplotlib would tick every 0.5).
    ax.set_xlim(0, 3)
    ax.figure.canvas.draw()
    ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
    assert ticks and all(float(t).is_integer() for t in ticks), ticks


def test_plot_cost_of_a_zero_cost_result_is_linear(client: Any, figure: Any) -> None:
    # Every weight 0 and no obstacle: cost 0 from the start, `converged`.
    # A log scale has nothing to show there (matplotlib warned and drew an
    # empty panel).
    zero = {"weights": {"state": [0] * 6, "control": [0, 0], "terminal": [0] * 6}, "obstacles": []}
    result = client.solve(zero)
    assert (result.status, result.cost) == ("converged", 0.0)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ax = plot_cost(result, ax=figure.subplots())
    assert ax.get_yscale() == "linear"
    assert list(ax.lines[0].get_ydata()) == [0.0]


def test_plot_cost_needs_a_trace(seed_result: SolveResult) -> None:
    import dataclasses

    with pytest.raises(ValueError, match="trace"):
        plot_cost(dataclasses.replace(seed_result, trace=None))


def test_missing_matplotlib_is_explained(seed_result: SolveResult, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # makes `import matplotlib` fail
    with pytest.raises(ImportError, match=r"ilqr-client\[plot\]"):
        plot_solution(seed_result)
