"""numpy arrays are first-class problem values, at run time and to a type checker.

The test command also runs ``mypy --strict`` over the package and this file,
so a signature that rejects ``numpy.ndarray`` (numpy arrays are not
``Sequence``s to a type checker) fails CI, not a user's type check.
"""

from __future__ import annotations

import inspect
import json
import typing
from typing import List, Optional

import pytest
from ilqr_client import (
    Client,
    FloatRows,
    Floats,
    Gains,
    Model,
    ModelInfo,
    Obstacle,
    Problem,
    QuadrotorModel,
    SolveResult,
    TraceEntry,
    Weights,
)

pytest.importorskip("numpy")
import numpy as np  # noqa: E402  (typed, unlike importorskip's return value)


def test_numpy_arrays_in_every_vector_and_matrix_field_become_plain_json() -> None:
    problem = Problem(
        initial_state=np.array([5.0, 0, 0, 0, 0, 0]),
        goal_state=np.zeros(6),
        weights=Weights(state=np.ones(6), control=np.full(2, 0.1), terminal=np.full(6, 5e4)),
        obstacles=[Obstacle(center=np.array([4.5, 4.5]), weight=1000.0)],
        initial_controls=np.full((100, 2), 4.905),
        dt=0.05,
    )
    doc = problem.to_dict()
    # json.dumps without a default: every value is a plain JSON type.
    text = json.dumps(doc, allow_nan=False)
    assert json.loads(text)["initial_controls"][99] == [4.905, 4.905]
    assert doc["obstacles"] == [{"center": [4.5, 4.5], "weight": 1000.0}]
    assert doc["weights"]["terminal"] == [5e4] * 6

    # Rows may be arrays too, and tuples stay accepted.
    rows = Problem(initial_controls=[np.array([4.9, 4.9])] * 3, goal_state=(4, 9, 0, 0, 0, 0))
    assert rows.to_dict() == {"initial_controls": [[4.9, 4.9]] * 3, "goal_state": [4, 9, 0, 0, 0, 0]}

    # Lists of plain numbers (a warm start from a result) are sent as they
    # are; anything else in them (a numpy scalar, a tuple row, a bool) still
    # takes the general conversion.
    from ilqr_client.models import to_json_value

    plain = [[4.9, 4.9], [5, 4.8]]
    sent = to_json_value(plain)
    assert sent == plain and sent is not plain and sent[0] is not plain[0]
    mixed = [[4.9, np.float32(4.5)], (5, 4), [True, 0]]
    converted = to_json_value(mixed)
    assert converted == [[4.9, 4.5], [5, 4], [True, 0]]
    assert json.loads(json.dumps(converted)) == converted
    assert to_json_value([1.0, np.float32(2.0)]) == [1.0, 2.0]


def test_a_unicycle_problem_of_numpy_arrays_and_a_warm_start_type_checks() -> None:
    # Vectors as long as the model's state (3) and controls (2); a warm
    # start from a dict. mypy --strict checks this file.
    problem = Problem(
        model=Model("unicycle"),
        integrator="rk4",
        initial_state=np.zeros(3),
        goal_state=np.array([4.0, 0.0, 0.0]),
        weights=Weights(state=np.ones(3), control=np.ones(2), terminal=np.full(3, 1e3)),
        warm_start={"controls": np.full((60, 2), 0.5).tolist(), "model": "unicycle"},
    )
    doc = problem.to_dict()
    assert json.loads(json.dumps(doc, allow_nan=False)) == doc
    assert doc["model"] == {"type": "unicycle"} and doc["weights"]["terminal"] == [1e3] * 3
    quadrotor = QuadrotorModel(mass=2.0)
    mass: Optional[float] = quadrotor.mass
    assert mass == 2.0


def test_the_feedback_policy_takes_numpy_states() -> None:
    gains = Gains(
        feedback=[[[1.0, 0, 0, 0, 0, 0], [0, 2.0, 0, 0, 0, 0]]],
        feedforward=[[0.0, 0.0]],
        regularization=0.0,
    )
    u: List[float] = gains.control(0, np.ones(6), np.zeros(6), np.array([4.0, 5.0]))
    assert u == [5.0, 7.0]


def test_type_hints_resolve_at_run_time() -> None:
    # Tools that read field annotations at run time (typing.get_type_hints,
    # dataclass introspection) need every alias defined there. At run time
    # the aliases say Sequence; numpy arrays are accepted all the same.
    for cls in (Problem, Weights, Obstacle, Gains, SolveResult, Model, ModelInfo):
        hints = typing.get_type_hints(cls)
        assert hints, cls
    assert typing.get_type_hints(Problem)["initial_controls"] == typing.Optional[FloatRows]
    assert typing.get_type_hints(Obstacle)["center"] == Floats
    # And every public callable's: as_numpy's numpy return type, the plot
    # functions' matplotlib Axes (both raised NameError: those modules are
    # imported only for type checkers), every class's methods and
    # properties.
    import ilqr_client
    import ilqr_client.plot

    public = [getattr(ilqr_client, name) for name in ilqr_client.__all__]
    public += [getattr(ilqr_client.plot, name) for name in ilqr_client.plot.__all__]
    checked = 0
    for obj in public:
        if isinstance(obj, type):
            for name, member in vars(obj).items():
                if name.startswith("_") and name != "__init__":
                    continue
                if isinstance(member, property):
                    member = member.fget
                elif isinstance(member, (classmethod, staticmethod)):
                    member = member.__func__
                if inspect.isfunction(member):
                    typing.get_type_hints(member)
                    checked += 1
        elif inspect.isfunction(obj):  # not the aliases, which are no functions
            typing.get_type_hints(obj)
            checked += 1
    assert checked > 30, checked


def test_gains_fields_are_parsed_strictly() -> None:
    base = {"feedback": [[[0.0] * 6] * 2], "feedforward": [[0.0, 0.0]]}
    old = Gains.from_dict(base)  # an older service sends neither field
    assert (old.regularization, old.about_previous_iterate) == (None, None)
    full = Gains.from_dict({**base, "regularization": 2.5, "about_previous_iterate": True})
    assert (full.regularization, full.about_previous_iterate) == (2.5, True)
    with pytest.raises(ValueError, match=r"/gains/about_previous_iterate: expected a boolean, got 'true'"):
        Gains.from_dict({**base, "about_previous_iterate": "true"})
    with pytest.raises(ValueError, match=r"/gains/regularization"):
        Gains.from_dict({**base, "regularization": "x"})


def test_editing_an_expanded_problem_type_checks_as_the_readme_shows() -> None:
    # The README's idiom for editing default_problem()'s answer: the fields
    # are Optional and obstacles a Sequence, so append() and attribute
    # access on a field would not type-check. mypy --strict checks this file.
    import dataclasses

    problem = Problem.from_dict(
        {
            "obstacles": [{"center": [4.5, 4.5], "weight": 1000}],
            "weights": {"state": [1] * 6, "control": [0.1, 0.1], "terminal": [5e4] * 6},
        }
    )
    problem.obstacles = [*(problem.obstacles or []), Obstacle(center=[2.0, 6.0], weight=500.0)]
    assert problem.weights is not None
    problem.weights = dataclasses.replace(problem.weights, terminal=[1e5] * 6)
    doc = problem.to_dict()
    assert doc["obstacles"] == [
        {"center": [4.5, 4.5], "weight": 1000},
        {"center": [2.0, 6.0], "weight": 500.0},
    ]
    assert doc["weights"] == {"state": [1] * 6, "control": [0.1, 0.1], "terminal": [1e5] * 6}
