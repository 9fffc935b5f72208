"""Python client for ilqr-service, a trajectory optimiser (iLQR) over HTTP for a
planar quadrotor, a unicycle, or any other model the service offers.

Quick start::

    from ilqr_client import Client, ValidationError

    with Client("http://127.0.0.1:8080") as client:
        result = client.solve({"horizon": 80, "goal_state": [3, 8, 0, 0, 0, 0]})
        print(result.status, result.cost, len(result.states))
        unicycle = client.solve({"model": {"type": "unicycle"}})

Modules:

* :mod:`ilqr_client.client`: :class:`Client` and its retry policy.
* :mod:`ilqr_client.models`: typed problem (request) and result (response) dataclasses.
* :mod:`ilqr_client.errors`: the :class:`ApiError` hierarchy for problem+json answers.
* :mod:`ilqr_client.plot`: matplotlib helpers (needs the ``plot`` extra).
"""

from ._version import __version__
from .client import Client, ProblemLike
from .errors import (
    ApiError,
    FieldError,
    MalformedRequestError,
    MethodNotAllowedError,
    NotFoundError,
    OverloadedError,
    PayloadTooLargeError,
    RequestTimeoutError,
    ServerError,
    ShuttingDownError,
    UnexpectedResponseError,
    UnsupportedMediaTypeError,
    ValidationError,
)
from .models import (
    DEFAULT_MODEL,
    OBSTACLE_SHAPES,
    SOLVE_STATUSES,
    WARNING_CODES,
    BoundValues,
    Bounds,
    ConstraintReport,
    Constraints,
    ConstraintStatus,
    FloatRows,
    Floats,
    Gains,
    Model,
    ModelInfo,
    Obstacle,
    ObstacleStatus,
    OutputOptions,
    ParameterInfo,
    Problem,
    QuadrotorModel,
    QuantityInfo,
    SolveResult,
    SolverOptions,
    SolveWarning,
    StartReport,
    TraceEntry,
    Warning,
    Weights,
)

__all__ = [
    "__version__",
    "Client",
    "ProblemLike",
    # models
    "SOLVE_STATUSES",
    "DEFAULT_MODEL",
    "Problem",
    "Model",
    "QuadrotorModel",
    "Weights",
    "Obstacle",
    "Bounds",
    "Constraints",
    "SolverOptions",
    "OutputOptions",
    "SolveResult",
    "Gains",
    "TraceEntry",
    "ConstraintReport",
    "ConstraintStatus",
    "ObstacleStatus",
    "SolveWarning",
    "StartReport",
    "WARNING_CODES",
    "OBSTACLE_SHAPES",
    "ModelInfo",
    "QuantityInfo",
    "ParameterInfo",
    "Floats",
    "FloatRows",
    "BoundValues",
    # ``Warning`` (SolveWarning's other name) is importable but not listed,
    # so that ``from ilqr_client import *`` keeps Python's own ``Warning``.
    # errors
    "ApiError",
    "FieldError",
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
]
