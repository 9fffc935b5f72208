"""Exceptions raised for error answers of ilqr-service.

The service answers every error with an RFC 9457 problem document
(``application/problem+json``)::

    {"type": "urn:ilqr-service:validation", "title": "Invalid problem",
     "status": 422, "detail": "...", "errors": [{"pointer": "/dt", "detail": "..."}]}

:func:`error_from_response` turns such an answer into an instance of the
:class:`ApiError` subclass that matches its ``type`` (or, for bodies that are
not problem documents, e.g. from a proxy, its HTTP status). Transport
failures (connection refused, timeouts) are not wrapped: they surface as the
``requests`` exceptions they are.
"""

from __future__ import annotations

import email.utils
import json
import time
from dataclasses import dataclass
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Type

import requests

__all__ = [
    "PROBLEM_TYPE_PREFIX",
    "FieldError",
    "ApiError",
    "MalformedRequestError",
    "ValidationError",
    "UnsupportedMediaTypeError",
    "PayloadTooLargeError",
    "RequestTimeoutError",
    "NotFoundError",
    "MethodNotAllowedError",
    "OverloadedError",
    "ShuttingDownError",
    "ServerError",
    "UnexpectedResponseError",
    "error_from_response",
    "parse_retry_after",
]

#: Every problem ``type`` the service sends starts with this prefix; the rest is the slug.
PROBLEM_TYPE_PREFIX = "urn:ilqr-service:"

#: Response header carrying the request id (the service echoes the client's, or makes one).
REQUEST_ID_HEADER = "x-request-id"


@dataclass(frozen=True)
class FieldError:
    """One invalid field of a rejected problem.

    Attributes:
        pointer: RFC 6901 JSON pointer into the posted document, e.g.
            ``"/weights/state/2"``; ``""`` means the document as a whole. A
            missing required field is pointed at where it belongs
            (``"/obstacles/0/center"``), so the pointer may name a member
            the document does not have.
        detail: What was wrong and what is expected.
    """

    pointer: str
    detail: str

    def __str__(self) -> str:
        return f"{self.pointer or '(body)'}: {self.detail}"


class ApiError(Exception):
    """An error answer (HTTP status >= 400) from ilqr-service.

    Attributes:
        status: The HTTP status code.
        type: The problem type URI, e.g. ``"urn:ilqr-service:validation"``, or
            ``None`` when the body was not a problem document.
        title: Short summary of the kind of problem (the reason phrase when
            the body was not a problem document).
        detail: What went wrong in this request (the raw body text when the
            body was not a problem document).
        errors: Per-field errors (validation errors only; empty otherwise).
        request_id: The ``x-request-id`` response header, for finding the
            request in the service's logs.
        retry_after: Seconds the service asked the client to wait before
            retrying (overload only), else ``None``.
        body: The parsed problem document, or ``None`` if the body was not JSON.
    """

    def __init__(
        self,
        status: int,
        title: str,
        detail: str,
        *,
        type_: Optional[str] = None,
        errors: Sequence[FieldError] = (),
        request_id: Optional[str] = None,
        retry_after: Optional[float] = None,
        body: Optional[Mapping[str, Any]] = None,
    ) -> None:
        self.status = status
        self.type = type_
        self.title = title
        self.detail = detail
        self.errors: List[FieldError] = list(errors)
        self.request_id = request_id
        self.retry_after = retry_after
        self.body = body
        super().__init__(status, title, detail)

    def __str__(self) -> str:
        return self._message()

    def __reduce__(self) -> Tuple[Any, ...]:
        # Rebuild from the attributes so that errors survive pickling
        # (multiprocessing, concurrent.futures) with everything they carry.
        return (type(self), (self.status, self.title, self.detail), dict(self.__dict__))

    @property
    def slug(self) -> Optional[str]:
        """The problem type without the ``urn:ilqr-service:`` prefix (``"validation"``, ...)."""
        if self.type is not None and self.type.startswith(PROBLEM_TYPE_PREFIX):
            return self.type[len(PROBLEM_TYPE_PREFIX):]
        return None

    def _message(self) -> str:
        message = f"{self.status} {self.title}"
        if self.detail:
            message += f": {self.detail}"
        if len(self.errors) > 1:
            message += "".join(f"\n  {error}" for error in self.errors)
        if self.request_id:
            message += f" [request id {self.request_id}]"
        return message

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(status={self.status!r}, type={self.type!r}, "
            f"title={self.title!r}, detail={self.detail!r}, request_id={self.request_id!r})"
        )


class MalformedRequestError(ApiError):
    """400 ``malformed-json`` (the body was not valid JSON),
    ``unreadable-body`` (the body could not be read: broken chunked
    encoding, say) or ``bad-query`` (a query parameter the route does not
    take, or a value it cannot read)."""


class ValidationError(ApiError):
    """422 ``validation``: the problem was well-formed JSON but invalid.

    :attr:`errors` lists every offending field as a :class:`FieldError`.
    """

    @property
    def pointers(self) -> List[str]:
        """The JSON pointers of the invalid fields, e.g. ``["/dt", "/weights/state/2"]``."""
        return [error.pointer for error in self.errors]

    @property
    def unlisted(self) -> int:
        """How many more invalid values the service found than :attr:`errors` lists.

        The service lists the first 100 (fewer when huge keys make their
        pointers long: 64 KiB of pointers and messages after the first) and
        counts the rest in the problem document's ``unlisted_errors``; 0 when
        everything is listed.
        """
        raw = (self.body or {}).get("unlisted_errors")
        if isinstance(raw, int) and not isinstance(raw, bool) and raw > 0:
            return raw
        return 0


class UnsupportedMediaTypeError(ApiError):
    """415 ``unsupported-media-type``: the request's Content-Type was not JSON."""


class PayloadTooLargeError(ApiError):
    """413 ``payload-too-large``: the body exceeded the service's size limit."""


class RequestTimeoutError(ApiError):
    """408 ``request-timeout``: the body did not arrive within the service's
    read timeout (``--read-timeout-secs``, default 30 s). Not retried: a
    body that slow usually means a stalled upload, not a busy service.
    """


class NotFoundError(ApiError):
    """404 ``not-found``: no such route (usually a wrong ``base_url``), or
    no such model (``default_problem(model=...)``: ``detail`` lists the
    service's models)."""


class MethodNotAllowedError(ApiError):
    """405 ``method-not-allowed``: the route exists but not for this HTTP method."""


class OverloadedError(ApiError):
    """503 ``overloaded``: every worker is busy and the queue is full, the
    solves queued ahead would take longer than the request's time budget
    allows it to wait, or the service is receiving as many request bodies
    as its memory budget for them allows (``detail`` says which); and 503
    ``expired-in-queue``: admitted, but its budget ran out while it waited
    for a worker, so nothing was solved.

    Transient. :attr:`retry_after` holds the seconds the service asked to
    wait (from the ``Retry-After`` header, else the body's ``retry_after``).
    :class:`~ilqr_client.Client` retries these by itself before raising.
    """


class ShuttingDownError(ApiError):
    """503 ``shutting-down``: this instance is draining; retry on another replica.

    :class:`~ilqr_client.Client` retries these with backoff on a new
    connection (a load balancer sends it to another replica) before raising.
    """


class ServerError(ApiError):
    """500 ``internal`` (a bug in the service) and any other 5xx answer."""


class UnexpectedResponseError(ApiError):
    """A successful answer whose body is not what the API documents."""


_BY_SLUG: Dict[str, Type[ApiError]] = {
    "malformed-json": MalformedRequestError,
    "unreadable-body": MalformedRequestError,
    "bad-query": MalformedRequestError,
    "validation": ValidationError,
    "unsupported-media-type": UnsupportedMediaTypeError,
    "payload-too-large": PayloadTooLargeError,
    "request-timeout": RequestTimeoutError,
    "not-found": NotFoundError,
    "method-not-allowed": MethodNotAllowedError,
    "overloaded": OverloadedError,
    "expired-in-queue": OverloadedError,
    "shutting-down": ShuttingDownError,
    "internal": ServerError,
}

_BY_STATUS: Dict[int, Type[ApiError]] = {
    400: MalformedRequestError,
    404: NotFoundError,
    405: MethodNotAllowedError,
    408: RequestTimeoutError,
    413: PayloadTooLargeError,
    415: UnsupportedMediaTypeError,
    422: ValidationError,
}


def parse_retry_after(value: Optional[str], now: Optional[float] = None) -> Optional[float]:
    """Parse a ``Retry-After`` header value into seconds from now.

    Accepts both forms of RFC 9110: a non-negative number of seconds
    (``"1"``) and an HTTP date (``"Wed, 21 Oct 2015 07:28:00 GMT"``).

    Args:
        value: The header value, or ``None``.
        now: The current POSIX time (for tests); defaults to ``time.time()``.

    Returns:
        The delay in seconds (never negative), or ``None`` if the value is
        missing or cannot be parsed.
    """
    if value is None:
        return None
    value = value.strip()
    try:
        seconds = float(value)
    except ValueError:
        pass
    else:
        return seconds if seconds >= 0 else None
    try:
        when = email.utils.parsedate_to_datetime(value)
    except (TypeError, ValueError, IndexError):
        return None
    if when is None or when.tzinfo is None:  # pragma: no cover - depends on Python version
        return None
    current = time.time() if now is None else now
    return max(0.0, when.timestamp() - current)


def _field_errors(raw: Any) -> List[FieldError]:
    """Parse the problem document's ``errors`` member, skipping malformed entries."""
    if not isinstance(raw, list):
        return []
    parsed = []
    for item in raw:
        if isinstance(item, Mapping):
            parsed.append(FieldError(str(item.get("pointer", "")), str(item.get("detail", ""))))
    return parsed


def _problem_document(response: requests.Response) -> Optional[Dict[str, Any]]:
    """The body as a JSON object if it looks like a problem document, else ``None``."""
    content_type = response.headers.get("content-type", "").split(";")[0].strip().lower()
    if not (content_type == "application/problem+json" or content_type.endswith("json")):
        return None
    try:
        body = json.loads(response.text)
    except ValueError:
        return None
    if not isinstance(body, dict) or ("status" not in body and "type" not in body):
        return None
    return body


def error_from_response(response: requests.Response) -> ApiError:
    """Build the :class:`ApiError` subclass that describes an error answer.

    The class is chosen by the problem document's ``type`` slug; bodies that
    are not problem documents (a proxy's HTML page, say) are classified by
    HTTP status, with the body text as :attr:`ApiError.detail`. A 503 that is
    not a problem document but carries ``Retry-After`` counts as an overload.

    Args:
        response: A response with status >= 400.

    Returns:
        The exception to raise (it is not raised here).
    """
    status = response.status_code
    request_id = response.headers.get(REQUEST_ID_HEADER)
    retry_after = parse_retry_after(response.headers.get("retry-after"))
    body = _problem_document(response)

    if body is None:
        text = response.text.strip()
        if len(text) > 2000:
            text = text[:2000] + "..."
        cls = _BY_STATUS.get(status)
        if cls is None:
            if status == 503 and retry_after is not None:
                cls = OverloadedError
            elif status >= 500:
                cls = ServerError
            else:
                cls = ApiError
        return cls(
            status,
            response.reason or f"HTTP {status}",
            text,
            request_id=request_id,
            retry_after=retry_after,
        )

    type_ = body.get("type")
    type_ = type_ if isinstance(type_, str) else None
    slug = type_[len(PROBLEM_TYPE_PREFIX):] if type_ and type_.startswith(PROBLEM_TYPE_PREFIX) else None
    cls = _BY_SLUG.get(slug or "") or _BY_STATUS.get(status)
    if cls is None:
        cls = ServerError if status >= 500 else ApiError
    if retry_after is None:
        body_retry = body.get("retry_after")
        if isinstance(body_retry, (int, float)) and not isinstance(body_retry, bool) and body_retry >= 0:
            retry_after = float(body_retry)
    return cls(
        status,
        str(body.get("title") or response.reason or f"HTTP {status}"),
        str(body.get("detail") or ""),
        type_=type_,
        errors=_field_errors(body.get("errors")),
        request_id=request_id,
        retry_after=retry_after,
        body=body,
    )
