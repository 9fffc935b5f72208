"""Error answers: typed exceptions from the real service, and parsing of odd bodies."""

from __future__ import annotations

import copy
import dataclasses
import json
import pickle
from typing import Any, Dict, List, Optional

import pytest
import requests
from conftest import ServiceProcess
from ilqr_client import (
    ApiError,
    Client,
    FieldError,
    MalformedRequestError,
    MethodNotAllowedError,
    NotFoundError,
    Obstacle,
    OverloadedError,
    PayloadTooLargeError,
    Problem,
    RequestTimeoutError,
    ServerError,
    ShuttingDownError,
    SolveResult,
    UnexpectedResponseError,
    UnsupportedMediaTypeError,
    ValidationError,
    Weights,
)
from ilqr_client.errors import error_from_response, parse_retry_after
from ilqr_client.models import to_json_value


@pytest.mark.parametrize(
    ("problem", "pointers"),
    [
        pytest.param({"dt": -1}, ["/dt"], id="negative-dt"),
        pytest.param({"foo": 1}, ["/foo"], id="unknown-field"),
        pytest.param({"initial_state": [1, 2]}, ["/initial_state"], id="wrong-length"),
        pytest.param({"solver": {"time_limit_ms": 0}}, ["/solver/time_limit_ms"], id="nested"),
        pytest.param(
            {"dt": -1, "horizon": 0, "weights": {"state": [1, 1, -1, 1, 1, 1]}},
            ["/dt", "/horizon", "/weights/state/2"],
            id="several",
        ),
        pytest.param(Problem(extra={"bogus": True}), ["/bogus"], id="dataclass-extra"),
        pytest.param({"obstacles": [{"weight": 1}]}, ["/obstacles/0/center"], id="missing-field"),
        pytest.param({"horizon": "x"}, ["/horizon"], id="not-an-integer"),
        pytest.param(
            {"dt": "x", "horizon": "y", "weights": {"state": [1, 1, -1, 1, 1, 1]}},
            ["/dt", "/horizon", "/weights/state/2"],
            id="wrong-types-and-a-range",
        ),
    ],
)
def test_validation_errors(client: Client, problem: Any, pointers: List[str]) -> None:
    with pytest.raises(ValidationError) as info:
        client.solve(problem)
    error = info.value
    assert error.status == 422
    assert error.type == "urn:ilqr-service:validation"
    assert error.slug == "validation"
    assert sorted(error.pointers) == sorted(pointers)
    assert all(isinstance(e, FieldError) and e.detail for e in error.errors)
    assert error.request_id
    assert pointers[0] in str(error)


def test_a_flood_of_invalid_values_lists_100_and_counts_the_rest(client: Client) -> None:
    rows = [[1e13, 1e13]] * 5000  # finite, so the client sends them; the service refuses
    with pytest.raises(ValidationError) as info:
        client.solve({"horizon": 5000, "initial_controls": rows})
    error = info.value
    assert len(error.errors) == 100 and error.unlisted == 9900
    # Every listed entry names a field: the count is not an entry of its own.
    assert error.pointers[:2] == ["/initial_controls/0/0", "/initial_controls/0/1"]
    assert "" not in error.pointers
    assert "10000 invalid values" in str(error)

    with pytest.raises(ValidationError) as info:
        client.solve({"dt": -1})
    assert info.value.unlisted == 0


@pytest.mark.parametrize("bad", ["", "has space", "é", "x" * 129])
def test_a_request_id_the_service_would_replace_is_refused_before_sending(
    client: Client, bad: str
) -> None:
    with pytest.raises(ValueError, match="request_id"):
        client.solve({}, request_id=bad)
    # The longest and oddest ids it keeps go through unchanged.
    for good in ["x" * 128, "a-b_c.d~!#"]:
        assert client.solve({"output": {"gains": False, "trace": False}}, request_id=good).request_id == good


def test_validation_error_carries_the_request_id(client: Client) -> None:
    with pytest.raises(ValidationError) as info:
        client.solve({"dt": -1}, request_id="bad-dt-42")
    assert info.value.request_id == "bad-dt-42"
    assert "bad-dt-42" in str(info.value)


def test_client_errors_are_not_retried(service: ServiceProcess, monkeypatch: pytest.MonkeyPatch) -> None:
    client = Client(service.url, retries=3)
    sleeps: List[float] = []
    monkeypatch.setattr(client, "_sleep", sleeps.append)
    with client, pytest.raises(ValidationError):
        client.solve({"dt": -1})
    assert sleeps == []


def test_unsupported_media_type(service: ServiceProcess) -> None:
    response = requests.post(
        f"{service.url}/solve", data="{}", headers={"Content-Type": "text/plain"}, timeout=10
    )
    assert response.status_code == 415
    assert response.headers["content-type"].startswith("application/problem+json")
    error = error_from_response(response)
    assert isinstance(error, UnsupportedMediaTypeError)
    assert error.slug == "unsupported-media-type"
    assert error.request_id == response.headers["x-request-id"]


def test_malformed_json(service: ServiceProcess) -> None:
    response = requests.post(
        f"{service.url}/solve", data="{bad", headers={"Content-Type": "application/json"}, timeout=10
    )
    error = error_from_response(response)
    assert isinstance(error, MalformedRequestError)
    assert error.status == 400 and error.slug == "malformed-json"


def test_a_bare_nan_from_json_dumps_is_a_422_at_its_pointer(service: ServiceProcess) -> None:
    # json.dumps writes NaN and -Infinity, which JSON lacks (requests'
    # json= refuses them); the service names the first one's field instead
    # of a 400 for the body.
    document = {"dt": 0.05, "weights": {"state": [1, 1, float("-inf"), 1, 1, 1]}, "horizon": float("nan")}
    response = requests.post(
        f"{service.url}/solve",
        data=json.dumps(document),
        headers={"Content-Type": "application/json"},
        timeout=10,
    )
    error = error_from_response(response)
    assert isinstance(error, ValidationError), response.text
    assert error.status == 422 and error.slug == "validation"
    assert error.pointers == ["/weights/state/2"]
    assert error.errors[0].detail.startswith("got -Infinity, which is not JSON")


def test_payload_too_large(client: Client) -> None:
    # The service's default limit is 4 MiB; it answers 413 before looking at the fields.
    problem = {"padding": "x" * 5_000_000}
    with pytest.raises(PayloadTooLargeError) as info:
        client.solve(problem)
    assert info.value.status == 413


def test_not_found_and_method_not_allowed(service: ServiceProcess) -> None:
    with Client(f"{service.url}/no-such-prefix") as c, pytest.raises(NotFoundError) as info:
        c.default_problem()
    assert info.value.status == 404
    error = error_from_response(requests.get(f"{service.url}/solve", timeout=10))
    assert isinstance(error, MethodNotAllowedError) and error.status == 405


def test_a_base_url_without_a_scheme_is_refused_at_once() -> None:
    with pytest.raises(ValueError, match=r"e\.g\. 'http://127\.0\.0\.1:8080'"):
        Client("127.0.0.1:8080")
    Client("HTTPS://example.invalid").close()
    # A session of one's own may serve other schemes through its adapters.
    session = requests.Session()
    session.mount("http+unix://", requests.adapters.HTTPAdapter())
    Client("http+unix://%2Frun%2Filqr.sock", session=session).close()
    session.close()


def test_nan_is_refused_before_sending_with_its_pointer(client: Client) -> None:
    # JSON has no NaN: the client refuses it and says where, which matters
    # in a 10000-row initial_controls. It used to say only "Out of range
    # float values are not JSON compliant".
    with pytest.raises(ValueError, match=r"^/dt: nan cannot be sent"):
        client.solve({"dt": float("nan")})
    rows = [[4.9, 4.9]] * 5000 + [[4.9, float("-inf")]] + [[4.9, 4.9]] * 4999
    with pytest.raises(ValueError, match=r"^/initial_controls/5000/1: -inf cannot be sent"):
        client.solve({"horizon": 10000, "initial_controls": rows})
    problem = Problem(weights=Weights(state=[1.0, 1.0, float("inf"), 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match=r"^/weights/state/2: inf cannot be sent"):
        client.solve(problem)
    with pytest.raises(ValueError, match=r"^/a~1b: nan cannot be sent"):
        client.solve({"a/b": float("nan")})
    # An empty key is a pointer token too ("/weights/" is the member "" of
    # /weights): the message quotes that value, not the whole object.
    with pytest.raises(ValueError, match=r"^/weights/: inf cannot be sent"):
        client.solve({"weights": {"": float("inf")}})


def test_a_problem_document_missing_a_required_member_names_it() -> None:
    # It was a TypeError from the dataclass's constructor, with no pointer;
    # posted as a dict, the service names /obstacles/1/center.
    document = {"obstacles": [{"center": [1.0, 2.0], "weight": 5.0}, {"weight": 5.0}]}
    with pytest.raises(ValueError, match=r"^/obstacles/1: missing member 'center'$"):
        Problem.from_dict(document)
    # The weight has a default (the service's 1000), so it may be left out.
    assert Problem.from_dict({"obstacles": [{"center": [1.0, 2.0]}]}).obstacles == [Obstacle(center=[1.0, 2.0])]
    assert Obstacle(center=[1.0, 2.0]).to_dict() == {"center": [1.0, 2.0]}
    with pytest.raises(ValueError, match=r"^/obstacles: expected an array"):
        Problem.from_dict({"obstacles": {"center": [1.0, 2.0], "weight": 5.0}})
    assert Problem.from_dict({"obstacles": [{"center": [1.0, 2.0], "weight": 5.0}]}).obstacles == [
        Obstacle(center=[1.0, 2.0], weight=5.0)
    ]
    # A tuple of obstacles is an array, as everywhere else in a problem.
    assert Problem.from_dict({"obstacles": ({"center": [1.0, 2.0], "weight": 5.0},)}).obstacles == [
        Obstacle(center=[1.0, 2.0], weight=5.0)
    ]
    # A member that should be an object names itself; values are the
    # service's to check (a 422 with the same pointer).
    with pytest.raises(TypeError, match=r"^/model: expected an object, got int$"):
        Problem.from_dict({"model": 5})
    with pytest.raises(TypeError, match=r"^/obstacles/0: expected an object, got int$"):
        Problem.from_dict({"obstacles": [5]})


def test_only_the_clients_own_request_types_are_sent_through_to_dict() -> None:
    # Any dataclass used to go through .to_dict(): one of the caller's own
    # raised AttributeError instead of the documented TypeError.
    @dataclasses.dataclass
    class Point:
        x: float

    with pytest.raises(TypeError, match=r"^cannot send a Point as JSON"):
        to_json_value({"center": Point(1.0)})
    assert to_json_value({"weights": Weights(control=(0.2, 0.2))}) == {"weights": {"control": [0.2, 0.2]}}


def test_unsupported_problem_type(client: Client) -> None:
    with pytest.raises(TypeError):
        client.solve([1, 2, 3])  # type: ignore[arg-type]


# --------------------------------------------------------------------------- #
# Parsing without a server
# --------------------------------------------------------------------------- #


def fake_response(
    status: int, body: str, content_type: str = "application/problem+json",
    headers: Optional[Dict[str, str]] = None, reason: str = "",
) -> requests.Response:
    """A requests.Response as if received from a server."""
    response = requests.Response()
    response.status_code = status
    response.reason = reason
    response._content = body.encode()
    response.headers["content-type"] = content_type
    response.headers.update(headers or {})
    return response


def test_non_problem_body_from_a_proxy() -> None:
    error = error_from_response(
        fake_response(502, "<html>Bad gateway</html>", "text/html", reason="Bad Gateway")
    )
    assert type(error) is ServerError
    assert error.status == 502 and error.type is None
    assert error.title == "Bad Gateway" and "Bad gateway" in error.detail


def test_non_problem_503_with_retry_after_is_an_overload() -> None:
    error = error_from_response(fake_response(503, "busy", "text/plain", {"Retry-After": "7"}))
    assert isinstance(error, OverloadedError) and error.retry_after == 7


def test_unknown_4xx_is_a_plain_api_error() -> None:
    error = error_from_response(fake_response(429, "slow down", "text/plain"))
    assert type(error) is ApiError and error.status == 429 and error.detail == "slow down"


def test_problem_documents_map_by_type() -> None:
    overloaded = error_from_response(fake_response(
        503,
        '{"type":"urn:ilqr-service:overloaded","title":"Service overloaded","status":503,'
        '"detail":"retry in 2 s","retry_after":2}',
    ))
    assert isinstance(overloaded, OverloadedError) and overloaded.retry_after == 2.0

    draining = error_from_response(fake_response(
        503, '{"type":"urn:ilqr-service:shutting-down","title":"Service shutting down","status":503,"detail":"x"}'
    ))
    assert isinstance(draining, ShuttingDownError) and draining.retry_after is None

    internal = error_from_response(fake_response(
        500, '{"type":"urn:ilqr-service:internal","title":"Internal error","status":500,"detail":"bug"}',
        headers={"x-request-id": "r-1"},
    ))
    assert isinstance(internal, ServerError) and internal.request_id == "r-1"

    # Broken chunked framing: the service answers 400 unreadable-body.
    unreadable = error_from_response(fake_response(
        400, '{"type":"urn:ilqr-service:unreadable-body","title":"Request body unreadable",'
        '"status":400,"detail":"the body could not be read: ..."}'
    ))
    assert type(unreadable) is MalformedRequestError and unreadable.slug == "unreadable-body"

    slow = error_from_response(fake_response(
        408, '{"type":"urn:ilqr-service:request-timeout","title":"Request body too slow",'
        '"status":408,"detail":"the body did not arrive within 30 s"}'
    ))
    assert type(slow) is RequestTimeoutError and slow.slug == "request-timeout"
    # Also by status alone, from a proxy that sends its own page.
    assert type(error_from_response(fake_response(408, "timeout", "text/plain"))) is RequestTimeoutError

    unknown = error_from_response(fake_response(
        400, '{"type":"urn:ilqr-service:something-new","title":"New","status":400,"detail":"d"}'
    ))
    assert isinstance(unknown, MalformedRequestError) and unknown.slug == "something-new"


def test_parse_retry_after() -> None:
    assert parse_retry_after(None) is None
    assert parse_retry_after("3") == 3.0
    assert parse_retry_after("-1") is None
    assert parse_retry_after("soon") is None
    now = 1_445_412_450.0  # 2015-10-21 07:27:30 UTC
    assert parse_retry_after("Wed, 21 Oct 2015 07:28:00 GMT", now=now) == pytest.approx(30.0)
    assert parse_retry_after("Wed, 21 Oct 2015 07:27:00 GMT", now=now) == 0.0


def test_unexpected_success_body(monkeypatch: pytest.MonkeyPatch) -> None:
    client = Client("http://example.invalid")
    monkeypatch.setattr(
        client.session, "request",
        lambda *args, **kwargs: fake_response(200, '{"status": "converged"}', "application/json"),
    )
    with client, pytest.raises(UnexpectedResponseError, match="cost"):
        client.solve({})


def test_errors_survive_pickling() -> None:
    error = ValidationError(
        422, "Invalid problem", "2 invalid fields; see `errors`",
        type_="urn:ilqr-service:validation",
        errors=[FieldError("/dt", "must be positive"), FieldError("/horizon", "too big")],
        request_id="r-7",
    )
    copy = pickle.loads(pickle.dumps(error))
    assert type(copy) is ValidationError
    assert copy.pointers == ["/dt", "/horizon"]
    assert copy.request_id == "r-7" and copy.status == 422
    assert str(copy) == str(error)


def test_an_answer_of_the_wrong_shape_is_named_by_pointer(seed_result: SolveResult) -> None:
    # Answers take a fast path (every number a float); anything else falls
    # back to the checks that name the member, and whole numbers still read.
    good = _answer_of(seed_result)
    assert SolveResult.from_dict(good) == seed_result
    whole = copy.deepcopy(good)
    whole["states"][0] = [5, 0, 0, 0, 0, 0]
    parsed = SolveResult.from_dict(whole).states[0]
    assert parsed == [5.0, 0.0, 0.0, 0.0, 0.0, 0.0] and all(type(v) is float for v in parsed)
    for path, value, message in [
        (("states", 3), [0.0] * 5, r"^/states/3: expected 6 numbers, got 5$"),
        (("controls", 2, 1), "x", r"^/controls/2/1: expected a number, got 'x'$"),
        (("controls", 7), {"u1": 1.0}, r"^/controls/7: expected an array, got dict$"),
        (("gains", "feedback", 4, 1, 5), True, r"^/gains/feedback/4/1/5: expected a number, got True$"),
        (("gains", "feedforward", 9), [0.0], r"^/gains/feedforward/9: expected 2 numbers, got 1$"),
        (("closest_approach", 0), None, r"^/closest_approach/0: expected a number, got None$"),
    ]:
        bad = copy.deepcopy(good)
        target = bad
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
        with pytest.raises(ValueError, match=message):
            SolveResult.from_dict(bad)


def test_a_parsed_answer_shares_no_list_with_its_document(seed_result: SolveResult) -> None:
    # The fast path once returned the document's own lists: editing the
    # dict changed the frozen result, and two results parsed from one dict
    # changed together.
    document = _answer_of(seed_result)
    first = SolveResult.from_dict(document)
    second = SolveResult.from_dict(document)
    assert first.gains is not None and second.gains is not None
    document["states"][1][0] = 1e9
    document["controls"][0][0] = 1e9
    document["closest_approach"][0] = 1e9
    document["gains"]["feedback"][0][0][0] = 1e9
    document["gains"]["feedforward"][0][0] = 1e9
    assert first == seed_result and second == seed_result
    first.states[1][0] = -1.0
    first.gains.feedback[0][0][0] = -1.0
    assert second.states[1][0] == seed_result.states[1][0]
    assert seed_result.gains is not None
    assert second.gains.feedback[0][0][0] == seed_result.gains.feedback[0][0][0]


def _answer_of(result: SolveResult) -> Dict[str, Any]:
    """The JSON answer a result was parsed from (its members, as the service writes them)."""
    assert result.gains is not None and result.trace is not None
    return {
        "model": result.model,
        "integrator": result.integrator,
        "status": result.status,
        "cost": result.cost,
        "initial_cost": result.initial_cost,
        "iterations": result.iterations,
        "goal_distance": result.goal_distance,
        "closest_approach": list(result.closest_approach),
        "states": [list(row) for row in result.states],
        "controls": [list(row) for row in result.controls],
        "solve_time_ms": result.solve_time_ms,
        "queue_time_ms": result.queue_time_ms,
        "gains": {
            "feedback": [[list(row) for row in k] for k in result.gains.feedback],
            "feedforward": [list(row) for row in result.gains.feedforward],
            "regularization": result.gains.regularization,
            "about_previous_iterate": result.gains.about_previous_iterate,
        },
        "trace": [
            {key: value for key, value in vars(entry).items() if value is not None} for entry in result.trace
        ],
        "constraint_violation": result.constraint_violation,
        "warnings": [warning.to_dict() for warning in result.warnings],
        "starts": [start.to_dict() for start in result.starts],
        **({} if result.constraint_report is None else {"constraint_report": result.constraint_report.to_dict()}),
    }
