"""HTTP client for ilqr-service.

:class:`Client` wraps one :class:`requests.Session` and exposes the API as
typed methods: :meth:`Client.solve`, :meth:`Client.default_problem`,
:meth:`Client.models`, :meth:`Client.health` and :meth:`Client.ready`.

Retry policy (for ``solve``, ``default_problem`` and ``models``; ``retries`` extra
attempts at most, shared by the three kinds of failure):

* 503 ``overloaded``: sleep for the answer's ``Retry-After`` (capped at
  ``max_retry_wait``, plus up to 10 % random jitter so that many clients do
  not come back in lockstep), then try again. When the retries are used up
  the :class:`~ilqr_client.errors.OverloadedError` is raised.
* Connection failures (:class:`requests.ConnectionError`: refused, reset,
  connect timeout, and a connection closed after the request was sent, as
  by a server killed mid-solve) and 503 ``shutting-down``: exponential backoff
  ``backoff · 2^attempt`` (capped at ``max_retry_wait``), then try again;
  the last exception or :class:`~ilqr_client.errors.ShuttingDownError` is
  raised. A draining instance closes the connection with its answer, so the
  retry opens a new one, which a load balancer sends to another replica
  (a rolling deploy), or which reaches the instance that replaced this one.
  Solving has no side effects, so repeating a POST is safe, but a retried
  answer comes later: :attr:`SolveResult.attempts` says how many attempts
  it took, and a control loop that must act on fresh answers only makes its
  client with ``retries=0``.
* Nothing else is retried: not 4xx answers (the same request would fail the
  same way), not 500, and not read timeouts (the service abandons a solve
  whose client has gone, and the same solve would most likely run out of
  time again: raise the timeout instead).

Progress is logged on the ``ilqr_client.client`` logger (a WARNING per retry).
"""

from __future__ import annotations

import json
import logging
import os
import random
import time
from types import TracebackType
from typing import Any, Callable, Dict, List, Mapping, Optional, Tuple, Type, Union, cast
from urllib.parse import urlencode

import requests
import urllib3

from ._version import __version__
from .errors import OverloadedError, ShuttingDownError, UnexpectedResponseError, error_from_response
from .models import (
    DEFAULT_MODEL,
    ModelInfo,
    Problem,
    SolveResult,
    _list,
    _non_finite,
    _parse_server_timing,
    to_json_value,
)

__all__ = ["Client", "ProblemLike", "TimeoutSpec"]

logger = logging.getLogger(__name__)

#: What :meth:`Client.solve` accepts: a :class:`Problem`, a JSON-like mapping, or ``None`` for ``{}``.
ProblemLike = Union[Problem, Mapping[str, Any], None]
#: A requests timeout: seconds for connect and read alike, or ``(connect, read)``.
TimeoutSpec = Union[float, Tuple[float, float]]

#: Seconds :meth:`Client.health` and :meth:`Client.ready` wait by default.
PROBE_TIMEOUT = 5.0

#: Seconds a raised read timeout allows beyond the ``solver.time_limit_ms``
#: it was raised to cover: the budget covers queueing and solving, not
#: encoding the answer and moving it (about 0.1 s for the largest answer on
#: a LAN).
_BUDGET_MARGIN_S = 5.0

#: Budgets above this (about 31 years, in ms) leave the timeout alone: a
#: read timeout much larger overflows the socket layer's time arithmetic
#: (CPython's fails between 9e9 and 1e10 s). A service may be configured to
#: accept any budget, so anything smaller is covered.
_MAX_COVERED_BUDGET_MS = 10**12


def _covering(timeout: Optional[TimeoutSpec], document: Mapping[str, Any]) -> Optional[TimeoutSpec]:
    """``timeout`` with its read part raised, when it is no longer than the
    time budget that ``document`` asks for, to that budget plus
    :data:`_BUDGET_MARGIN_S`.

    Without it, a read timeout below the budget gave up on a solve the service
    was still entitled to run, and the service then cancelled it: the caller
    got ``ReadTimeout`` instead of the trajectory. A read timeout longer than
    the budget is the caller's deadline and is kept: raising every read
    timeout below budget + 5 s turned a control loop's 0.1 s timeout with a
    20 ms budget into 5 s. A budget that is not a
    number from 0 to 1e12 ms (31 years) is left to the service to refuse (422), and a
    timeout requests accepts in another form (a ``urllib3.Timeout``) is
    used as it is.
    """
    solver = document.get("solver")
    limit_ms = solver.get("time_limit_ms") if isinstance(solver, Mapping) else None
    if (
        isinstance(limit_ms, bool)
        or not isinstance(limit_ms, (int, float))
        or not 0 <= limit_ms <= _MAX_COVERED_BUDGET_MS
    ):
        return timeout
    budget = limit_ms / 1000.0
    need = budget + _BUDGET_MARGIN_S

    def short(read: object) -> bool:
        return isinstance(read, (int, float)) and not isinstance(read, bool) and read <= budget

    if isinstance(timeout, tuple):
        connect, read = timeout
        return (connect, need) if short(read) else timeout
    if isinstance(timeout, (int, float)) and short(timeout):
        return (timeout, need)
    return timeout


#: Largest ``deadline`` accepted, in seconds: the bound of
#: :data:`_MAX_COVERED_BUDGET_MS`, for the same reason (a deadline replaces
#: a timeout of ``None``, and one much larger overflows the socket layer).
_MAX_DEADLINE_S = _MAX_COVERED_BUDGET_MS / 1000

#: Least time a retry must have left after its wait to be made, in seconds:
#: an attempt with less would end in a timeout rather than an answer, and
#: the caller would get that ``requests.Timeout`` instead of the error that
#: called for the retry.
_MIN_RETRY_S = 0.01


def _deadline_at(deadline: Optional[float]) -> Optional[float]:
    """The :func:`time.monotonic` instant ``deadline`` seconds from now."""
    if deadline is None:
        return None
    if (
        isinstance(deadline, bool)
        or not isinstance(deadline, (int, float))
        or not 0 < deadline <= _MAX_DEADLINE_S
    ):
        raise ValueError(
            f"deadline must be a positive number of seconds, at most {_MAX_DEADLINE_S:g}, "
            f"got {deadline!r}"
        )
    return time.monotonic() + deadline


def _cut(timeout: Optional[TimeoutSpec], left: float) -> urllib3.Timeout:
    """``timeout`` with its connect and read parts at most ``left`` seconds,
    and ``left`` as the bound on both together.

    requests applies the connect and the read timeout one after the other,
    so cutting each to ``left`` alone let an attempt take nearly twice
    that (a connection retransmitted after a full accept queue, then a
    silent server: 2.5 s for a 1.5 s deadline); urllib3's ``total`` bounds
    their sum.
    """
    connect: Optional[float]
    read: Optional[float]
    if isinstance(timeout, tuple):
        connect, read = timeout
    elif isinstance(timeout, (int, float)):
        connect = read = timeout
    else:
        # None (wait forever) or a form requests takes as is (a
        # urllib3.Timeout): the deadline is the only bound stated in seconds.
        connect = read = None
    return urllib3.Timeout(
        connect=left if connect is None else min(connect, left),
        read=left if read is None else min(read, left),
        total=left,
    )


def _past(deadline_at: Optional[float], wait: float) -> bool:
    """Whether a retry after sleeping ``wait`` seconds would have less than
    :data:`_MIN_RETRY_S` left before ``deadline_at``."""
    return deadline_at is not None and time.monotonic() + wait + _MIN_RETRY_S > deadline_at


_JSON = "application/json"

#: How answers are decoded: orjson where installed (``pip install
#: 'ilqr-client[fast]'``), else the standard library. Both give the same
#: floats, bit for bit (both round correctly); orjson takes about a tenth
#: of the time: 0.85 ms against 7.1 ms for an N = 1000 answer with gains and
#: trace (441 kB), 0.026 against 0.25 ms for a lean seed answer (measured
#: 2026-11-25, the best of five repeats).
_loads: Callable[[bytes], Any]
try:
    import orjson

    _loads = orjson.loads
except ImportError:  # the `fast` extra is not installed
    _loads = json.loads


class Client:
    """A client for one ilqr-service instance.

    Reuses one HTTP session (connection pool) across calls. Use it as a
    context manager, or call :meth:`close`, to release the connections::

        with Client("http://127.0.0.1:8080") as client:
            result = client.solve({"horizon": 50})

    Args:
        base_url: The service's root URL; a path prefix (behind a proxy) is kept.
        timeout: Per-request timeout in seconds, or ``(connect, read)``. A
            solve can legitimately take as long as its time budget (the
            service's default is 10 s, the maximum 60 s). When a problem sets
            ``solver.time_limit_ms`` and the read timeout is no longer than
            that budget, :meth:`solve` raises it to the budget plus 5 s, so
            the answer is not abandoned (and the solve cancelled) while the
            service is still within the budget it was given; a longer read
            timeout is kept (leave room for encoding and moving the answer,
            up to about 0.1 s for the largest). ``solve(timeout=...)``
            overrides it for one call, exactly.
        retries: Extra attempts after an overload (503 with Retry-After), a
            503 ``shutting-down`` or a connection failure; 0 disables
            retrying. See the module docs.
        session: A :class:`requests.Session` to use (for custom adapters,
            proxies, auth...). The client does not close a session it did not
            create, nor change how it reads the environment. For a session
            it creates, the client reads the proxy variables (``HTTP_PROXY``,
            ``NO_PROXY``, ...), ``REQUESTS_CA_BUNDLE``/``CURL_CA_BUNDLE`` and
            ``~/.netrc`` for ``base_url`` once, when it is made, not on every
            call as requests does (0.2-0.4 ms a call), and applies them to
            its own requests only: that session has ``trust_env`` off.
        backoff: First delay in seconds of the exponential backoff after a
            connection failure or a ``shutting-down`` answer (and after an
            overload answer that carries no Retry-After).
        max_retry_wait: Upper bound in seconds on any single wait, whatever
            Retry-After says, before the jitter (up to 10 % more).
        compress: Ask for gzip-compressed answers (``Accept-Encoding: gzip``,
            as requests does by default). Worth it over slow links: a seed
            answer shrinks about 2×. On the same host or a fast LAN, pass
            ``False``: over loopback an N = 1000 round trip (3.8 ms of
            solving) took 20.5 ms compressed and 15.2 ms not.

    Raises:
        ValueError: for a negative ``retries``, ``backoff`` or ``max_retry_wait``,
            and for a ``base_url`` that does not start with ``http://`` or
            ``https://`` unless a ``session`` is given (whose adapters may
            serve other schemes).

    A :class:`requests.Session` is not guaranteed to be thread-safe: give each
    thread its own client (they are cheap) rather than sharing one.
    """

    def __init__(
        self,
        base_url: str = "http://127.0.0.1:8080",
        timeout: Optional[TimeoutSpec] = 30.0,
        retries: int = 3,
        session: Optional[requests.Session] = None,
        *,
        backoff: float = 0.5,
        max_retry_wait: float = 30.0,
        compress: bool = True,
    ) -> None:
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        if backoff < 0 or max_retry_wait < 0:
            raise ValueError("backoff and max_retry_wait must be >= 0")
        if session is None and not base_url.lower().startswith(("http://", "https://")):
            # requests would only fail at the first call, with InvalidSchema
            # or "No connection adapters were found". A session of the
            # caller's may have an adapter for another scheme (http+unix://).
            raise ValueError(
                "base_url must start with http:// or https://, "
                f"e.g. 'http://{base_url}'; got {base_url!r}"
            )
        self.base_url = base_url.rstrip("/")
        self.timeout = timeout
        self.retries = retries
        self.backoff = backoff
        self.max_retry_wait = max_retry_wait
        self.compress = compress
        self._owns_session = session is None
        self.session = session if session is not None else requests.Session()
        # What requests would read from the environment on every call (see
        # _read_environment_once); empty for a session of the caller's.
        self._environment: Dict[str, Any] = {}
        self._netrc_auth: Optional[Tuple[str, str]] = None
        # Each model's position entries, from the last models() call: given
        # to the results of this client's solves (SolveResult.positions).
        self._positions: Dict[str, Tuple[int, int]] = {}
        if self._owns_session:
            self.session.headers["User-Agent"] = (
                f"ilqr-client-python/{__version__} {requests.utils.default_user_agent()}"
            )
            self._read_environment_once()

    def _read_environment_once(self) -> None:
        """Read what requests takes from the environment now, once.

        With ``trust_env`` a session looks up the proxy variables (and
        ``no_proxy``), the CA-bundle variables and ``~/.netrc`` on every call:
        0.2-0.4 ms a call, more than a lean seed solve. Every call goes to
        ``base_url``'s host, so the answer is the same each time; it is kept
        by the client, passed with each of its requests, and the session's
        ``trust_env`` is turned off. Variables changed after the client was
        made are not seen, and ``client.session`` used directly reads none.
        """
        # Kept apart and passed with each of the client's own requests, not
        # set on the session: `client.session` used for another host must
        # not carry this host's netrc credentials or proxy choice.
        self._environment["proxies"] = requests.utils.get_environ_proxies(self.base_url)
        bundle = os.environ.get("REQUESTS_CA_BUNDLE") or os.environ.get("CURL_CA_BUNDLE")
        if bundle:
            self._environment["verify"] = bundle
        self._netrc_auth = requests.utils.get_netrc_auth(self.base_url)
        self.session.trust_env = False

    def _settings(self) -> Dict[str, Any]:
        """The environment's settings for one of the client's requests, with
        requests' precedence: netrc only where the session has no auth."""
        if self._netrc_auth is not None and self.session.auth is None:
            return {**self._environment, "auth": self._netrc_auth}
        return self._environment

    # ------------------------------------------------------------------ #
    # Lifecycle
    # ------------------------------------------------------------------ #

    def close(self) -> None:
        """Close the HTTP session, if this client created it."""
        if self._owns_session:
            self.session.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(
        self,
        exc_type: Optional[Type[BaseException]],
        exc: Optional[BaseException],
        traceback: Optional[TracebackType],
    ) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Client(base_url={self.base_url!r}, timeout={self.timeout!r}, retries={self.retries!r})"

    # ------------------------------------------------------------------ #
    # API
    # ------------------------------------------------------------------ #

    def solve(
        self,
        problem: ProblemLike = None,
        *,
        timeout: Optional[TimeoutSpec] = None,
        request_id: Optional[str] = None,
        deadline: Optional[float] = None,
    ) -> SolveResult:
        """Solve a trajectory-optimisation problem (``POST /solve``).

        Args:
            problem: A :class:`Problem`, a JSON-like mapping (lists, tuples and
                numpy arrays are all fine as values), or ``None`` for ``{}``,
                the seed scenario. Omitted fields take the model's defaults.
            timeout: Overrides the client's timeout for this call, exactly.
                Without it the client's timeout is used, its read part raised
                to the problem's ``solver.time_limit_ms`` plus 5 s when it is
                no longer than that budget (which includes time spent queued).
            request_id: Sent as ``x-request-id``; the service logs it and
                echoes it (also on errors), which helps correlate logs. 1 to
                128 visible ASCII characters (no spaces): the service would
                replace anything else with an id of its own.
            deadline: Seconds this call may take in all (at most 1e9),
                retries and the waits between them included. Each attempt's
                connect and read timeouts, and their sum, are cut to the
                time left; a request whose deadline passed while it was
                being encoded is not sent (``requests.Timeout``); a retry
                that would have less than 10 ms left after its wait is not
                made: the error that called for it is raised at once. The
                service does not know the deadline: give the problem a
                ``solver.time_limit_ms``
                below it, so that the service answers with its best
                trajectory before the client stops waiting (an abandoned
                answer cancels the solve). The read timeout bounds each wait
                for data, so a connection that trickles bytes could outlast
                it; the service sends its answer in one piece.

        Returns:
            The parsed answer. How the solve ended is ``result.status``; every
            status carries the best trajectory found.

        Raises:
            ValidationError: the problem is invalid (``.pointers`` says where).
            OverloadedError: still overloaded after ``retries`` retries.
            ShuttingDownError: the instance is draining for shutdown.
            ApiError: any other error answer (see :mod:`ilqr_client.errors`).
            requests.RequestException: transport failures (after retries for
                connection errors).
            requests.Timeout: no answer within ``timeout``, or within
                what was left of ``deadline``.
            TypeError, ValueError: the problem cannot be encoded as JSON
                (a NaN or infinity: the message starts with its JSON
                pointer), ``request_id`` is not one the service would
                keep, or ``deadline`` is not a positive number of seconds
                up to 1e9.
        """
        # Taken first, so that encoding a long horizon counts against it.
        deadline_at = _deadline_at(deadline)
        if request_id is not None and not (
            0 < len(request_id) <= 128 and all("!" <= c <= "~" for c in request_id)
        ):
            raise ValueError(
                f"request_id must be 1 to 128 visible ASCII characters (no spaces), got {request_id!r}"
            )
        document = self._problem_body(problem)
        try:
            body = json.dumps(document, allow_nan=False, separators=(",", ":"))
        except ValueError:
            # Only now look for where: the walk formats a pointer per number,
            # which costs more than the encoding itself on long horizons.
            found = _non_finite(document)
            if found is None:
                raise
            where, value = found
            raise ValueError(
                f"{where or '(the document)'}: {value!r} cannot be sent: JSON has no "
                "NaN or infinity (the service takes finite numbers only)"
            ) from None
        headers = {"Content-Type": _JSON}
        if request_id is not None:
            headers["x-request-id"] = request_id
        if timeout is None:
            timeout = _covering(self.timeout, document)
        response, attempts = self._request(
            "POST", "/solve", data=body.encode("utf-8"), headers=headers, timeout=timeout,
            deadline_at=deadline_at,
        )
        data = self._json(response)
        model = data.get("model") if isinstance(data, Mapping) else None
        try:
            return SolveResult.from_dict(
                data,
                request_id=response.headers.get("x-request-id"),
                server_timing=_parse_server_timing(response.headers.get("server-timing")),
                attempts=attempts,
                model_position=self._positions.get(model if isinstance(model, str) else DEFAULT_MODEL),
            )
        except (ValueError, TypeError) as exc:
            raise self._unexpected(response, f"malformed solve result: {exc}") from exc

    def default_problem(self, model: Optional[str] = None, *, deadline: Optional[float] = None) -> Problem:
        """Fetch a model's default problem with every field expanded
        (``GET /problems/default``).

        Edit it and pass it to :meth:`solve`; ``problem.to_dict()`` gives the
        JSON document. Its ``solver.time_limit_ms`` is the service's default
        budget; ``initial_controls`` is left out (the model's rest controls).

        Args:
            model: The model's name (``"unicycle"``; :meth:`models` lists
                them). ``None``: the default model's, the planar quadrotor's
                seed scenario (the request then has no query).
            deadline: Seconds this call may take in all (at most 1e9),
                retries and the waits between them included, as for
                :meth:`solve`.

        Raises:
            NotFoundError: the service has no model of that name.
            ApiError: for another error answer.
            requests.Timeout: an attempt ran out of time, or ``deadline``
                left none for one.
            requests.RequestException: other transport failures.
            ValueError: ``deadline`` is not a positive number of seconds.
        """
        deadline_at = _deadline_at(deadline)
        path = "/problems/default"
        if model is not None:
            if not isinstance(model, str):
                raise TypeError(f"model must be a model's name (a str), got {type(model).__name__}")
            path += "?" + urlencode({"model": model})
        response, _ = self._request("GET", path, deadline_at=deadline_at)
        data = self._json(response)
        try:
            return Problem.from_dict(data)
        except (ValueError, TypeError) as exc:
            raise self._unexpected(response, f"malformed problem document: {exc}") from exc

    def models(self, *, deadline: Optional[float] = None) -> List[ModelInfo]:
        """Every model the service solves for (``GET /models``), the default first.

        Each :class:`~ilqr_client.models.ModelInfo` names the model's state
        components and controls (their number is the length of the
        problem's vectors), its parameters with their defaults and ranges,
        the state entries of its position in the plane, and its default
        problem. The client keeps the positions: the results of its later
        solves read their :attr:`~ilqr_client.SolveResult.positions` from
        them.

        Args:
            deadline: Seconds this call may take in all, as for :meth:`solve`.

        Raises:
            ApiError: for an error answer.
            requests.Timeout: an attempt ran out of time, or ``deadline``
                left none for one.
            requests.RequestException: other transport failures.
            ValueError: ``deadline`` is not a positive number of seconds.
        """
        deadline_at = _deadline_at(deadline)
        response, _ = self._request("GET", "/models", deadline_at=deadline_at)
        data = self._json(response)
        try:
            if not isinstance(data, Mapping):
                raise ValueError("expected a JSON object")
            entries = _list(data.get("models"), "/models")
            infos = [ModelInfo.from_dict(entry, f"/models/{i}") for i, entry in enumerate(entries)]
        except (ValueError, TypeError) as exc:
            raise self._unexpected(response, f"malformed model list: {exc}") from exc
        self._positions = {info.type: info.position for info in infos}
        return infos

    def health(self, timeout: TimeoutSpec = PROBE_TIMEOUT) -> bool:
        """Liveness (``GET /healthz``): ``True`` iff the service answers 200.

        A single attempt; any other status, a transport failure or no answer
        within ``timeout`` seconds (default 5, not the client's solve
        timeout: a health check that hangs for 30 s is no health check)
        gives ``False`` rather than an exception.
        """
        return self._probe("/healthz", timeout)

    def ready(self, timeout: TimeoutSpec = PROBE_TIMEOUT) -> bool:
        """Readiness (``GET /readyz``): ``True`` iff the service admits solves.

        ``False`` while it drains for shutdown (503), for any other non-200
        status, when it cannot be reached and when it does not answer within
        ``timeout`` seconds (default 5). A single attempt.
        """
        return self._probe("/readyz", timeout)

    # ------------------------------------------------------------------ #
    # Internals
    # ------------------------------------------------------------------ #

    def _url(self, path: str) -> str:
        return f"{self.base_url}{path}"

    @staticmethod
    def _problem_body(problem: ProblemLike) -> Dict[str, Any]:
        """The JSON object to post for ``problem``."""
        if problem is None:
            return {}
        if isinstance(problem, Problem):
            return problem.to_dict()
        if isinstance(problem, Mapping):
            return cast(Dict[str, Any], to_json_value(problem))
        if isinstance(problem, SolveResult):
            raise TypeError(
                "a SolveResult is not a problem: to start from it, pass it as the "
                "problem's warm_start, e.g. Problem(model=Model(result.model), warm_start=result)"
            )
        raise TypeError(f"problem must be a Problem, a mapping or None, not {type(problem).__name__}")

    def _probe(self, path: str, timeout: TimeoutSpec) -> bool:
        try:
            response = self.session.get(self._url(path), timeout=timeout, **self._settings())
        except requests.RequestException as exc:
            logger.debug("GET %s failed: %s", path, exc)
            return False
        with response:
            return response.status_code == 200

    def _request(
        self,
        method: str,
        path: str,
        *,
        data: Optional[bytes] = None,
        headers: Optional[Dict[str, str]] = None,
        timeout: Optional[TimeoutSpec] = None,
        deadline_at: Optional[float] = None,
    ) -> Tuple[requests.Response, int]:
        """Send a request, retrying overloads and connection failures (see the module docs).

        ``deadline_at`` (a :func:`time.monotonic` instant) cuts each
        attempt's timeouts and their sum to the time left (see
        :func:`_cut`), sends nothing once it has passed, and stops retrying
        where the next wait would leave less than :data:`_MIN_RETRY_S`.

        Returns:
            A response with a status below 400, and how many attempts it took.

        Raises:
            ApiError: the error answer, once retrying is over or not allowed.
            requests.RequestException: the last transport failure.
        """
        url = self._url(path)
        all_headers = {"Accept": f"{_JSON}, application/problem+json"}
        if not self.compress:
            all_headers["Accept-Encoding"] = "identity"
        all_headers.update(headers or {})
        effective_timeout = self.timeout if timeout is None else timeout
        attempt = 0
        while True:
            attempt_timeout: Any = effective_timeout
            if deadline_at is not None:
                left = deadline_at - time.monotonic()
                if left <= 0:
                    # Encoding a long horizon took it all: sending now would
                    # start a solve whose answer nobody waits for.
                    raise requests.Timeout(
                        f"{method} {path}: the deadline passed before the request was sent"
                    )
                attempt_timeout = _cut(effective_timeout, left)
            try:
                response = self.session.request(
                    method, url, data=data, headers=all_headers, timeout=attempt_timeout,
                    **self._settings(),
                )
            except requests.exceptions.SSLError:
                raise  # a certificate problem does not go away by retrying
            except requests.ConnectionError as exc:
                if attempt >= self.retries:
                    raise
                wait = self._backoff(attempt)
                if _past(deadline_at, wait):
                    raise
                logger.warning(
                    "%s %s: connection failed (%s); retry %d/%d in %.2f s",
                    method, path, exc, attempt + 1, self.retries, wait,
                )
            else:
                if response.status_code < 400:
                    return response, attempt + 1
                error = error_from_response(response)
                response.close()
                retried = isinstance(error, (OverloadedError, ShuttingDownError))
                if not retried or attempt >= self.retries:
                    raise error
                if isinstance(error, ShuttingDownError):
                    wait = self._backoff(attempt)
                    reason = "service shutting down"
                elif error.retry_after is not None:
                    wait = self._jitter(min(max(error.retry_after, 0.1), self.max_retry_wait))
                    reason = f"service overloaded (Retry-After {error.retry_after:g} s)"
                else:
                    wait = self._backoff(attempt)
                    reason = "service overloaded (no Retry-After)"
                if _past(deadline_at, wait):
                    raise error
                logger.warning(
                    "%s %s: %s; retry %d/%d in %.2f s [request id %s]",
                    method, path, reason, attempt + 1, self.retries, wait, error.request_id,
                )
            self._sleep(wait)
            attempt += 1

    def _backoff(self, attempt: int) -> float:
        """The exponential backoff before retry ``attempt + 1``, capped, with jitter."""
        return self._jitter(min(self.backoff * 2 ** attempt, self.max_retry_wait))

    @staticmethod
    def _jitter(wait: float) -> float:
        """Add up to 10 % random extra wait (never less than ``wait``)."""
        return wait + random.uniform(0.0, 0.1 * wait)

    @staticmethod
    def _sleep(seconds: float) -> None:
        """Wait between attempts (a separate method so tests can observe it)."""
        time.sleep(seconds)

    def _json(self, response: requests.Response) -> Any:
        """The body of a successful answer as JSON."""
        try:
            return _loads(response.content)
        except ValueError as exc:
            raise self._unexpected(response, f"the body is not JSON: {response.text[:200]!r}") from exc

    @staticmethod
    def _unexpected(response: requests.Response, detail: str) -> UnexpectedResponseError:
        return UnexpectedResponseError(
            response.status_code,
            "Unexpected response",
            detail,
            request_id=response.headers.get("x-request-id"),
        )
