"""Overload, shutdown and connection failures: what is retried and what is raised.

A server with one worker and no queue is overloaded by a single background
solve; every other solve then gets ``503 overloaded`` with ``Retry-After: 1``.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import time
from pathlib import Path
from typing import Callable, Iterator, List

import pytest
import requests
from conftest import (
    BackgroundSolve,
    ServiceProcess,
    busy_problem,
    free_port,
    running_service,
)
from ilqr_client import Client, OverloadedError, ShuttingDownError

SMALL = {"horizon": 20, "output": {"gains": False, "trace": False}}


@contextlib.contextmanager
def silent_server() -> Iterator[str]:
    """The URL of a socket that listens and never answers: the kernel
    completes connections from its backlog, and nobody reads them."""
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen(4)
        yield f"http://127.0.0.1:{silent.getsockname()[1]}"


@pytest.fixture(scope="module")
def single_worker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    """A server that can run one solve at a time and queues none."""
    with running_service(
        tmp_path_factory.mktemp("single-worker"), "--workers", "1", "--queue-capacity", "0"
    ) as svc:
        yield svc


def test_overload_is_raised_without_retries(single_worker: ServiceProcess) -> None:
    job = BackgroundSolve(single_worker.url, busy_problem(2500)).start()

    with Client(single_worker.url, retries=0) as client:
        started = time.monotonic()
        with pytest.raises(OverloadedError) as info:
            client.solve({})
        assert time.monotonic() - started < 0.5, "retries=0 must not wait"
    error = info.value
    assert error.status == 503
    assert error.type == "urn:ilqr-service:overloaded"
    assert error.retry_after is not None and error.retry_after >= 1
    assert error.request_id

    # With one retry the client waits out Retry-After once, then gives up.
    with Client(single_worker.url, retries=1) as client:
        started = time.monotonic()
        with pytest.raises(OverloadedError):
            client.solve(SMALL)
        assert time.monotonic() - started >= 1.0

    assert len(job.result().states) == 10001


def test_retry_honours_retry_after(single_worker: ServiceProcess, caplog: pytest.LogCaptureFixture) -> None:
    job = BackgroundSolve(single_worker.url, busy_problem(1500)).start()

    with caplog.at_level(logging.WARNING, logger="ilqr_client"):
        with Client(single_worker.url, retries=5) as client:
            started = time.monotonic()
            result = client.solve(SMALL)
            waited = time.monotonic() - started

    assert len(result.states) == 21
    assert waited >= 1.0, f"the client should have slept for Retry-After, waited {waited:.2f} s"
    # The answer says it took more than one attempt (a control loop may not
    # want to act on it), as many as the log shows.
    assert result.attempts >= 2
    # The retry got through because the busy solve released the worker.
    assert len(job.result().states) == 10001
    retries = [r for r in caplog.records if "overloaded" in r.getMessage()]
    assert retries and "Retry-After 1" in retries[0].getMessage()
    assert result.attempts == len(retries) + 1


def test_shutting_down_is_retried_with_backoff(
    tmp_path: Path, caplog: pytest.LogCaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    # One instance, draining: every retry reaches it again (behind a load
    # balancer the new connection would reach another replica), so the
    # client backs off, retries, and raises the last answer.
    with running_service(tmp_path, "--workers", "1", "--shutdown-grace-secs", "10") as svc:
        job = BackgroundSolve(svc.url, busy_problem(1500)).start()
        svc.signal_shutdown()
        with Client(svc.url, retries=2, backoff=0.05) as client:
            deadline = time.monotonic() + 5
            while client.ready() and time.monotonic() < deadline:
                time.sleep(0.02)
            assert client.ready() is False

            sleeps: List[float] = []
            monkeypatch.setattr(client, "_sleep", sleeps.append)
            with caplog.at_level(logging.WARNING, logger="ilqr_client"):
                with pytest.raises(ShuttingDownError) as info:
                    client.solve(SMALL)
        assert len(sleeps) == 2
        assert 0.05 <= sleeps[0] <= 0.055 and 0.1 <= sleeps[1] <= 0.11
        retries = [r.getMessage() for r in caplog.records if "shutting down" in r.getMessage()]
        assert len(retries) == 2 and "retry 1/2" in retries[0], retries
        assert info.value.status == 503 and info.value.retry_after is None
        # The solve that was in flight is allowed to finish.
        assert len(job.result().states) == 10001
        assert svc.stop() == 0


def test_connection_failures_are_retried_with_backoff(monkeypatch: pytest.MonkeyPatch) -> None:
    url = f"http://127.0.0.1:{free_port()}"  # nothing listens there
    client = Client(url, retries=2, backoff=0.05, timeout=2)
    sleeps: List[float] = []
    monkeypatch.setattr(client, "_sleep", sleeps.append)
    with client:
        with pytest.raises(requests.ConnectionError):
            client.solve({})
        assert len(sleeps) == 2
        assert 0.05 <= sleeps[0] <= 0.055 and 0.1 <= sleeps[1] <= 0.11
        assert client.health() is False
        assert client.ready() is False


def test_a_probe_of_a_service_that_does_not_answer_gives_up_on_its_own_timeout() -> None:
    # The kernel completes the connection from the listen backlog, and
    # nobody ever answers: the probe waited the client's solve timeout (30 s).
    with silent_server() as url:
        with Client(url, timeout=30) as client:
            started = time.monotonic()
            assert client.health(timeout=0.2) is False
            assert client.ready(timeout=0.2) is False
            assert time.monotonic() - started < 2


def test_the_proxy_environment_is_read_once_when_the_client_is_made(
    service: ServiceProcess, monkeypatch: pytest.MonkeyPatch
) -> None:
    # requests reads the proxy variables on every call (0.2-0.4 ms); the
    # client reads them when made. A proxy set then is used (nothing listens
    # there, so the call fails), and one set later is not.
    for name in ["no_proxy", "NO_PROXY", "all_proxy", "ALL_PROXY", "https_proxy", "HTTPS_PROXY"]:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("HTTP_PROXY", f"http://127.0.0.1:{free_port()}")
    monkeypatch.setenv("http_proxy", f"http://127.0.0.1:{free_port()}")
    with Client(service.url, retries=0) as proxied:
        assert proxied.session.trust_env is False
        monkeypatch.delenv("HTTP_PROXY")
        monkeypatch.delenv("http_proxy")
        with pytest.raises(requests.exceptions.ProxyError):
            proxied.solve(SMALL)
    with Client(service.url, retries=0) as direct:
        monkeypatch.setenv("HTTP_PROXY", f"http://127.0.0.1:{free_port()}")
        assert len(direct.solve(SMALL).states) == 21
    # NO_PROXY is honoured as requests honours it.
    monkeypatch.setenv("NO_PROXY", "127.0.0.1")
    with Client(service.url, retries=0) as bypassing:
        assert len(bypassing.solve(SMALL).states) == 21
    # A session of the caller's is left as it is.
    with Client(service.url, retries=0, session=requests.Session()) as own:
        assert own.session.trust_env is True


def test_netrc_credentials_go_to_the_service_only(
    service: ServiceProcess, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    # Read once, like the proxies, and sent with the client's own requests;
    # the session itself must not carry them to another host.
    netrc = tmp_path / "netrc"
    netrc.write_text("machine 127.0.0.1 login svc password s3cret\n")
    netrc.chmod(0o600)
    monkeypatch.setenv("NETRC", str(netrc))
    sent: List[str] = []
    with Client(service.url, retries=0) as client:
        client.session.hooks["response"].append(
            lambda r, *args, **kwargs: sent.append(r.request.headers.get("Authorization", ""))
        )
        assert len(client.solve(SMALL).states) == 21
        assert client.health()
        assert sent[0].startswith("Basic ") and sent[1] == sent[0], sent
        assert client.session.auth is None
        other = client.session.prepare_request(requests.Request("GET", "http://example.invalid/x"))
        assert "Authorization" not in other.headers
        # An auth the caller puts on the session wins, as in requests.
        client.session.auth = ("mine", "pw")
        client.solve(SMALL)
        assert sent[-1] != sent[0] and sent[-1].startswith("Basic "), sent


def recorded(sleeps: List[float]) -> Callable[[float], None]:
    """A sleep that also notes how long it slept."""

    def sleep(seconds: float) -> None:
        sleeps.append(seconds)
        time.sleep(seconds)

    return sleep


def test_a_deadline_stops_retrying_where_the_wait_would_pass_it(
    single_worker: ServiceProcess, monkeypatch: pytest.MonkeyPatch
) -> None:
    job = BackgroundSolve(single_worker.url, busy_problem(2500)).start()

    with Client(single_worker.url, retries=5) as client:
        sleeps: List[float] = []
        monkeypatch.setattr(client, "_sleep", sleeps.append)
        started = time.monotonic()
        # Retry-After is 1 s: waiting it out would end past a 0.5 s deadline.
        with pytest.raises(OverloadedError):
            client.solve(SMALL, deadline=0.5)
        assert time.monotonic() - started < 0.5
        assert sleeps == []

        # With room for one wait but not two, exactly one retry is made.
        monkeypatch.setattr(client, "_sleep", recorded(sleeps))
        started = time.monotonic()
        with pytest.raises(OverloadedError):
            client.solve(SMALL, deadline=1.8)
        assert len(sleeps) == 1 and 1.0 <= sleeps[0] <= 1.1
        assert time.monotonic() - started < 1.8

    assert len(job.result().states) == 10001


def test_a_deadline_cuts_the_read_timeout_and_the_connection_backoff(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Connected, never answered: the read timeout (30 s) is cut to the
    # deadline.
    with silent_server() as url:
        with Client(url, timeout=30) as client:
            started = time.monotonic()
            with pytest.raises(requests.Timeout):
                client.solve({}, deadline=0.3)
            assert 0.25 <= time.monotonic() - started < 2

    # Nothing listens: backoffs of 0.2 and 0.4 s, and the second would end
    # past the deadline.
    url = f"http://127.0.0.1:{free_port()}"
    with Client(url, retries=5, backoff=0.2) as client:
        sleeps: List[float] = []
        monkeypatch.setattr(client, "_sleep", recorded(sleeps))
        started = time.monotonic()
        with pytest.raises(requests.ConnectionError):
            client.solve({}, deadline=0.5)
        assert len(sleeps) == 1 and 0.2 <= sleeps[0] <= 0.22
        assert time.monotonic() - started < 0.5


def test_a_deadline_bounds_a_slow_connect_and_the_read_together() -> None:
    import threading

    # The accept queue is full, so the client's SYN is dropped and sent
    # again about 1 s later; the server frees the queue at 0.5 s, so the
    # connection opens at about 1 s, and the server then never answers.
    # With the connect and read timeouts each cut to 1.5 s alone, the call
    # took 2.5 s.
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(0)
        port = server.getsockname()[1]
        filler = socket.create_connection(("127.0.0.1", port))
        accepted: List[socket.socket] = []

        def free_the_queue() -> None:
            time.sleep(0.5)
            accepted.append(server.accept()[0])

        threading.Thread(target=free_the_queue, daemon=True).start()
        try:
            with Client(f"http://127.0.0.1:{port}", timeout=30, retries=0) as client:
                started = time.monotonic()
                with pytest.raises(requests.Timeout):
                    client.solve({}, deadline=1.5)
                assert time.monotonic() - started < 1.75
        finally:
            filler.close()
            for sock in accepted:
                sock.close()


def test_a_deadline_that_passed_while_encoding_sends_nothing(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Nothing listens: a request sent would be a ConnectionError.
    with Client(f"http://127.0.0.1:{free_port()}", retries=0) as client:
        sent: List[str] = []
        original = client.session.request

        def request(method: str, url: str, **kwargs: object) -> requests.Response:
            sent.append(url)
            return original(method, url, **kwargs)  # type: ignore[arg-type]

        monkeypatch.setattr(client.session, "request", request)
        # About 25 ms of encoding against a 1 ms deadline.
        problem = {"horizon": 10000, "initial_controls": [[4.905, 4.905]] * 10000}
        with pytest.raises(requests.Timeout, match="deadline passed before the request was sent"):
            client.solve(problem, deadline=0.001)
        assert sent == []


@pytest.mark.parametrize("deadline", [0, -1, float("nan"), float("inf"), 1e10, True, "1"])
def test_a_deadline_must_be_a_positive_number_of_seconds(deadline: object) -> None:
    with Client("http://127.0.0.1:1") as client:
        with pytest.raises(ValueError, match="deadline must be a positive number of seconds"):
            client.solve({}, deadline=deadline)  # type: ignore[arg-type]
        with pytest.raises(ValueError, match="deadline must be a positive number of seconds"):
            client.default_problem(deadline=deadline)  # type: ignore[arg-type]


def test_a_deadline_bounds_fetching_the_default_problem(single_worker: ServiceProcess) -> None:
    # Connected, never answered: without a deadline the client's 30 s read
    # timeout would apply.
    with silent_server() as url:
        with Client(url, timeout=30) as client:
            started = time.monotonic()
            with pytest.raises(requests.Timeout):
                client.default_problem(deadline=0.3)
            assert 0.25 <= time.monotonic() - started < 2
    # Against the service it is the default, whole.
    with Client(single_worker.url) as client:
        problem = client.default_problem(deadline=5)
        assert problem.horizon == 100 and len(problem.initial_state) == 6
