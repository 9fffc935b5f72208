"""Models are generic: the unicycle beside the quadrotor, RK4, GET /models,
each model's default problem, vector lengths per model, warm starts."""

from __future__ import annotations

import dataclasses
from typing import Any, Dict, List

import pytest
import requests
from conftest import ServiceProcess
from ilqr_client import (
    Client,
    Model,
    ModelInfo,
    NotFoundError,
    OutputOptions,
    ParameterInfo,
    Problem,
    QuadrotorModel,
    QuantityInfo,
    SolveResult,
    SolverOptions,
    ValidationError,
)

LEAN = OutputOptions(gains=False, trace=False)

#: Each model's dimensions (NX, NU), as the service describes them.
DIMENSIONS = {"quadrotor_2d": (6, 2), "unicycle": (3, 2)}


def test_a_unicycle_solve_converges_with_3_wide_states_and_2_wide_controls(unicycle_result: SolveResult) -> None:
    result = unicycle_result
    assert (result.model, result.integrator, result.status) == ("unicycle", "euler", "converged")
    assert result.cost < result.initial_cost and result.goal_distance < 0.05
    assert len(result.states) == 61 and all(len(state) == 3 for state in result.states)
    assert len(result.controls) == 60 and all(len(control) == 2 for control in result.controls)
    assert result.states[0] == [0.0, 0.0, 0.0]
    assert result.positions == [(x, y) for x, y, _ in result.states]
    assert result.gains is not None
    assert all(len(k) == 2 and all(len(row) == 3 for row in k) for k in result.gains.feedback)
    # The feedback policy takes 3-component states, and says so otherwise.
    k, state, control = 10, result.states[10], result.controls[10]
    assert result.gains.control(k, state, state, control) == pytest.approx(control)
    with pytest.raises(ValueError, match="states must have 3 components, got 6"):
        result.gains.control(k, [*state, 0, 0, 0], [*state, 0, 0, 0], control)


def test_as_numpy_takes_the_model_s_widths(unicycle_result: SolveResult) -> None:
    pytest.importorskip("numpy")
    arrays = unicycle_result.as_numpy()
    assert arrays["states"].shape == (61, 3)
    assert arrays["controls"].shape == (60, 2)
    assert arrays["feedback"].shape == (60, 2, 3)
    assert arrays["feedforward"].shape == (60, 2)


def test_a_result_s_rows_must_all_be_as_wide_as_the_first(unicycle_result: SolveResult) -> None:
    from test_errors import _answer_of

    answer = _answer_of(unicycle_result)
    assert SolveResult.from_dict(answer) == unicycle_result
    answer["states"][7] = [0.0] * 6
    with pytest.raises(ValueError, match=r"^/states/7: expected 3 numbers, got 6$"):
        SolveResult.from_dict(answer)
    # Gains must fit the states and controls: NU rows of NX columns.
    answer = _answer_of(unicycle_result)
    answer["gains"]["feedback"][0] = [[0.0] * 6] * 2
    with pytest.raises(ValueError, match=r"^/gains/feedback/0/0: expected 3 numbers, got 6$"):
        SolveResult.from_dict(answer)


@pytest.mark.parametrize("model", ["quadrotor_2d", "unicycle"])
def test_an_rk4_solve_says_so(client: Client, model: str) -> None:
    euler = client.solve(Problem(model=Model(model), output=LEAN))
    rk4 = client.solve(Problem(model=Model(model), integrator="rk4", output=LEAN))
    assert (euler.integrator, rk4.integrator) == ("euler", "rk4")
    assert rk4.model == model and rk4.converged
    assert rk4.cost != euler.cost  # another discretisation, another optimum


def test_models_lists_both_with_their_dimensions(client: Client) -> None:
    infos = client.models()
    assert [info.type for info in infos] == ["quadrotor_2d", "unicycle"]  # the default first
    for info in infos:
        assert isinstance(info, ModelInfo) and info.description
        assert (info.state_dim, info.control_dim) == DIMENSIONS[info.type]
        assert all(isinstance(q, QuantityInfo) and q.unit for q in info.state + info.control)
        assert info.position == (0, 1)
        problem = info.default_problem
        assert isinstance(problem, Problem)
        assert problem.model is not None and problem.model.type == info.type
        assert problem.initial_state is not None and len(problem.initial_state) == info.state_dim
        assert problem.weights is not None and problem.weights.control is not None
        assert len(problem.weights.control) == info.control_dim
        # The same problem GET /problems/default?model= gives.
        assert client.default_problem(model=info.type) == problem
    quadrotor, unicycle = infos
    assert [(q.name, q.unit) for q in unicycle.state] == [("x", "m"), ("y", "m"), ("θ", "rad")]
    assert [(q.name, q.unit) for q in unicycle.control] == [("v", "m/s"), ("ω", "rad/s")]
    assert unicycle.parameters == []
    assert [p.name for p in quadrotor.parameters] == ["mass", "inertia", "arm_length", "gravity"]
    mass = quadrotor.parameters[0]
    assert isinstance(mass, ParameterInfo)
    assert (mass.unit, mass.default, mass.minimum, mass.maximum) == ("kg", 1.0, 1e-6, 1e6)
    assert "unicycle" in repr(unicycle) and "θ" in repr(unicycle)
    # A model of a listed type, its parameters checked against the list.
    assert quadrotor.model(mass=2.0) == QuadrotorModel(mass=2.0)
    assert unicycle.model() == Model("unicycle")
    with pytest.raises(ValueError, match="model 'quadrotor_2d' has no parameter 'mas'; did you mean 'mass'"):
        quadrotor.model(mas=2.0)
    with pytest.raises(ValueError, match="model 'unicycle' has no parameter 'mass'; it has: none"):
        unicycle.model(mass=2.0)


def test_the_unicycle_s_default_problem_round_trips_through_solve(
    client: Client, unicycle_result: SolveResult
) -> None:
    problem = client.default_problem(model="unicycle")
    assert problem.model == Model("unicycle")
    assert (problem.horizon, problem.dt) == (60, 0.1)
    assert problem.initial_state == [0.0, 0.0, 0.0]
    assert problem.to_dict()["model"] == {"type": "unicycle"}
    # Posted back, it is the problem {"model": {"type": "unicycle"}} stands for.
    result = client.solve(problem)
    assert (result.model, result.cost, result.iterations) == ("unicycle", unicycle_result.cost, unicycle_result.iterations)
    assert (result.states, result.controls, result.gains) == (
        unicycle_result.states, unicycle_result.controls, unicycle_result.gains,
    )
    # The call without a model is the seed scenario's, as it always was.
    seed = client.default_problem()
    assert isinstance(seed.model, QuadrotorModel) and seed.model.mass == 1.0
    assert client.default_problem("quadrotor_2d") == seed


def test_an_unknown_model_s_default_problem_is_not_found(client: Client) -> None:
    with pytest.raises(NotFoundError) as info:
        client.default_problem(model="bicycle")
    assert "`quadrotor_2d`, `unicycle`" in info.value.detail
    with pytest.raises(TypeError, match="model must be a model's name"):
        client.default_problem(model=Model("unicycle"))  # type: ignore[arg-type]


def _wrong_length(model: str, pointer: str) -> Dict[str, Any]:
    """A problem of ``model`` whose vector at ``pointer`` is one entry too long."""
    nx, nu = DIMENSIONS[model]
    doc: Dict[str, Any] = {"model": {"type": model}}
    if pointer == "/initial_controls/0":
        doc.update(horizon=2, initial_controls=[[0.0] * (nu + 1), [0.0] * nu])
    elif pointer.startswith("/weights/"):
        doc["weights"] = {pointer.rsplit("/", 1)[1]: [1.0] * ((nu if pointer.endswith("control") else nx) + 1)}
    else:
        doc[pointer[1:]] = [0.0] * (nx + 1)
    return doc


@pytest.mark.parametrize("model", ["quadrotor_2d", "unicycle"])
@pytest.mark.parametrize(
    "pointer",
    ["/initial_state", "/goal_state", "/weights/state", "/weights/terminal", "/weights/control", "/initial_controls/0"],
)
def test_a_wrong_length_is_named_by_pointer_for_each_model(client: Client, model: str, pointer: str) -> None:
    nx, nu = DIMENSIONS[model]
    expected = nu if pointer in ("/weights/control", "/initial_controls/0") else nx
    with pytest.raises(ValidationError) as info:
        client.solve(_wrong_length(model, pointer))
    assert info.value.pointers == [pointer]
    detail = info.value.errors[0].detail
    assert f"must have {expected} entries for model `{model}`" in detail, detail


def test_a_warm_start_from_a_result_reproduces_its_cost(client: Client, unicycle_result: SolveResult) -> None:
    for warm_start in (unicycle_result, unicycle_result.to_warm_start()):
        problem = Problem(model=Model("unicycle"), warm_start=warm_start, output=LEAN)
        warm = client.solve(problem)
        assert warm.initial_cost == unicycle_result.cost  # the same controls, bit for bit
        assert warm.converged and warm.iterations <= 2, warm
        assert warm.horizon == unicycle_result.horizon  # set by the warm start
    # A SolveResult is sent as its controls and model, not its gains and trace.
    document = Problem(warm_start=unicycle_result).to_dict()
    assert document == {"warm_start": {"controls": unicycle_result.controls, "model": "unicycle"}}
    assert document["warm_start"]["controls"] is not unicycle_result.controls


def test_a_warm_start_from_an_answer_s_json(client: Client, service: ServiceProcess) -> None:
    # A plain dict (the whole answer, gains and trace included) is sent as it is.
    problem = {"integrator": "rk4", "output": {"trace": False}}
    answer = requests.post(f"{service.url}/solve", json=problem, timeout=30).json()
    warm = client.solve({**problem, "warm_start": answer})
    assert warm.initial_cost == answer["cost"] and warm.iterations <= 2
    assert Problem.from_dict({"warm_start": answer}).warm_start == answer


def test_a_warm_start_is_checked_against_the_problem(client: Client, unicycle_result: SolveResult) -> None:
    with pytest.raises(ValidationError) as info:
        client.solve(Problem(warm_start=unicycle_result))  # a quadrotor problem
    assert info.value.pointers == ["/warm_start/model"]
    with pytest.raises(ValidationError) as info:
        client.solve(Problem(
            model=Model("unicycle"), warm_start=unicycle_result, initial_controls=unicycle_result.controls,
        ))
    assert info.value.pointers == ["/warm_start"]


def test_posting_a_result_as_a_problem_hints_at_warm_start(client: Client, service: ServiceProcess) -> None:
    answer = requests.post(
        f"{service.url}/solve", json={"model": {"type": "unicycle"}, "output": {"trace": False}}, timeout=30,
    ).json()
    with pytest.raises(ValidationError) as info:
        client.solve(answer)
    details = {error.pointer: error.detail for error in info.value.errors}
    assert {"/controls", "/states", "/cost", "/status"} <= set(details)
    assert "warm_start" in details["/controls"], details["/controls"]
    # The result itself is no problem either: the client says what to do.
    result = SolveResult.from_dict(answer)
    with pytest.raises(TypeError, match="warm_start"):
        client.solve(result)  # type: ignore[arg-type]


def test_positions_come_from_the_model_s_position_entries(service: ServiceProcess, unicycle_result: SolveResult) -> None:
    # Both built-in models keep the position at entries 0 and 1; the client
    # takes them from GET /models once it has fetched them.
    with Client(service.url) as c:
        assert c.solve({"model": {"type": "unicycle"}, "horizon": 5}).model_position is None
        c.models()
        assert c.solve({"model": {"type": "unicycle"}, "horizon": 5}).model_position == (0, 1)
    swapped = dataclasses.replace(unicycle_result, model_position=(1, 0))
    assert swapped.position_entries == (1, 0)
    assert swapped.positions == [(y, x) for x, y, _ in unicycle_result.states]
    assert swapped == unicycle_result  # not part of equality
    unknown = dataclasses.replace(unicycle_result, model="hovercraft")
    assert unknown.position_entries == (0, 1)


def test_model_objects_are_sent_flat() -> None:
    assert Model("unicycle").to_dict() == {"type": "unicycle"}
    assert Model().to_dict() == {}
    assert Model("quadrotor_2d", {"mass": 2, "gravity": None}).to_dict() == {"type": "quadrotor_2d", "mass": 2}
    with pytest.raises(ValueError, match="'type' is the model's name"):
        Model(parameters={"type": "unicycle"}).to_dict()
    # Parsing gives a QuadrotorModel for the quadrotor (named parameters),
    # a Model for any other; equality looks at type and parameters only.
    quadrotor = Model.from_dict({"type": "quadrotor_2d", "mass": 2.0})
    assert type(quadrotor) is QuadrotorModel and quadrotor.mass == 2.0
    assert quadrotor == Model("quadrotor_2d", {"mass": 2.0})
    assert type(Model.from_dict({"type": "unicycle"})) is Model
    assert type(Model.from_dict({"mass": 3})) is QuadrotorModel
    with pytest.raises(TypeError, match="/model: expected an object, got str"):
        Problem.from_dict({"model": "unicycle"})
    problem = Problem.from_dict({"model": {"type": "unicycle"}, "integrator": "rk4"})
    assert problem.model == Model("unicycle") and problem.integrator == "rk4"


def test_quadrotor_model_keeps_its_named_parameters() -> None:
    model = QuadrotorModel(mass=2.0, gravity=3.7)
    assert isinstance(model, Model) and model.type == "quadrotor_2d"
    assert (model.mass, model.inertia, model.arm_length, model.gravity) == (2.0, None, None, 3.7)
    assert model.to_dict() == {"type": "quadrotor_2d", "mass": 2.0, "gravity": 3.7}
    model.inertia = 0.5
    model.gravity = None  # left out again: the service's default
    assert model.parameters == {"mass": 2.0, "inertia": 0.5}
    assert QuadrotorModel(None, 2.0).to_dict() == {"mass": 2.0}  # the old positional order
    assert QuadrotorModel(extra={"drag": 0.1}).to_dict() == {"type": "quadrotor_2d", "drag": 0.1}
    assert dataclasses.replace(model, parameters={"mass": 4.0}) == QuadrotorModel(mass=4.0)
    with pytest.raises(ValueError, match="use Model for others"):
        QuadrotorModel(type="unicycle")
    with pytest.raises(AttributeError, match="QuadrotorModel has no field 'mas'; did you mean 'mass'"):
        model.mas = 1.0  # type: ignore[attr-defined]


def test_model_parameters_reach_the_service(client: Client, seed_result: SolveResult) -> None:
    heavy = client.solve(Problem(model=QuadrotorModel(mass=2.0), output=LEAN))
    assert heavy.model == "quadrotor_2d" and heavy.cost != seed_result.cost
    assert client.solve(Problem(model=Model("quadrotor_2d", {"mass": 2.0}), output=LEAN)).cost == heavy.cost
    with pytest.raises(ValidationError) as info:
        client.solve(Problem(model=Model("unicycle", {"mass": 1.0})))
    assert info.value.pointers == ["/model/mass"]


def test_a_short_warm_start_sets_a_short_horizon(client: Client, unicycle_result: SolveResult) -> None:
    # The horizon follows the warm start's rows when the problem gives none.
    head: List[List[float]] = unicycle_result.controls[:20]
    result = client.solve(
        Problem(model=Model("unicycle"), warm_start={"controls": head}, solver=SolverOptions(max_iterations=0))
    )
    assert result.horizon == 20 and len(result.states) == 21
