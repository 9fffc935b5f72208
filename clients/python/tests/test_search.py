"""The search over routes: the seed's best route with its starts, the
single local solve on request, what given controls change, ``max_starts``,
and the typed models of the new members."""

from __future__ import annotations

import pytest
from conftest import SEED_COST, SEED_SINGLE_COST
from ilqr_client import Client, Problem, SolveResult, SolverOptions, StartReport, TraceEntry, ValidationError


def test_the_seed_searches_and_keeps_the_cheapest_route(seed_result: SolveResult) -> None:
    starts = seed_result.starts
    # The plain start goes west, so the west detour is not run again.
    assert [s.label for s in starts] == ["rest controls", "east of obstacle 0"]
    assert all(isinstance(s, StartReport) for s in starts)
    assert [s.chosen for s in starts] == [False, True]
    chosen = starts[1]
    assert (chosen.obstacle, chosen.side) == (0, "right")
    assert chosen.cost == seed_result.cost == pytest.approx(SEED_COST, rel=1e-6)
    assert chosen.iterations == seed_result.iterations
    assert chosen.guide_iterations is not None and 1 <= chosen.guide_iterations <= 15
    # The plain start is the paper's single solve.
    assert starts[0].cost == pytest.approx(SEED_SINGLE_COST, rel=1e-6)
    assert starts[0].obstacle is None and starts[0].guide_iterations is None
    assert all(s.status == "converged" and s.constraint_violation == 0.0 for s in starts)
    assert all(s.cost >= seed_result.cost for s in starts)
    # The trace is the chosen start's.
    assert seed_result.trace is not None and len(seed_result.trace) == chosen.iterations
    assert seed_result.trace[-1].cost == pytest.approx(seed_result.cost, rel=1e-12)
    # The east route: the path passes the obstacle at x > 4.5.
    nearest = min(seed_result.states, key=lambda x: (x[0] - 4.5) ** 2 + (x[1] - 4.5) ** 2)
    assert nearest[0] > 4.5


def test_multi_start_false_is_the_papers_single_solve(client: Client) -> None:
    result = client.solve(Problem(solver=SolverOptions(multi_start=False)))
    assert result.cost == pytest.approx(SEED_SINGLE_COST, rel=1e-6)
    assert len(result.starts) == 1
    assert result.starts[0].label == "rest controls" and result.starts[0].chosen
    assert result.starts[0].cost == result.cost


def test_given_controls_solve_once_unless_asked_to_search(client: Client, seed_result: SolveResult) -> None:
    hover = [[4.905, 4.905]] * 100
    once = client.solve({"initial_controls": hover})
    assert [s.label for s in once.starts] == ["initial_controls"]
    assert once.cost == pytest.approx(SEED_SINGLE_COST, rel=1e-6)
    searched = client.solve({"initial_controls": hover, "solver": {"multi_start": True}})
    assert len(searched.starts) == 2 and searched.starts[0].label == "initial_controls"
    assert searched.cost == pytest.approx(SEED_COST, rel=1e-6)
    # A warm start is given controls too.
    warm = client.solve({"warm_start": {"controls": seed_result.controls}})
    assert [s.label for s in warm.starts] == ["warm_start"]
    assert warm.cost == pytest.approx(SEED_COST, rel=1e-6)


def test_max_starts_caps_the_search(client: Client) -> None:
    one = client.solve({"solver": {"max_starts": 1}})
    assert len(one.starts) == 1 and one.cost == pytest.approx(SEED_SINGLE_COST, rel=1e-6)
    # Two are enough for the seed: the plain start and the side it did not take.
    two = client.solve({"solver": {"max_starts": 2}})
    assert [s.label for s in two.starts] == ["rest controls", "east of obstacle 0"]
    assert two.cost == pytest.approx(SEED_COST, rel=1e-6)
    # A plain start that does not converge decides nothing: both sides run.
    capped = client.solve({"solver": {"max_iterations": 5}})
    assert [s.label for s in capped.starts] == ["rest controls", "west of obstacle 0", "east of obstacle 0"]
    for bad in (0, 33, 2.5, "3", None):
        with pytest.raises(ValidationError) as info:
            client.solve({"solver": {"max_starts": bad}})
        assert [e.pointer for e in info.value.errors] == ["/solver/max_starts"], bad
    with pytest.raises(ValidationError) as info:
        client.solve({"solver": {"multi_start": "yes"}})
    assert [e.pointer for e in info.value.errors] == ["/solver/multi_start"]


def test_every_start_is_deterministic(client: Client, seed_result: SolveResult) -> None:
    again = client.solve({})
    assert [(s.label, s.cost, s.iterations, s.chosen) for s in again.starts] == [
        (s.label, s.cost, s.iterations, s.chosen) for s in seed_result.starts
    ]
    assert again.states == seed_result.states and again.controls == seed_result.controls


def test_the_new_members_round_trip() -> None:
    options = SolverOptions(multi_start=False, max_starts=3)
    assert options.to_dict() == {"multi_start": False, "max_starts": 3}
    assert SolverOptions.from_dict({"multi_start": True, "max_starts": 5}) == SolverOptions(
        multi_start=True, max_starts=5
    )
    row = TraceEntry.from_dict(
        {"iteration": 1, "cost": 2.0, "expected_reduction": 1.0, "actual_reduction": 1.0, "step_size": 1.0,
         "regularization": 0.0, "feedforward_norm": 0.1, "elapsed_ms": 0.2, "start": 2}
    )
    assert row.start == 2
    start = StartReport.from_dict(
        {"label": "east of obstacle 0", "obstacle": 0, "side": "right", "status": "converged", "cost": 1.0,
         "iterations": 3, "guide_iterations": 4, "constraint_violation": 0.0, "solve_time_ms": 0.5, "chosen": True}
    )
    assert (start.obstacle, start.side, start.guide_iterations, start.chosen) == (0, "right", 4, True)
    with pytest.raises(ValueError, match="/starts/-/cost"):
        StartReport.from_dict({"label": "x", "status": "converged", "cost": "no", "iterations": 1,
                               "constraint_violation": 0, "solve_time_ms": 0, "chosen": False})

