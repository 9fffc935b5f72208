"""Fixtures that run the real ilqr-service binary for the client tests.

The binary is ``$ILQR_SERVICE_BIN`` or, by default, ``release/ilqr-service`` under
``$CARGO_TARGET_DIR`` or ``<repo>/target`` (build it with ``cargo build --release``).
Each server gets a free local port, has its output captured to a log file
(shown when start-up fails), is waited for on ``/healthz`` and is stopped with
SIGTERM at the end.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import threading
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Dict, Iterator, List, Optional

import pytest
import requests
from ilqr_client import Client, SolveResult

REPO_ROOT = Path(__file__).resolve().parents[3]
# Where `cargo build --release` puts the binary: $CARGO_TARGET_DIR if set
# (relative to the repository, as cargo reads it there), else ./target.
DEFAULT_BINARY = REPO_ROOT / os.environ.get("CARGO_TARGET_DIR", "target") / "release" / "ilqr-service"

#: Seed-scenario cost of ``POST /solve {}``: the best of its routes, east
#: of the obstacle, found by the search over starts.
SEED_COST = 5418.304
#: The seed's single local solve from hover (``multi_start: false``), west.
SEED_SINGLE_COST = 5520.212


def service_binary() -> Path:
    """The ilqr-service binary to test, or a test failure explaining how to get one."""
    path = Path(os.environ.get("ILQR_SERVICE_BIN", str(DEFAULT_BINARY)))
    if not path.is_file() or not os.access(path, os.X_OK):
        pytest.fail(
            f"ilqr-service binary not found at {path}. Build it with "
            f"`cargo build --release` in {REPO_ROOT}, or point ILQR_SERVICE_BIN at it.",
            pytrace=False,
        )
    return path


def free_port() -> int:
    """A TCP port that was free a moment ago (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


class ServiceProcess:
    """One ilqr-service process listening on 127.0.0.1 at a free port.

    Args:
        log_dir: Where to write the server's log.
        args: Extra ``serve`` options, e.g. ``["--workers", "1"]``.
    """

    def __init__(self, log_dir: Path, args: List[str]) -> None:
        self.binary = service_binary()
        self.args = args
        self.log_path = log_dir / f"ilqr-service-{id(self)}.log"
        self.port = 0
        self.process: Optional["subprocess.Popen[bytes]"] = None

    @property
    def url(self) -> str:
        """The base URL of the running service."""
        return f"http://127.0.0.1:{self.port}"

    def log(self) -> str:
        """The server's log so far."""
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    def start(self, startup_timeout: float = 15.0) -> None:
        """Start the server and wait until ``/healthz`` answers 200.

        Retries with another port if the chosen one was taken in the meantime.
        """
        # Options given here must win over ILQR_* variables of the environment.
        env = {key: value for key, value in os.environ.items() if not key.startswith("ILQR_")}
        for _ in range(3):
            self.port = free_port()
            command = [str(self.binary), "serve", "--bind", f"127.0.0.1:{self.port}", *self.args]
            with open(self.log_path, "ab") as log:
                self.process = subprocess.Popen(
                    command, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env
                )
            deadline = time.monotonic() + startup_timeout
            while time.monotonic() < deadline:
                if self.process.poll() is not None:
                    break
                try:
                    if requests.get(f"{self.url}/healthz", timeout=0.5).status_code == 200:
                        return
                except requests.RequestException:
                    pass
                time.sleep(0.05)
            if self.process.poll() is None:
                self.stop()
                pytest.fail(f"ilqr-service did not become healthy in {startup_timeout} s:\n{self.log()}")
            if "in use" not in self.log().lower():
                pytest.fail(f"ilqr-service exited with {self.process.returncode}:\n{self.log()}")
        pytest.fail(f"could not find a free port for ilqr-service:\n{self.log()}")

    def signal_shutdown(self) -> None:
        """Send SIGTERM (graceful drain) without waiting for the exit."""
        assert self.process is not None
        self.process.send_signal(signal.SIGTERM)

    def stop(self, timeout: float = 15.0) -> Optional[int]:
        """Terminate (SIGTERM, then SIGKILL after ``timeout``) and reap the process."""
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.terminate()
        try:
            return self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            return self.process.wait()


@contextmanager
def running_service(log_dir: Path, *args: str) -> Iterator[ServiceProcess]:
    """Run an ilqr-service with ``serve`` options ``args`` for the duration of the block."""
    options = list(args)
    if "--shutdown-grace-secs" not in options:
        options += ["--shutdown-grace-secs", "2"]  # quick teardown
    service = ServiceProcess(log_dir, options)
    service.start()
    try:
        yield service
    finally:
        service.stop()


@pytest.fixture(scope="session")
def service(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceProcess]:
    """A shared server with default limits and two workers."""
    with running_service(tmp_path_factory.mktemp("service"), "--workers", "2") as svc:
        yield svc


@pytest.fixture
def client(service: ServiceProcess) -> Iterator[Client]:
    """A client of the shared server."""
    with Client(service.url, timeout=30.0) as c:
        yield c


@pytest.fixture(scope="session")
def seed_result(service: ServiceProcess) -> SolveResult:
    """The answer to ``POST /solve {}``, solved once for the tests that only read it."""
    with Client(service.url) as c:
        return c.solve({})


@pytest.fixture(scope="session")
def unicycle_result(service: ServiceProcess) -> SolveResult:
    """The answer to ``POST /solve {"model": {"type": "unicycle"}}``: the
    unicycle's default problem, solved once for the tests that only read it."""
    with Client(service.url) as c:
        return c.solve({"model": {"type": "unicycle"}})


def busy_problem(time_limit_ms: int) -> Dict[str, Any]:
    """A problem that keeps a worker busy for about ``time_limit_ms``.

    The longest horizon and 100 far-away obstacles make each iteration slow
    (~0.1 s), and tolerance 0 with many iterations keeps the solver going, so
    it ends at its time limit: stopping early with ``no_progress`` takes 40-60
    iterations (several seconds). Gains and trace are left out of the answer.
    """
    return {
        "horizon": 10000,
        "dt": 0.0005,
        "obstacles": [{"center": [100.0 + i, 100.0], "weight": 1.0} for i in range(100)],
        "solver": {"tolerance": 0, "max_iterations": 10000, "time_limit_ms": time_limit_ms},
        "output": {"gains": False, "trace": False},
    }


class BackgroundSolve:
    """A solve running in a thread, to occupy the service's workers."""

    def __init__(self, url: str, problem: Dict[str, Any]) -> None:
        self._url = url
        self._problem = problem
        self._result: Optional[SolveResult] = None
        self._error: Optional[BaseException] = None
        self._thread = threading.Thread(target=self._run, name="background-solve", daemon=True)

    def _run(self) -> None:
        try:
            with Client(self._url, retries=0, timeout=60.0) as c:
                self._result = c.solve(self._problem)
        except BaseException as exc:  # reported by result()
            self._error = exc

    def start(self, settle: float = 0.3) -> "BackgroundSolve":
        """Start the solve and give it ``settle`` seconds to reach a worker."""
        self._thread.start()
        time.sleep(settle)
        return self

    def result(self, timeout: float = 30.0) -> SolveResult:
        """Wait for the solve and return its result (re-raising its error)."""
        self._thread.join(timeout)
        assert not self._thread.is_alive(), "background solve did not finish"
        if self._error is not None:
            raise self._error
        assert self._result is not None
        return self._result
