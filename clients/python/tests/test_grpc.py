"""The gRPC front end against the real release binary, with grpcio: Solve
agrees with HTTP, SolveStream streams every iteration, invalid input gets
its google.rpc.BadRequest field violations, overload is RESOURCE_EXHAUSTED
with google.rpc.RetryInfo, and a short deadline returns ``time_limit``.

The stubs are generated from ``proto/ilqr/v1/ilqr.proto`` by grpcio-tools
into a temporary directory (``examples/grpc_client.py`` does the same), so
they always match the contract.
"""

from __future__ import annotations

import importlib.util
import sys
import time
from types import ModuleType
from typing import Any, Iterator, Tuple

import pytest
from conftest import REPO_ROOT, BackgroundSolve, ServiceProcess, busy_problem, free_port, running_service
from ilqr_client import Client

grpc = pytest.importorskip("grpc")
error_details_pb2 = pytest.importorskip("google.rpc.error_details_pb2")
rpc_status = pytest.importorskip("grpc_status.rpc_status")


def _load_example() -> ModuleType:
    """``examples/grpc_client.py``, whose stub generation the tests share."""
    spec = importlib.util.spec_from_file_location("grpc_example", REPO_ROOT / "examples" / "grpc_client.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def stubs(tmp_path_factory: pytest.TempPathFactory) -> Tuple[ModuleType, ModuleType]:
    """``(ilqr_pb2, ilqr_pb2_grpc)`` generated from the proto."""
    out = tmp_path_factory.mktemp("stubs")
    pb2, pb2_grpc = _load_example().load_stubs(out)
    yield pb2, pb2_grpc
    sys.path.remove(str(out))


class GrpcService:
    """A running service with its gRPC port."""

    def __init__(self, process: ServiceProcess, grpc_port: int) -> None:
        self.process = process
        self.target = f"127.0.0.1:{grpc_port}"


def _serve(tmp_path_factory: pytest.TempPathFactory, *args: str) -> Iterator[GrpcService]:
    port = free_port()
    with running_service(tmp_path_factory.mktemp("grpc"), "--grpc-bind", f"127.0.0.1:{port}", *args) as svc:
        channel = grpc.insecure_channel(f"127.0.0.1:{port}")
        grpc.channel_ready_future(channel).result(timeout=10)
        channel.close()
        yield GrpcService(svc, port)


@pytest.fixture(scope="module")
def grpc_service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[GrpcService]:
    """A server with two workers and gRPC on a free port."""
    yield from _serve(tmp_path_factory, "--workers", "2")


def _stub(stubs: Tuple[ModuleType, ModuleType], target: str) -> Tuple[Any, Any]:
    pb2, pb2_grpc = stubs
    channel = grpc.insecure_channel(target)
    return channel, pb2_grpc.TrajectoryOptimizerStub(channel)


def test_solve_of_an_empty_problem_is_posts(stubs: Tuple[ModuleType, ModuleType], grpc_service: GrpcService) -> None:
    pb2, _ = stubs
    channel, stub = _stub(stubs, grpc_service.target)
    with channel:
        r = stub.Solve(pb2.SolveRequest(problem=pb2.Problem()), timeout=30).result
    with Client(grpc_service.process.url) as client:
        http = client.solve({})
    assert r.status == pb2.SOLVE_STATUS_CONVERGED
    assert r.model == "quadrotor_2d" and r.integrator == pb2.INTEGRATOR_EULER
    # The same solve: the same cost to the last digit, the same trajectory.
    assert r.cost == http.cost
    assert r.iterations == http.iterations
    assert (r.state_dim, r.control_dim) == (6, 2)
    assert list(r.states) == [x for row in http.states for x in row]
    assert list(r.controls) == [u for row in http.controls for u in row]
    assert len(r.gains.feedback) == 100 * 2 * 6


def test_a_stream_gives_each_iteration_then_the_result(
    stubs: Tuple[ModuleType, ModuleType], grpc_service: GrpcService
) -> None:
    pb2, _ = stubs
    problem = pb2.Problem(model=pb2.Model(type="unicycle"), integrator=pb2.INTEGRATOR_RK4)
    channel, stub = _stub(stubs, grpc_service.target)
    with channel:
        events = list(stub.SolveStream(pb2.SolveRequest(problem=problem), timeout=30))
    *rows, last = events
    assert last.HasField("result") and all(e.HasField("iteration") for e in rows)
    result = last.result
    assert result.status == pb2.SOLVE_STATUS_CONVERGED
    assert (result.state_dim, result.control_dim) == (3, 2)
    assert len(rows) == result.iterations > 0
    assert [e.iteration.iteration for e in rows] == list(range(1, result.iterations + 1))
    # The rows are the result's own trace.
    assert [e.iteration for e in rows] == list(result.trace)


def test_invalid_input_names_each_field(stubs: Tuple[ModuleType, ModuleType], grpc_service: GrpcService) -> None:
    pb2, _ = stubs
    problem = pb2.Problem(
        model=pb2.Model(type="unicycle", parameters={"mass": 2.0}),
        dt=-1.0,
        initial_state=[0.0, 0.0],
    )
    channel, stub = _stub(stubs, grpc_service.target)
    with channel, pytest.raises(grpc.RpcError) as raised:
        stub.Solve(pb2.SolveRequest(problem=problem), timeout=30)
    error = raised.value
    assert error.code() == grpc.StatusCode.INVALID_ARGUMENT
    status = rpc_status.from_call(error)
    assert status is not None
    violations = []
    for detail in status.details:
        if detail.Is(error_details_pb2.BadRequest.DESCRIPTOR):
            bad = error_details_pb2.BadRequest()
            detail.Unpack(bad)
            violations.extend((v.field, v.description) for v in bad.field_violations)
    fields = [field for field, _ in violations]
    assert fields == ["model.mass", "dt", "initial_state"], violations
    # The same words as the HTTP answer's.
    assert "must have 3 entries for model `unicycle`" in violations[2][1]


def test_overload_is_resource_exhausted_with_retry_info(
    stubs: Tuple[ModuleType, ModuleType], tmp_path_factory: pytest.TempPathFactory
) -> None:
    pb2, _ = stubs
    for svc in _serve(tmp_path_factory, "--workers", "1", "--queue-capacity", "1"):
        # One solve on the worker, one in the queue (with budget enough to
        # run after the first): the next is refused.
        busy = [BackgroundSolve(svc.process.url, busy_problem(ms)).start(settle=0.3) for ms in (2000, 4500)]
        channel, stub = _stub(stubs, svc.target)
        with channel, pytest.raises(grpc.RpcError) as raised:
            stub.Solve(pb2.SolveRequest(problem=pb2.Problem()), timeout=10)
        error = raised.value
        assert error.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        status = rpc_status.from_call(error)
        assert status is not None
        delays = []
        for detail in status.details:
            if detail.Is(error_details_pb2.RetryInfo.DESCRIPTOR):
                info = error_details_pb2.RetryInfo()
                detail.Unpack(info)
                delays.append(info.retry_delay.seconds)
        assert delays and delays[0] >= 1, status
        for b in busy:
            b.result()


def test_a_short_deadline_returns_the_best_trajectory_as_time_limit(
    stubs: Tuple[ModuleType, ModuleType], grpc_service: GrpcService
) -> None:
    pb2, _ = stubs
    doc = busy_problem(60_000)
    problem = pb2.Problem(
        horizon=doc["horizon"],
        dt=doc["dt"],
        solver=pb2.SolverOptions(tolerance=0.0, max_iterations=10000),
        output=pb2.OutputOptions(gains=False, trace=False),
    )
    problem.obstacles.SetInParent()
    for o in doc["obstacles"]:
        problem.obstacles.items.add(center=o["center"], weight=o["weight"])
    channel, stub = _stub(stubs, grpc_service.target)
    started = time.monotonic()
    with channel:
        r = stub.Solve(pb2.SolveRequest(problem=problem), timeout=1.5).result
    took = time.monotonic() - started
    # Not DEADLINE_EXCEEDED: the solve's budget ends before the call's
    # deadline, and the answer arrives within it.
    assert r.status == pb2.SOLVE_STATUS_TIME_LIMIT
    assert r.iterations >= 1
    assert took < 1.5
    assert len(r.states) == (doc["horizon"] + 1) * 6


def test_the_example_client_runs(grpc_service: GrpcService) -> None:
    import subprocess

    done = subprocess.run(
        [sys.executable, str(REPO_ROOT / "examples" / "grpc_client.py"), "--target", grpc_service.target],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "solve: SOLVE_STATUS_CONVERGED" in done.stdout
    assert "invalid problem: INVALID_ARGUMENT" in done.stdout
    assert "  dt: " in done.stdout

