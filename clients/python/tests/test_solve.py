"""Successful calls against the real service: solving, the default problem, output options."""

from __future__ import annotations

import dataclasses
import math

import pytest
import requests
from conftest import SEED_COST, ServiceProcess, busy_problem
from ilqr_client import (
    Client,
    Gains,
    Obstacle,
    OutputOptions,
    Problem,
    SolveResult,
    SolverOptions,
    TraceEntry,
    Weights,
)


def test_health_and_ready(client: Client) -> None:
    assert client.health() is True
    assert client.ready() is True


def test_seed_problem_converges(seed_result: SolveResult) -> None:
    result = seed_result
    assert result.status == "converged"
    assert result.converged
    assert result.cost == pytest.approx(SEED_COST, rel=1e-6)
    assert result.initial_cost > result.cost
    assert result.goal_distance < 0.01
    assert result.solve_time_ms > 0 and result.queue_time_ms >= 0
    assert result.request_id

    assert len(result.states) == 101 and all(len(state) == 6 for state in result.states)
    assert len(result.controls) == 100 and all(len(control) == 2 for control in result.controls)
    assert result.horizon == 100
    assert result.states[0] == [5.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    assert len(result.closest_approach) == 1 and result.closest_approach[0] > 0
    assert result.convexified_after_iteration is None
    assert result.convex_model_at_end is None


def test_a_long_flight_reports_the_convex_fallback(client: Client) -> None:
    # 200 s from a guess a hair above hover: the exact Hessian gets nowhere
    # after 2 iterations, the convex model of the cost takes over, and the
    # exact Hessian confirms the minimum it finds.
    result = client.solve(
        {"horizon": 4000, "initial_controls": [[4.9051, 4.9051]] * 4000, "output": {"gains": False}}
    )
    assert result.status == "converged"
    assert result.convexified_after_iteration == 2
    assert result.convex_model_at_end is False
    # Which model each iteration used: exact, exact, convex ..., exact again.
    assert result.trace is not None
    convex = [entry.convex_model for entry in result.trace]
    back = max(i for i, c in enumerate(convex) if c) + 1
    assert convex[:2] == [False, False] and all(convex[2:back]) and not any(convex[back:]), convex
    assert result.cost < 0.05 * result.initial_cost


def test_seed_problem_gains(seed_result: SolveResult) -> None:
    gains = seed_result.gains
    assert isinstance(gains, Gains)
    assert len(gains.feedback) == 100
    assert all(len(k) == 2 and all(len(row) == 6 for row in k) for k in gains.feedback)
    assert len(gains.feedforward) == 100 and all(len(d) == 2 for d in gains.feedforward)
    # The seed converges through the unregularised pass: undamped gains.
    assert gains.regularization == 0.0
    assert gains.about_previous_iterate is False
    # On the nominal trajectory the feedback policy reproduces the nominal controls.
    k = 42
    state, control = seed_result.states[k], seed_result.controls[k]
    assert gains.control(k, state, state, control) == pytest.approx(control)
    # Off it, the correction is K_k times the deviation: here 0.1 m in x, column 0 of K_k.
    moved = [state[0] + 0.1, *state[1:]]
    expected = [control[i] + 0.1 * gains.feedback[k][i][0] for i in range(2)]
    assert gains.control(k, moved, state, control) == pytest.approx(expected)
    with pytest.raises(ValueError):
        gains.control(k, state[:5], state, control)
    # Steps are 0..N-1: -1 is not Python's "last", it is a mistake.
    for bad in (-1, 100):
        with pytest.raises(IndexError, match=r"step k must be in 0\.\.99"):
            gains.control(bad, state, state, control)
    # A step is an integer: True read as step 1, 1.0 failed inside list indexing.
    for not_a_step in (True, 1.0, "1"):
        with pytest.raises(TypeError, match=r"step k must be an integer"):
            gains.control(not_a_step, state, state, control)  # type: ignore[arg-type]


def test_pandas_vectors_and_tables_are_sent_as_arrays(client: Client, seed_result: SolveResult) -> None:
    # A Series and a DataFrame have a to_dict, which gave {index: value}
    # objects and a 422 ("expected an array of length 6").
    pd = pytest.importorskip("pandas")
    problem = {
        "initial_state": pd.Series([5.0, 0.0, 0.0, 0.0, 0.0, 0.0], index=list("xyθuvw")),
        "initial_controls": pd.DataFrame(seed_result.controls, columns=["u1", "u2"]),
    }
    assert client.solve(problem).initial_cost == seed_result.cost
    edited = Problem(initial_state=pd.Series([5.0, 0.0, 0.0, 0.0, 0.0, 0.0]))
    assert client.solve(edited).cost == seed_result.cost


def test_compress_false_asks_for_an_uncompressed_answer(service: ServiceProcess) -> None:
    for compress, encoding in ((True, "gzip"), (False, None)):
        seen: list[requests.Response] = []
        with Client(service.url, compress=compress) as c:
            c.session.hooks["response"].append(lambda r, *args, **kwargs: seen.append(r))
            c.solve({})
        assert seen[-1].headers.get("Content-Encoding") == encoding


def test_seed_problem_trace(seed_result: SolveResult) -> None:
    trace = seed_result.trace
    assert trace, "trace should be present and non-empty"
    assert all(isinstance(entry, TraceEntry) for entry in trace)
    assert [entry.iteration for entry in trace] == list(range(1, len(trace) + 1))
    assert seed_result.iterations == len(trace)
    costs = seed_result.cost_history
    assert costs[0] == seed_result.initial_cost
    assert all(later <= earlier for earlier, later in zip(costs, costs[1:])), costs
    assert trace[-1].cost == seed_result.cost
    # False, not None: a service that dropped the field would pass `not any`.
    assert all(entry.convex_model is False for entry in trace)


def test_none_and_empty_problem_are_the_seed(client: Client, seed_result: SolveResult) -> None:
    assert client.solve().cost == seed_result.cost
    assert client.solve(Problem()).cost == seed_result.cost


def test_default_problem_round_trips(client: Client, service: ServiceProcess, seed_result: SolveResult) -> None:
    problem = client.default_problem()
    assert isinstance(problem, Problem)
    assert problem.horizon == 100 and problem.dt == 0.05
    assert problem.model is not None and problem.model.type == "quadrotor_2d"
    assert problem.obstacles == [Obstacle(center=[4.5, 4.5], weight=1000.0)]
    assert problem.extra == {}

    # Posting the parsed problem back solves the same problem.
    assert client.solve(problem).cost == seed_result.cost

    # The raw document (with its explicit nulls) posts back too, and parsing
    # loses nothing but the nulls.
    raw = requests.get(f"{service.url}/problems/default", timeout=10).json()
    assert client.solve(raw).cost == seed_result.cost
    without_nulls = {key: value for key, value in raw.items() if value is not None}
    without_nulls["solver"] = {k: v for k, v in raw["solver"].items() if v is not None}
    assert problem.to_dict() == without_nulls


def test_edited_default_problem(client: Client) -> None:
    problem = client.default_problem()
    problem.horizon = 40
    problem.obstacles = []
    problem.output = OutputOptions(gains=False, trace=True)
    result = client.solve(problem)
    assert len(result.states) == 41 and len(result.controls) == 40
    assert result.closest_approach == []
    assert result.gains is None and result.trace is not None


def test_warm_start_from_a_result_is_exact(client: Client, seed_result: SolveResult) -> None:
    # The result's controls, posted back as the initial guess, roll out to
    # the result's own cost bit for bit: every number survives JSON both
    # ways (the service parses with serde_json's exact float parser).
    problem = Problem(initial_controls=seed_result.controls, solver=SolverOptions(max_iterations=1))
    warm = client.solve(problem)
    assert warm.initial_cost == seed_result.cost
    assert warm.cost <= seed_result.cost


def test_output_flags_omit_gains_and_trace(client: Client, service: ServiceProcess) -> None:
    problem = {"output": {"gains": False, "trace": False}}
    result = client.solve(problem)
    assert result.gains is None
    assert result.trace is None
    assert result.cost_history == []
    assert len(result.states) == 101

    raw = requests.post(f"{service.url}/solve", json=problem, timeout=30).json()
    assert "gains" not in raw and "trace" not in raw


def test_time_limit_returns_best_trajectory(client: Client) -> None:
    problem = Problem(
        horizon=5000,
        dt=0.001,
        solver=SolverOptions(time_limit_ms=50, tolerance=0, max_iterations=10000),
        output=OutputOptions(gains=False, trace=False),
    )
    result = client.solve(problem)
    assert result.status == "time_limit"
    assert not result.converged
    assert len(result.states) == 5001 and len(result.controls) == 5000
    assert math.isfinite(result.cost)


def test_request_id_is_sent_and_echoed(client: Client) -> None:
    result = client.solve({"horizon": 5, "output": {"gains": False, "trace": False}}, request_id="client-test-1")
    assert result.request_id == "client-test-1"


def test_server_timing_is_read_into_the_result(seed_result: SolveResult) -> None:
    # The header's milliseconds by name: what the time budget covers (solve)
    # and what it does not (queue, encode), without a raw request.
    timing = seed_result.server_timing
    assert timing is not None and set(timing) == {"queue", "solve", "encode"}, timing
    assert all(value >= 0 for value in timing.values()), timing
    assert timing["solve"] == pytest.approx(seed_result.solve_time_ms, abs=1e-3)
    assert timing["queue"] == pytest.approx(seed_result.queue_time_ms, abs=1e-3)
    # Not part of equality, as request_id: a timing is no property of the solution.
    assert dataclasses.replace(seed_result, server_timing=None, request_id=None) == seed_result
    # Nor is how many attempts the answer took: one, here.
    assert seed_result.attempts == 1
    assert dataclasses.replace(seed_result, attempts=3) == seed_result


def test_server_timing_parsing_skips_what_it_cannot_read() -> None:
    from ilqr_client.models import _parse_server_timing

    assert _parse_server_timing(None) is None
    assert _parse_server_timing("") == {}
    assert _parse_server_timing('queue;dur=0.5, miss, solve;desc="x";dur="1.25", bad;dur=abc, ;dur=3') == {
        "queue": 0.5,
        "solve": 1.25,
    }


def test_numpy_problem_values_and_as_numpy(client: Client, seed_result: SolveResult) -> None:
    np = pytest.importorskip("numpy")
    result = client.solve({"initial_state": np.array([5.0, 0, 0, 0, 0, 0]), "dt": np.float64(0.05)})
    assert result.cost == seed_result.cost

    arrays = seed_result.as_numpy()
    assert arrays["states"].shape == (101, 6)
    assert arrays["controls"].shape == (100, 2)
    assert arrays["feedback"].shape == (100, 2, 6)
    assert arrays["feedforward"].shape == (100, 2)
    assert arrays["cost"].shape == (seed_result.iterations + 1,)
    assert arrays["closest_approach"].shape == (1,)


def test_results_are_frozen(seed_result: SolveResult) -> None:
    with pytest.raises(AttributeError):
        seed_result.cost = 0.0  # type: ignore[misc]


def test_context_manager_closes_its_own_session(service: ServiceProcess, monkeypatch: pytest.MonkeyPatch) -> None:
    client = Client(service.url)
    closed = []
    monkeypatch.setattr(client.session, "close", lambda: closed.append(True))
    with client as c:
        assert c.health()
    assert closed == [True]


def test_borrowed_session_is_not_closed(service: ServiceProcess, monkeypatch: pytest.MonkeyPatch) -> None:
    session = requests.Session()
    closed = []
    monkeypatch.setattr(session, "close", lambda: closed.append(True))
    with Client(service.url, session=session) as c:
        assert c.health()
    assert closed == []


def test_one_connection_serves_every_call(service: ServiceProcess) -> None:
    """Session reuse: health, the default problem, a solve and a 422 all go
    over the one keep-alive connection the client's pool opened."""
    from ilqr_client import ValidationError

    with Client(service.url) as c:
        assert c.health()
        problem = c.default_problem()
        problem.horizon = 20
        assert c.solve(problem).status in ("converged", "max_iterations")
        with pytest.raises(ValidationError):
            c.solve({"dt": -1})
        assert c.ready()
        pools = c.session.get_adapter(service.url).poolmanager.pools
        (key,) = pools.keys()  # one pool: one host
        assert pools[key].num_requests == 5
        assert pools[key].num_connections == 1


def test_a_read_timeout_below_the_time_budget_is_raised_to_cover_it(service: ServiceProcess) -> None:
    # A 1 s read timeout and a 2.5 s budget: the client waits for the answer
    # instead of leaving (which would also cancel the solve).
    with Client(service.url, timeout=1.0, retries=0) as c:
        result = c.solve(busy_problem(2500))
    assert result.status == "time_limit"
    assert result.solve_time_ms > 2000
    # A timeout given for the call is kept exactly.
    with Client(service.url, retries=0) as c:
        with pytest.raises(requests.exceptions.ReadTimeout):
            c.solve(busy_problem(2500), timeout=1.0)


def test_only_a_usable_budget_raises_the_timeout() -> None:
    from ilqr_client.client import _covering

    def budget(limit: object) -> dict:
        return {"solver": {"time_limit_ms": limit}}

    assert _covering(30.0, budget(45000)) == (30.0, 50.0)
    assert _covering(30.0, budget(1000)) == 30.0
    assert _covering((2.0, 10.0), budget(45000)) == (2.0, 50.0)
    assert _covering((2.0, 60.0), budget(45000)) == (2.0, 60.0)
    # A read timeout equal to the budget leaves nothing for the answer.
    assert _covering(10.0, budget(10000)) == (10.0, 15.0)
    # One longer than the budget is the caller's deadline: a control loop's
    # 0.1 s with a 20 ms budget stays 0.1 s (it was raised to 5.02 s).
    assert _covering(0.1, budget(20)) == 0.1
    assert _covering((0.05, 0.1), budget(20)) == (0.05, 0.1)
    assert _covering(46.0, budget(45000)) == 46.0
    assert _covering(None, budget(45000)) is None
    # A service may accept budgets of days (--max-time-limit-ms has no cap).
    assert _covering(30.0, budget(86_400_001)) == (30.0, 86_405.001)
    # Left for the service to refuse, or not set: the timeout as it was.
    for unusable in [True, "45000", -1, float("nan"), None, 10**20, 1e300, 10**400, float("inf")]:
        assert _covering(30.0, budget(unusable)) == 30.0, unusable
    # Other forms requests accepts are used as given.
    import urllib3

    other = urllib3.Timeout(connect=2, read=30)
    assert _covering(other, budget(45000)) is other
    assert _covering(30.0, {}) == 30.0
    assert _covering(30.0, {"solver": None}) == 30.0


def test_a_result_shows_as_one_short_line(seed_result: SolveResult) -> None:
    # The generated repr printed every array: 50 KB for the seed.
    text = repr(seed_result)
    assert len(text) < 600 and "\n" not in text, text
    assert text.startswith("SolveResult(model='quadrotor_2d', integrator='euler', status='converged', cost=5418.30")
    assert "horizon=100" in text and "gains=<100 knots>" in text
    assert seed_result.trace is not None and f"trace=<{len(seed_result.trace)} rows>" in text


def test_a_misspelled_field_is_refused_not_dropped() -> None:
    # Set on a plain dataclass, `horizn` was kept on the object and never
    # sent: the solve ran with the default horizon, without a word.
    problem = Problem(solver=SolverOptions(), output=OutputOptions())
    with pytest.raises(AttributeError, match="Problem has no field 'horizn'; did you mean 'horizon'"):
        problem.horizn = 20  # type: ignore[attr-defined]
    with pytest.raises(AttributeError, match="SolverOptions has no field 'time_limit'"):
        problem.solver.time_limit = 1  # type: ignore[union-attr]
    with pytest.raises(AttributeError, match="OutputOptions has no field 'gain'"):
        problem.output.gain = False  # type: ignore[union-attr]
    problem.horizon = 20
    problem.extra["integrator"] = "euler"  # what the client does not know goes here
    assert problem.to_dict() == {"horizon": 20, "solver": {}, "output": {}, "integrator": "euler"}


def test_ddp_converges_in_a_few_steps_where_ilqr_crawls(client: Client) -> None:
    # The seed with R = 90 I: iLQR crawls (hundreds of half steps), DDP's
    # model has the dynamics' curvature and converges in a few.
    problem = Problem(weights=Weights(control=[90, 90]), output=OutputOptions(gains=False, trace=False))
    ilqr = client.solve(problem)
    problem.solver = SolverOptions(method="ddp")
    ddp = client.solve(problem)
    assert ilqr.converged and ddp.converged
    assert ilqr.iterations > 200 and ddp.iterations <= 15, (ilqr.iterations, ddp.iterations)
    assert ddp.cost == pytest.approx(ilqr.cost, rel=1e-8)
    assert client.default_problem().solver.method == "ilqr"  # type: ignore[union-attr]


def test_answers_decode_the_same_with_and_without_orjson(client: Client, service: ServiceProcess) -> None:
    # The `fast` extra swaps the decoder; the result must not change by a bit.
    import json

    import ilqr_client.client as client_module

    orjson = pytest.importorskip("orjson")
    assert client_module._loads is orjson.loads
    problem = {"horizon": 300, "dt": 0.02, "obstacles": [{"center": [4.5, 4.5], "weight": 1000.0}]}
    body = requests.post(f"{service.url}/solve", json=problem, timeout=30).content
    fast = SolveResult.from_dict(orjson.loads(body))
    plain = SolveResult.from_dict(json.loads(body))
    assert fast.gains is not None and fast.trace is not None
    assert fast == plain  # every float, gains and trace included
    assert fast.trace[-1].elapsed_ms == plain.trace[-1].elapsed_ms
    # And through the client, which decodes with orjson.
    assert client.solve(problem).cost == fast.cost


def test_shifted_controls_is_the_receding_horizon_warm_start(seed_result: SolveResult) -> None:
    controls = seed_result.controls
    shifted = seed_result.shifted_controls()
    assert shifted == controls[1:] + controls[-1:]
    assert len(shifted) == seed_result.horizon
    assert seed_result.shifted_controls(3) == controls[3:] + [controls[-1]] * 3
    assert seed_result.shifted_controls(0) == controls
    assert seed_result.shifted_controls(100) == [controls[-1]] * 100
    # New lists: editing the warm start leaves the (frozen) result alone.
    shifted[0][0] = -1.0
    assert seed_result.controls[1][0] != -1.0
    for bad in [-1, 101, 1.5, True]:
        with pytest.raises(ValueError, match="steps must be an integer from 0 to the horizon 100"):
            seed_result.shifted_controls(bad)  # type: ignore[arg-type]
