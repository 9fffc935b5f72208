"""Typed request and response models of the ilqr-service API.

Requests
    :class:`Problem` and its parts (:class:`Model` or :class:`QuadrotorModel`,
    :class:`Weights`, :class:`Obstacle`, :class:`SolverOptions`,
    :class:`OutputOptions`) are mutable dataclasses meant to be built and
    edited. A field left ``None`` is left out of the request, so the service
    fills in the model's default. ``extra`` keeps members this client version
    does not know, so a problem fetched from a newer service posts back
    unchanged.

Responses
    :class:`SolveResult`, :class:`Gains` and :class:`TraceEntry` are frozen
    dataclasses parsed from the JSON answer; :class:`ModelInfo` (with
    :class:`QuantityInfo` and :class:`ParameterInfo`) describes a model of
    ``GET /models``. Arrays are plain nested lists of floats, as wide as the
    model's state (NX) and controls (NU); ``as_numpy()`` converts them when
    numpy is installed (it is not a dependency).

Only the shape of responses is checked here; the service validates problems.
"""

from __future__ import annotations

import difflib
import math
import operator
from dataclasses import MISSING, dataclass, field, fields
from typing import TYPE_CHECKING, Any, Dict, List, Mapping, Optional, Sequence, Tuple, Type, TypeVar, Union, cast

# A vector field accepts a list or tuple of numbers, or a numpy array (sent
# through its ``tolist``); a matrix field rows of those, or a 2-D array.
# Type checkers see numpy in the alias, so that ``mypy --strict`` accepts
# arrays, which are not ``Sequence``s to it. At run time numpy is optional,
# so the aliases leave it out there and ``typing.get_type_hints`` still
# resolves every field without importing numpy.
# ``Array`` is what ``as_numpy`` returns: ``numpy.ndarray`` to type checkers,
# ``Any`` at run time for the same reason.
if TYPE_CHECKING:  # pragma: no cover
    import numpy

    Floats = Union[Sequence[float], numpy.ndarray[Any, Any]]
    BoundValues = Union[Sequence[Optional[float]], numpy.ndarray[Any, Any]]
    FloatRows = Union[Sequence[Floats], numpy.ndarray[Any, Any]]
    Array = numpy.ndarray[Any, Any]
else:
    Floats = Sequence[float]
    BoundValues = Sequence[Optional[float]]
    FloatRows = Sequence[Sequence[float]]
    Array = Any

__all__ = [
    "SOLVE_STATUSES",
    "DEFAULT_MODEL",
    "Model",
    "QuadrotorModel",
    "Weights",
    "Obstacle",
    "Bounds",
    "Constraints",
    "SolverOptions",
    "OutputOptions",
    "Problem",
    "TraceEntry",
    "Gains",
    "ConstraintStatus",
    "ObstacleStatus",
    "ConstraintReport",
    "SolveWarning",
    "WARNING_CODES",
    "OBSTACLE_SHAPES",
    "SolveResult",
    "QuantityInfo",
    "ParameterInfo",
    "ModelInfo",
    "to_json_value",
    "Floats",
    "FloatRows",
    "BoundValues",
]

#: Every ``status`` a 200 answer may carry. Each one comes with the best trajectory found.
#: ``infeasible``: with hard constraints, their violation could not be
#: brought under ``solver.constraint_tolerance``.
SOLVE_STATUSES = ("converged", "max_iterations", "time_limit", "cancelled", "no_progress", "infeasible")

#: Every ``code`` of a result's :attr:`SolveResult.warnings` this client version knows.
WARNING_CODES = ("goal_not_reached", "inside_obstacle", "negative_thrust")

#: Every ``shape`` of an :class:`Obstacle`.
OBSTACLE_SHAPES = ("point", "circle", "rectangle")

#: The state entries of the position in the plane, ``(x, y)``, of the
#: models this client version knows of: those a result's ``positions``
#: reads when the client has not fetched ``GET /models`` (which says, for
#: every model the service has), and for a model this table does not name.
_BUILTIN_POSITIONS: Dict[str, Tuple[int, int]] = {"quadrotor_2d": (0, 1), "unicycle": (0, 1)}
#: The position entries assumed for a model of neither source.
_FALLBACK_POSITION = (0, 1)


# --------------------------------------------------------------------------- #
# JSON conversion helpers
# --------------------------------------------------------------------------- #


def to_json_value(value: Any) -> Any:
    """Convert a problem value to plain JSON types.

    Handles the request dataclasses (via ``to_dict``), a :class:`SolveResult`
    (as a warm start: its ``controls`` and ``model``), mappings, sequences
    (tuples become lists), numpy arrays and scalars and pandas Series (via
    ``tolist``) and pandas DataFrames (their values, row by row).

    Raises:
        TypeError: for values that have no JSON form.
    """
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if type(value) is list and _plain_numbers(value):
        # Already JSON: a warm start's `result.controls[1:] + ...` (N rows of
        # two floats) took 0.15-0.3 ms through the general walk below, more
        # than a lean seed solve; checked in place it takes a few µs. Copied
        # row by row, as the walk does, so a document shares no list with
        # the problem it came from.
        return [item[:] if type(item) is list else item for item in value]
    # Only this module's request dataclasses go through ``to_dict``: pandas
    # objects have one too, which gives a Series as {index: value}, not an
    # array. Any other dataclass falls through to the TypeError below.
    if isinstance(value, _REQUEST_TYPES):
        return value.to_dict()
    if isinstance(value, SolveResult):  # a warm start
        return value.to_warm_start()
    tolist = getattr(value, "tolist", None)
    if callable(tolist):  # numpy arrays and numpy scalars, pandas Series
        return tolist()
    to_numpy = getattr(value, "to_numpy", None)
    if callable(to_numpy):  # a pandas DataFrame: its rows
        return to_numpy().tolist()
    if isinstance(value, Mapping):
        return {str(key): to_json_value(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)) or (
        isinstance(value, Sequence) and not isinstance(value, (bytes, bytearray))
    ):
        return [to_json_value(item) for item in value]
    raise TypeError(f"cannot send a {type(value).__name__} as JSON: {value!r}")


_NUMBER_TYPES = (float, int)


def _plain_numbers(items: List[Any]) -> bool:
    """Whether ``items`` is a list of floats and ints, or of such lists
    (exact types: ``bool`` and numpy scalars take the general path)."""
    for item in items:
        kind = type(item)
        if kind is list:
            if not all(type(v) in _NUMBER_TYPES for v in item):
                return False
        elif kind not in _NUMBER_TYPES:
            return False
    return True


def _spec_to_dict(spec: Any) -> Dict[str, Any]:
    """Serialise a request dataclass: known fields that are not ``None``, then ``extra``."""
    out: Dict[str, Any] = {}
    for f in fields(spec):
        if f.name == "extra":
            continue
        value = getattr(spec, f.name)
        if value is not None:
            out[f.name] = to_json_value(value)
    for key, value in spec.extra.items():
        out.setdefault(key, to_json_value(value))
    return out


def _non_finite(value: Any, pointer: str = "") -> Optional[Tuple[str, float]]:
    """The JSON pointer and value of the first NaN or infinity in a plain JSON value, if any.

    JSON has no such numbers, so the client refuses to send them; this says
    where, in a 10000-row ``initial_controls`` as in a weight.
    """
    if isinstance(value, float):
        return None if math.isfinite(value) else (pointer, value)
    if isinstance(value, Mapping):
        for key, item in value.items():
            escaped = str(key).replace("~", "~0").replace("/", "~1")
            found = _non_finite(item, f"{pointer}/{escaped}")
            if found is not None:
                return found
    elif isinstance(value, list):
        for i, item in enumerate(value):
            found = _non_finite(item, f"{pointer}/{i}")
            if found is not None:
                return found
    return None


_Spec = TypeVar("_Spec")


def _build(cls: Type[_Spec], known: Dict[str, Any], extra: Dict[str, Any], where: str) -> _Spec:
    """``cls(**known, extra=extra)``, with a missing required member named as the service would."""
    for f in fields(cls):  # type: ignore[arg-type]
        if f.default is MISSING and f.default_factory is MISSING and f.name not in known:
            raise ValueError(f"{where}: missing member {f.name!r}")
    return cls(**known, extra=extra)  # type: ignore[call-arg]


def _split_known(cls: Any, data: Mapping[str, Any], what: str) -> Tuple[Dict[str, Any], Dict[str, Any]]:
    """Split a JSON object into the members ``cls`` declares and the rest."""
    if not isinstance(data, Mapping):
        raise TypeError(f"{what}: expected an object, got {type(data).__name__}")
    names = {f.name for f in fields(cls)} - {"extra"}
    known = {key: value for key, value in data.items() if key in names}
    extra = {key: value for key, value in data.items() if key not in names}
    return known, extra


def _float(value: Any, where: str) -> float:
    """A JSON number as float (ints accepted, booleans and strings rejected)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{where}: expected a number, got {value!r}")
    return float(value)


def _int(value: Any, where: str) -> int:
    """A JSON integer as int."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{where}: expected an integer, got {value!r}")
    return value


def _bool(value: Any, where: str) -> bool:
    """A JSON boolean."""
    if not isinstance(value, bool):
        raise ValueError(f"{where}: expected a boolean, got {value!r}")
    return value


def _string(value: Any, where: str) -> str:
    """A JSON string."""
    if not isinstance(value, str):
        raise ValueError(f"{where}: expected a string, got {value!r}")
    return value


def _list(value: Any, where: str) -> List[Any]:
    if not isinstance(value, list):
        raise ValueError(f"{where}: expected an array, got {type(value).__name__}")
    return value


def _items(value: Any, where: str) -> Sequence[Any]:
    """A request-side array: a list, a tuple or any other non-string sequence."""
    if isinstance(value, (str, bytes, bytearray)) or not isinstance(value, Sequence):
        raise ValueError(f"{where}: expected an array, got {type(value).__name__}")
    return value


def _floats(value: Any, length: Optional[int]) -> bool:
    """Whether ``value`` is already a list of floats of the right length.

    The service writes every number of its arrays as a float, so answers
    take this path: it checks each number without the per-number calls and
    pointer strings of the slow path, which cost more than decoding the JSON
    (0.6 ms against 0.4 ms for the seed's answer).
    """
    return (
        type(value) is list
        and (length is None or len(value) == length)
        and all(type(item) is float for item in value)
    )


def _vector(value: Any, where: str, length: Optional[int] = None) -> List[float]:
    if _floats(value, length):
        # A copy, as the slow path makes: a frozen result must not share
        # its lists with the dict it was parsed from, or with another result.
        return list(value)
    items = _list(value, where)
    if length is not None and len(items) != length:
        raise ValueError(f"{where}: expected {length} numbers, got {len(items)}")
    return [_float(item, f"{where}/{i}") for i, item in enumerate(items)]


def _matrix(value: Any, where: str, columns: Optional[int] = None) -> List[List[float]]:
    """Rows of numbers, every one ``columns`` wide: as wide as the first
    when ``columns`` is ``None`` (the width is the model's)."""
    rows = _list(value, where)
    if columns is None and rows and isinstance(rows[0], list):
        columns = len(rows[0])
    return [
        list(row) if _floats(row, columns) else _vector(row, f"{where}/{i}", columns)
        for i, row in enumerate(rows)
    ]


def _require(data: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in data:
        raise ValueError(f"{where}: missing member {key!r}")
    return data[key]


def _array(rows: List[List[float]]) -> Array:
    """Rows of equal width as a 2-D numpy array ((0, 0) for no rows)."""
    np = _numpy()
    array: Array = np.asarray(rows, dtype=float).reshape(len(rows), len(rows[0]) if rows else 0)
    return array


def _numpy() -> Any:
    """Import numpy on first use, with a helpful message when it is missing."""
    try:
        import numpy
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("as_numpy() needs numpy: pip install numpy") from exc
    return numpy


# --------------------------------------------------------------------------- #
# Request models
# --------------------------------------------------------------------------- #


class _FieldsOnly:
    """Refuses to set an attribute that is not a field of the dataclass.

    A misspelled one (``problem.horizn = 20``) would otherwise be kept on
    the object and left out of the request without a word: the service
    rejects unknown members, but it never sees this one. Members this client
    does not know go in ``extra``. A subclass cannot add plain attributes
    either: give it fields.
    """

    __slots__ = ()

    # Hidden from type checkers: a class with a `__setattr__` taking any
    # name makes them accept any attribute assignment, and mypy --strict
    # already reports `problem.horizn = 20` as an error.
    if not TYPE_CHECKING:

        def __setattr__(self, name, value):
            known = getattr(type(self), "__dataclass_fields__", {})
            # A data descriptor of the class (QuadrotorModel.mass) sets itself.
            if name not in known and not hasattr(getattr(type(self), name, None), "__set__"):
                names = list(known) + [
                    n for n in dir(type(self))
                    if not n.startswith("_") and hasattr(getattr(type(self), n, None), "__set__")
                ]
                close = difflib.get_close_matches(name, names, n=1)
                hint = f"; did you mean {close[0]!r}?" if close else f"; its fields: {', '.join(known)}"
                raise AttributeError(f"{type(self).__name__} has no field {name!r}{hint}")
            object.__setattr__(self, name, value)


#: The model a problem that names none is solved for.
DEFAULT_MODEL = "quadrotor_2d"


@dataclass(eq=False)
class Model(_FieldsOnly):
    """A dynamics model and its parameter values (``model`` in a problem).

    Sent flat, as the service wants it: ``Model("quadrotor_2d", {"mass":
    2.0})`` is ``{"type": "quadrotor_2d", "mass": 2.0}``. Which models exist
    and which parameters each takes is the service's to say
    (:meth:`~ilqr_client.Client.models`); the service has
    ``"quadrotor_2d"`` (parameters ``mass``, ``inertia``, ``arm_length``,
    ``gravity``; :class:`QuadrotorModel` names them) and ``"unicycle"``
    (no parameters). A parameter left out takes the model's default; one
    the model does not have is a 422 at ``/model/<name>``.

    Two models are equal when their ``type`` and ``parameters`` are,
    whichever of the two classes they are.

    Attributes:
        type: The model's name; ``None`` leaves it out, and the service
            then uses its default model, ``"quadrotor_2d"``.
        parameters: Parameter values by name (numbers; a ``None`` value is
            left out of the request).
    """

    type: Optional[str] = None
    parameters: Dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object for this model: ``type`` and every parameter, flat.

        Raises:
            ValueError: if ``parameters`` has a member ``"type"``, which
                would collide with the model's name.
        """
        if "type" in self.parameters:
            raise ValueError("/model: 'type' is the model's name, not a parameter: set Model.type")
        out: Dict[str, Any] = {} if self.type is None else {"type": self.type}
        for name, value in self.parameters.items():
            if value is not None:
                out[name] = to_json_value(value)
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/model") -> "Model":
        """Build from the JSON object (as in ``GET /problems/default``).

        Every member but ``type`` is a parameter. Called on :class:`Model`,
        a planar quadrotor (``type`` ``"quadrotor_2d"``, or none) comes back
        as a :class:`QuadrotorModel`, so that ``problem.model.mass`` reads
        as it did before models were generic.

        Raises:
            TypeError: if ``data`` is not an object.
        """
        if not isinstance(data, Mapping):
            raise TypeError(f"{where}: expected an object, got {type(data).__name__}")
        kind = data.get("type")
        parameters = {str(key): value for key, value in data.items() if key != "type"}
        if cls is Model and kind in (None, DEFAULT_MODEL):
            return QuadrotorModel(type=kind, parameters=parameters)
        return cls(type=kind, parameters=parameters)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Model):
            return NotImplemented
        return (self.type, self.parameters) == (other.type, other.parameters)

    __hash__ = None  # type: ignore[assignment]  # mutable, as the other request dataclasses


class _Parameter:
    """A named parameter of :class:`QuadrotorModel`: reads and writes
    ``parameters[name]``, where ``None`` means left out."""

    def __init__(self, doc: str) -> None:
        self.__doc__ = doc
        self.name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, obj: Optional[Model], owner: Optional[type] = None) -> Optional[float]:
        if obj is None:  # on the class: the descriptor itself, for help() and docs
            return self  # type: ignore[return-value]
        value = obj.parameters.get(self.name)
        return None if value is None else cast(float, value)

    def __set__(self, obj: Model, value: Optional[float]) -> None:
        if value is None:
            obj.parameters.pop(self.name, None)
        else:
            obj.parameters[self.name] = value


class QuadrotorModel(Model):
    """The planar quadrotor, ``quadrotor_2d``, with its parameters by name.

    A :class:`Model` whose ``type`` is ``"quadrotor_2d"``; ``mass``,
    ``inertia``, ``arm_length`` and ``gravity`` read and write
    ``parameters`` (``None``: left out, the service's default).
    ``QuadrotorModel(mass=2.0).to_dict()`` is ``{"type": "quadrotor_2d",
    "mass": 2.0}``.

    Args:
        type: ``"quadrotor_2d"``, or ``None`` to leave ``type`` out of the
            request (the service's default model, which is this one).
        mass: Mass m in kg (1e-6..1e6). Service default 1.
        inertia: Moment of inertia I in kg·m² (1e-6..1e6). Service default 1.
        arm_length: Distance r from the centre to each rotor in m (1e-6..1e6). Service default 1.
        gravity: Gravitational acceleration g in m/s² (0..1e4). Service default 9.81.
        extra: Other members, sent as they are (the service refuses a
            parameter the model does not have); merged into ``parameters``.
        parameters: Parameter values by name, as for :class:`Model`; the
            named arguments above override them.

    Raises:
        ValueError: for a ``type`` other than ``"quadrotor_2d"``.
    """

    mass = _Parameter("Mass m in kg; ``None``: the service's default, 1.")
    inertia = _Parameter("Moment of inertia I in kg·m²; ``None``: the service's default, 1.")
    arm_length = _Parameter("Distance r from the centre to each rotor in m; ``None``: the service's default, 1.")
    gravity = _Parameter("Gravitational acceleration g in m/s²; ``None``: the service's default, 9.81.")

    def __init__(
        self,
        type: Optional[str] = DEFAULT_MODEL,
        mass: Optional[float] = None,
        inertia: Optional[float] = None,
        arm_length: Optional[float] = None,
        gravity: Optional[float] = None,
        extra: Optional[Mapping[str, Any]] = None,
        *,
        parameters: Optional[Mapping[str, Any]] = None,
    ) -> None:
        if type not in (None, DEFAULT_MODEL):
            raise ValueError(f"a QuadrotorModel is of type {DEFAULT_MODEL!r}, got {type!r}: use Model for others")
        merged: Dict[str, Any] = {**(parameters or {}), **(extra or {})}
        for name, value in (("mass", mass), ("inertia", inertia), ("arm_length", arm_length), ("gravity", gravity)):
            if value is not None:
                merged[name] = value
        super().__init__(type=type, parameters=merged)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/model") -> "QuadrotorModel":
        """Build from the JSON object; every member but ``type`` is a parameter.

        Raises:
            TypeError: if ``data`` is not an object.
            ValueError: if its ``type`` is another model's.
        """
        return cast(QuadrotorModel, super().from_dict(data, where))


@dataclass
class Weights(_FieldsOnly):
    """Diagonal cost weights (no ½ factors).

    Attributes:
        state: Diagonal of Q, NX numbers (one per state component of the
            model) in [0, 1e12]. Model default (the quadrotor's: all 1).
        control: Diagonal of R, NU numbers in [0, 1e12]. Model default (the
            quadrotor's: ``[0.1, 0.1]``).
        terminal: Diagonal of Q_f, NX numbers in [0, 1e12]. Model default
            (the quadrotor's: all 50000).
        extra: Members this client does not know; sent as they are.
    """

    state: Optional[Floats] = None
    control: Optional[Floats] = None
    terminal: Optional[Floats] = None
    extra: Dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object for these weights, without ``None`` fields."""
        return _spec_to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Weights":
        """Build from the JSON object."""
        known, extra = _split_known(cls, data, "/weights")
        return _build(cls, known, extra, "/weights")


@dataclass
class Obstacle(_FieldsOnly):
    """An obstacle in the plane of the model's position ``p``: a point, a
    circle or a rectangle.

    ``d`` is the signed distance from ``p`` to it (to the centre for a
    point; negative inside a circle or rectangle). With ``weight`` it adds
    ``weight·exp(−d)`` to every stage cost (soft); with ``clearance`` it is
    hard: ``d ≥ clearance`` at every state after the initial one. It can be
    both. Every field but ``center`` left ``None`` is left out of the request.

    Attributes:
        center: ``[x, y]`` in m, each of magnitude ≤ 1e6. Required.
        weight: Weight q in [0, 1e12] (cost units). ``None`` is left out of
            the request, and the service then uses 1000, the seed obstacle's;
            so ``Obstacle(c)`` and ``Obstacle(c, 1000.0)`` pose the same
            problem, though they compare unequal. 0 for a hard obstacle only.
        shape: One of :data:`OBSTACLE_SHAPES`: ``"point"`` (service
            default), ``"circle"`` (with ``radius``) or ``"rectangle"``
            (with ``size`` and ``angle``).
        radius: A circle's radius in m, 0..1e6; required for a circle, and
            only for one.
        size: A rectangle's ``[width, height]`` in m, each 0..1e6 (width
            along its own x axis, turned by ``angle``); required for a
            rectangle, and only for one.
        angle: A rectangle's counter-clockwise rotation about its centre in
            rad. Service default 0; only for a rectangle.
        clearance: Makes it hard: the smallest signed distance ``d`` (m)
            allowed at every state after the initial one (negative lets the
            position that far inside). ``None``: soft only.
        extra: Members this client does not know; sent as they are.
    """

    center: Floats
    weight: Optional[float] = None
    # After the original two, so that they keep their positions.
    shape: Optional[str] = None
    radius: Optional[float] = None
    size: Optional[Floats] = None
    angle: Optional[float] = None
    clearance: Optional[float] = None
    extra: Dict[str, Any] = field(default_factory=dict)

    @property
    def hard(self) -> bool:
        """Whether it is a hard constraint (it has a ``clearance``)."""
        return self.clearance is not None

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object for this obstacle, without ``None`` fields."""
        return _spec_to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/obstacles/-") -> "Obstacle":
        """Build from the JSON object at ``where``.

        Raises:
            ValueError: if ``center`` is missing.
        """
        known, extra = _split_known(cls, data, where)
        return _build(cls, known, extra, where)


@dataclass
class Bounds(_FieldsOnly):
    """Lower and upper bounds, one entry per component (``constraints.control``
    and ``constraints.state`` in a problem).

    An entry ``None`` (JSON ``null``), or a list left out, is no bound; each
    lower bound must be at most its upper bound (else a 422 at
    ``/constraints/<control|state>/lower/<i>``).

    Attributes:
        lower: NU (control) or NX (state) numbers or ``None``s, in the
            components' units.
        upper: As ``lower``.
        extra: Members this client does not know; sent as they are.
    """

    lower: Optional[BoundValues] = None
    upper: Optional[BoundValues] = None
    extra: Dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object for these bounds, without ``None`` fields (``None``
        entries inside a list are sent as ``null``)."""
        return _spec_to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/constraints/control") -> "Bounds":
        """Build from the JSON object at ``where``."""
        known, extra = _split_known(cls, data, where)
        return _build(cls, known, extra, where)


@dataclass
class Constraints(_FieldsOnly):
    """Hard constraints (``constraints`` in a problem), solved with an
    augmented Lagrangian; the result's :attr:`SolveResult.constraint_report`
    says how they hold. Every member is optional: one left ``None``
    constrains nothing. Hard obstacles are :class:`Obstacle` objects with a
    ``clearance``.

    Attributes:
        control: Bounds on the controls at every step (they hold exactly in
            the result).
        state: Bounds on the state at every step after the initial one.
        goal_tolerance: ``|x_N − goal_state| ≤ goal_tolerance``, NX numbers
            in [0, 1e6], in the state's units; 0 makes a component an
            equality.
        extra: Members this client does not know; sent as they are.
    """

    control: Optional[Bounds] = None
    state: Optional[Bounds] = None
    goal_tolerance: Optional[Floats] = None
    extra: Dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object for these constraints, without ``None`` fields."""
        return _spec_to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Constraints":
        """Build from the JSON object (``control`` and ``state`` as :class:`Bounds`)."""
        known, extra = _split_known(cls, data, "/constraints")
        for key in ("control", "state"):
            if known.get(key) is not None:
                known[key] = Bounds.from_dict(known[key], f"/constraints/{key}")
        return _build(cls, known, extra, "/constraints")


@dataclass
class SolverOptions(_FieldsOnly):
    """How the solver runs and when it stops (``solver`` in a problem).

    Attributes:
        max_iterations: Iteration limit, 0..10000. Service default 500.
        tolerance: Relative cost change below which the solve has converged,
            in [0, 1). Service default 1e-9.
        time_limit_ms: Wall-clock budget in ms, counted from when the service
            admits the request (queue wait included); ``None`` means the
            service's default budget (``--default-time-limit-ms``).
        method: ``"ilqr"`` (service default: the paper's algorithm) or
            ``"ddp"`` (keeps the dynamics' second derivatives; converges in
            a few steps where iLQR crawls, and may find another local
            optimum).
        constraint_tolerance: The largest violation of the hard
            constraints a solve may end with (in the constrained
            quantities' units); a solve that cannot get under it is
            ``infeasible``. Service default 1e-6.
        multi_start: Search over the ways around the obstacles: solve
            from the plain start and from detours on either side of each
            obstacle in the way, and return the cheapest converged answer
            (every start is listed in :attr:`SolveResult.starts`). Service
            default: ``True``, unless initial or warm-start controls are
            given. ``False``: the single local solve, as the paper does it.
        max_starts: The most starts of a search, the plain one included,
            1..32. Service default 7.
        extra: Members this client does not know; sent as they are.
    """

    max_iterations: Optional[int] = None
    tolerance: Optional[float] = None
    time_limit_ms: Optional[int] = None
    method: Optional[str] = None
    constraint_tolerance: Optional[float] = None
    multi_start: Optional[bool] = None
    max_starts: Optional[int] = None
    extra: Dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object for these options, without ``None`` fields."""
        return _spec_to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "SolverOptions":
        """Build from the JSON object."""
        known, extra = _split_known(cls, data, "/solver")
        return _build(cls, known, extra, "/solver")


@dataclass
class OutputOptions(_FieldsOnly):
    """Which optional parts of the result to return (``output`` in a problem).

    Attributes:
        gains: Include the feedback/feedforward gains. Service default true.
        trace: Include the per-iteration trace. Service default true.
        extra: Members this client does not know; sent as they are.
    """

    gains: Optional[bool] = None
    trace: Optional[bool] = None
    extra: Dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object for these options, without ``None`` fields."""
        return _spec_to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "OutputOptions":
        """Build from the JSON object."""
        known, extra = _split_known(cls, data, "/output")
        return _build(cls, known, extra, "/output")


@dataclass
class Problem(_FieldsOnly):
    """A trajectory-optimisation problem for one of the service's models.

    Every field is optional: ``None`` leaves it out of the request and the
    service uses the model's default (``GET /models`` lists them), so
    ``Problem()`` posts ``{}``, the planar quadrotor's seed scenario, and
    ``Problem(model=Model("unicycle"))`` the unicycle's default problem.

    Vector lengths follow the model: NX numbers for a state (6 for
    ``quadrotor_2d``: ``[x, y, θ, ẋ, ẏ, θ̇]`` in m, m, rad, m/s, m/s, rad/s;
    3 for ``unicycle``: ``[x, y, θ]`` in m, m, rad) and NU for a control (2
    for both: rotor thrusts ``[u1, u2]`` in N; ``[v, ω]`` in m/s, rad/s). A
    wrong length is a 422 naming the pointer, the model and the length.
    Sequences may be lists, tuples or numpy arrays.

    Attributes:
        model: Dynamics model and its parameters (a :class:`Model`, or a
            :class:`QuadrotorModel`). Service default: ``quadrotor_2d`` with
            its default parameters.
        integrator: Discretisation: ``"euler"`` (service default) or ``"rk4"``.
        dt: Time step in s, in (0, 10]. Model default (0.05 for the quadrotor).
        horizon: Number of control steps N (1..10000). Model default (100
            for the quadrotor), or the warm start's number of controls.
        initial_state: NX numbers of magnitude ≤ 1e6.
        goal_state: NX numbers of magnitude ≤ 1e6.
        weights: Diagonal cost weights.
        obstacles: Soft obstacles (at most 100), around the model's position
            in the plane; ``[]`` means none, ``None`` the model's default
            (for the quadrotor, one at (4.5, 4.5) with weight 1000).
        initial_controls: Initial guess, N rows of NU numbers (magnitude ≤
            1e12). Not together with ``warm_start``.
        solver: Termination settings.
        output: Which optional parts of the result to return.
        warm_start: A previous result to start from: a :class:`SolveResult`
            (sent as its ``controls`` and ``model``) or a mapping such as an
            answer's JSON (sent as it is). Its controls become the initial
            guess and set the horizon when ``horizon`` is ``None``; its
            model, if it names one, must be this problem's. Not together
            with ``initial_controls``.
        constraints: Hard constraints (control and state bounds, goal
            tolerance); ``None`` leaves them out (none).
        extra: Members this client does not know; sent as they are.
    """

    model: Optional[Model] = None
    integrator: Optional[str] = None
    dt: Optional[float] = None
    horizon: Optional[int] = None
    initial_state: Optional[Floats] = None
    goal_state: Optional[Floats] = None
    weights: Optional[Weights] = None
    obstacles: Optional[Sequence[Obstacle]] = None
    initial_controls: Optional[FloatRows] = None
    solver: Optional[SolverOptions] = None
    output: Optional[OutputOptions] = None
    # Last, so that the fields before keep their positions.
    warm_start: Optional[Union["SolveResult", Mapping[str, Any]]] = None
    constraints: Optional[Constraints] = None
    extra: Dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> Dict[str, Any]:
        """The JSON document to post to ``/solve`` (``None`` fields left out)."""
        return _spec_to_dict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "Problem":
        """Build from a problem document, e.g. the answer of ``GET /problems/default``.

        Explicit JSON ``null`` members become ``None``, which :meth:`to_dict`
        leaves out, so the service applies its default. (Posted as is, the
        service takes ``null`` only for ``initial_controls``, ``warm_start``
        and ``solver.time_limit_ms``, whose defaults are "none given"; send
        :meth:`to_dict`, not ``dataclasses.asdict``.) Unknown members are
        kept in ``extra``.
        """
        known, extra = _split_known(cls, data, "(problem)")
        parsers: Dict[str, Any] = {
            "model": Model.from_dict,
            "weights": Weights.from_dict,
            "solver": SolverOptions.from_dict,
            "output": OutputOptions.from_dict,
            "constraints": Constraints.from_dict,
            "obstacles": lambda items: [
                Obstacle.from_dict(item, f"/obstacles/{i}") for i, item in enumerate(_items(items, "/obstacles"))
            ],
        }
        for key, parse in parsers.items():
            if known.get(key) is not None:
                known[key] = parse(known[key])
        return cls(**known, extra=extra)


#: The dataclasses :func:`to_json_value` serialises with their ``to_dict``.
_REQUEST_TYPES = (Model, Weights, Obstacle, Bounds, Constraints, SolverOptions, OutputOptions, Problem)


# --------------------------------------------------------------------------- #
# Response models
# --------------------------------------------------------------------------- #


@dataclass(frozen=True)
class TraceEntry:
    """One iteration of the solver.

    Attributes:
        iteration: 1-based iteration number.
        cost: Cost after the iteration (unchanged when no step was accepted).
        expected_reduction: Reduction the quadratic model predicted.
        actual_reduction: Reduction achieved (0 when no step was accepted).
        step_size: Line-search step size accepted, 0 when none was.
        regularization: Levenberg–Marquardt regularisation μ of the backward pass.
        feedforward_norm: Mean over steps of ``max_i |d_i| / (|u_i| + 1)``.
        elapsed_ms: Time since the solve started, in ms.
        convex_model: ``True`` when the iteration's backward pass used the
            convex model of the cost instead of its exact Hessian (after a
            fallback, see ``SolveResult.convexified_after_iteration``);
            ``False`` on nearly every solve; ``None`` from a service too old
            to report it.
        outer_iteration: With hard constraints, the outer iteration of the
            augmented Lagrangian this iteration belongs to (1-based); else
            ``None``.
        constraint_violation: With hard constraints, their largest
            violation after the iteration (control bounds, which hold
            throughout, not counted); else ``None``.
        penalty: With hard constraints, the augmented Lagrangian's penalty
            ρ; else ``None``.
        start: In a progress stream of a search, the start (index in
            :attr:`SolveResult.starts`) the row belongs to; else ``None``.
    """

    iteration: int
    cost: float
    expected_reduction: float
    actual_reduction: float
    step_size: float
    regularization: float
    feedforward_norm: float
    elapsed_ms: float
    convex_model: Optional[bool] = None
    outer_iteration: Optional[int] = None
    constraint_violation: Optional[float] = None
    penalty: Optional[float] = None
    start: Optional[int] = None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/trace/-") -> "TraceEntry":
        """Parse one trace row; unknown members are ignored."""
        if not isinstance(data, Mapping):
            raise ValueError(f"{where}: expected an object")
        values: Dict[str, Any] = {}
        for f in fields(cls):
            path = f"{where}/{f.name}"
            parse = _bool if f.name == "convex_model" else _int if f.name in _INT_TRACE_MEMBERS else _float
            if f.name in _OPTIONAL_TRACE_MEMBERS:
                raw = data.get(f.name)
                values[f.name] = None if raw is None else parse(raw, path)
                continue
            values[f.name] = parse(_require(data, f.name, where), path)
        return cls(**values)


_INT_TRACE_MEMBERS = frozenset({"iteration", "outer_iteration", "start"})
_OPTIONAL_TRACE_MEMBERS = frozenset({"convex_model", "outer_iteration", "constraint_violation", "penalty", "start"})


@dataclass(frozen=True)
class Gains:
    """The time-varying feedback policy ``u_k = ū_k + K_k (x_k − x̄_k)``.

    Attributes:
        feedback: K_0..K_{N−1}: N matrices of NU rows (controls) × NX
            columns (states), row-major (2 × 6 for the quadrotor, 2 × 3 for
            the unicycle).
        feedforward: d_0..d_{N−1}: N rows of NU, the control change the solver
            would take next (near zero at convergence).
        regularization: The μ of the backward pass that produced the gains
            (``Q_uu + μI``): 0 for the undamped Riccati gains, larger for
            damped, more cautious ones. ``None`` from a service too old to
            report it.
        about_previous_iterate: ``False`` when the gains are about the
            returned trajectory. ``True`` when the solve stopped
            (``time_limit``, ``cancelled``; ``no_progress`` only where
            the derivatives overflow) after an accepted step, before the
            backward pass about the new iterate completed (often, when a
            tight budget stops a long horizon):
            the gains are then the previous iterate's, one step away: a
            fallback (``K`` further off the more obstacles there are,
            ``feedforward`` not the next step; see docs/limits.md). ``None`` from a
            service too old to report it.
    """

    feedback: List[List[List[float]]]
    feedforward: List[List[float]]
    regularization: Optional[float] = None
    about_previous_iterate: Optional[bool] = None

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        where: str = "/gains",
        *,
        state_dim: Optional[int] = None,
        control_dim: Optional[int] = None,
    ) -> "Gains":
        """Parse the ``gains`` member of a solve answer.

        ``state_dim`` and ``control_dim`` (NX, NU: the widths of the
        result's states and controls) are checked where given; otherwise
        every matrix must be as wide as the first, and ``feedforward`` as
        wide as the matrices are tall.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"{where}: expected an object")
        rows = _list(_require(data, "feedback", where), f"{where}/feedback")
        feedback: List[List[List[float]]] = []
        for i, k in enumerate(rows):
            matrix = _matrix(k, f"{where}/feedback/{i}", state_dim)
            if control_dim is not None and len(matrix) != control_dim:
                raise ValueError(f"{where}/feedback/{i}: expected {control_dim} rows, got {len(matrix)}")
            if state_dim is None and matrix:
                state_dim = len(matrix[0])
            control_dim = len(matrix)
            feedback.append(matrix)
        feedforward = _matrix(_require(data, "feedforward", where), f"{where}/feedforward", control_dim)
        raw_mu = data.get("regularization")
        regularization = None if raw_mu is None else _float(raw_mu, f"{where}/regularization")
        raw_prev = data.get("about_previous_iterate")
        about_previous_iterate = None if raw_prev is None else _bool(raw_prev, f"{where}/about_previous_iterate")
        return cls(
            feedback=feedback,
            feedforward=feedforward,
            regularization=regularization,
            about_previous_iterate=about_previous_iterate,
        )

    def control(self, k: int, state: Floats, nominal_state: Floats,
                nominal_control: Floats) -> List[float]:
        """Evaluate the feedback policy at step ``k``.

        Args:
            k: Step index, 0 ≤ k < N.
            state: The actual state x_k.
            nominal_state: The optimised state x̄_k (``result.states[k]``).
            nominal_control: The optimised control ū_k (``result.controls[k]``).

        Returns:
            ``ū_k + K_k (x_k − x̄_k)``, NU numbers.

        Raises:
            IndexError: if ``k`` is not in 0..N−1 (a negative ``k`` does not
                count from the end).
            TypeError: if ``k`` is not an integer (``True`` and ``1.0`` are
                not steps; numpy integers are).
            ValueError: if a state does not have NX components or the
                control NU (the gain matrix's columns and rows).
        """
        if isinstance(k, bool) or not hasattr(type(k), "__index__"):
            raise TypeError(f"step k must be an integer, got {k!r}")
        k = operator.index(k)
        if not 0 <= k < len(self.feedback):
            raise IndexError(f"step k must be in 0..{len(self.feedback) - 1}, got {k}")
        gain = self.feedback[k]
        nx = len(gain[0]) if gain else 0
        if len(state) != nx or len(nominal_state) != nx:
            raise ValueError(
                f"states must have {nx} components, got {len(state)} and {len(nominal_state)}"
            )
        if len(nominal_control) != len(gain):
            raise ValueError(f"the control must have {len(gain)} components, got {len(nominal_control)}")
        deviation = [a - b for a, b in zip(state, nominal_state)]
        return [
            u + sum(gain * dx for gain, dx in zip(row, deviation))
            for u, row in zip(nominal_control, gain)
        ]

    def as_numpy(self) -> Tuple[Array, Array]:
        """``(feedback, feedforward)`` as numpy arrays of shape (N, NU, NX) and (N, NU).

        Raises:
            ImportError: if numpy is not installed.
        """
        np = _numpy()
        feedback = self.feedback
        nu = len(feedback[0]) if feedback else 0
        nx = len(feedback[0][0]) if feedback and feedback[0] else 0
        return (
            np.asarray(feedback, dtype=float).reshape(len(feedback), nu, nx),
            _array(self.feedforward),
        )


def _object(data: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(data, Mapping):
        raise ValueError(f"{where}: expected an object")
    return data


@dataclass(frozen=True)
class ConstraintStatus:
    """One hard constraint (control bounds, state bounds or goal tolerance)
    at the result.

    Attributes:
        max_violation: Its largest violation, in the constrained quantity's
            unit; 0 when it holds everywhere.
        active_steps: Steps at which it is active: within
            ``solver.constraint_tolerance`` of its bound, or past it (for
            the goal tolerance, 1 when a component is at its tolerance).
    """

    max_violation: float
    active_steps: int

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/constraint_report/control") -> "ConstraintStatus":
        """Parse the JSON object at ``where``; unknown members are ignored."""
        data = _object(data, where)
        return cls(
            max_violation=_float(_require(data, "max_violation", where), f"{where}/max_violation"),
            active_steps=_int(_require(data, "active_steps", where), f"{where}/active_steps"),
        )

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object the service sends for it."""
        return {"max_violation": self.max_violation, "active_steps": self.active_steps}


@dataclass(frozen=True)
class ObstacleStatus:
    """A hard obstacle (one with a ``clearance``) at the result.

    Attributes:
        obstacle: Its index in the problem's ``obstacles``.
        max_violation: How far inside its clearance the path goes at worst
            (m); 0 when the clearance holds at every state.
        active_steps: Steps at which the clearance is active.
        smallest_distance: The smallest signed distance (m) from a state
            after the initial one to the obstacle; at least ``clearance``
            when the constraint holds.
    """

    obstacle: int
    max_violation: float
    active_steps: int
    smallest_distance: float

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/constraint_report/obstacles/-") -> "ObstacleStatus":
        """Parse the JSON object at ``where``; unknown members are ignored."""
        data = _object(data, where)
        values: Dict[str, Any] = {}
        for f in fields(cls):
            raw = _require(data, f.name, where)
            path = f"{where}/{f.name}"
            values[f.name] = _int(raw, path) if f.name in ("obstacle", "active_steps") else _float(raw, path)
        return cls(**values)

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object the service sends for it."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class ConstraintReport:
    """The state of the hard constraints at the result
    (:attr:`SolveResult.constraint_report`; only with hard constraints).

    Attributes:
        outer_iterations: Outer iterations of the augmented Lagrangian
            (each a warm iLQR solve at new multipliers and penalty).
        obstacles: One entry per hard obstacle, in the problem's order.
        control: ``constraints.control``, if given; else ``None``.
        state: ``constraints.state``, if given; else ``None``.
        goal: ``constraints.goal_tolerance``, if given; else ``None``.
    """

    outer_iterations: int
    obstacles: List[ObstacleStatus]
    control: Optional[ConstraintStatus] = None
    state: Optional[ConstraintStatus] = None
    goal: Optional[ConstraintStatus] = None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/constraint_report") -> "ConstraintReport":
        """Parse the ``constraint_report`` of a solve answer; unknown members are ignored."""
        data = _object(data, where)
        obstacles = _list(_require(data, "obstacles", where), f"{where}/obstacles")
        parts: Dict[str, Optional[ConstraintStatus]] = {}
        for key in ("control", "state", "goal"):
            raw = data.get(key)
            parts[key] = None if raw is None else ConstraintStatus.from_dict(raw, f"{where}/{key}")
        return cls(
            outer_iterations=_int(_require(data, "outer_iterations", where), f"{where}/outer_iterations"),
            obstacles=[
                ObstacleStatus.from_dict(item, f"{where}/obstacles/{i}") for i, item in enumerate(obstacles)
            ],
            **parts,
        )

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object the service sends for it (``None`` parts left out)."""
        out: Dict[str, Any] = {"outer_iterations": self.outer_iterations}
        for key in ("control", "state", "goal"):
            part = getattr(self, key)
            if part is not None:
                out[key] = part.to_dict()
        out["obstacles"] = [status.to_dict() for status in self.obstacles]
        return out


@dataclass(frozen=True)
class SolveWarning:
    """Something about a result its ``status`` does not say (an entry of
    :attr:`SolveResult.warnings`). Also importable as ``ilqr_client.Warning``
    (not in ``__all__``, so that ``import *`` keeps Python's ``Warning``).

    Attributes:
        code: What it is, for programs: one of :data:`WARNING_CODES`
            (``"goal_not_reached"``, ``"inside_obstacle"``,
            ``"negative_thrust"``), or a newer service's.
        message: What it is, for people: where, by how much, and how to
            turn it into a hard constraint.
    """

    code: str
    message: str

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/warnings/-") -> "SolveWarning":
        """Parse one entry of ``warnings``; unknown members are ignored."""
        data = _object(data, where)
        return cls(
            code=_string(_require(data, "code", where), f"{where}/code"),
            message=_string(_require(data, "message", where), f"{where}/message"),
        )

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object the service sends for it."""
        return {"code": self.code, "message": self.message}


#: :class:`SolveWarning` by the name the API gives it.
Warning = SolveWarning


@dataclass(frozen=True)
class StartReport:
    """One start of a solve (an entry of :attr:`SolveResult.starts`).

    Attributes:
        label: Which way it went: ``"rest controls"`` (the model's rest:
            hover for the quadrotor), ``"initial_controls"`` or
            ``"warm_start"`` for the plain start, with ``", clearances
            kept"`` for the plain guess solved keeping the clearances it
            has (with hard obstacles); for a detour, the compass side of
            the obstacle it was guided round, e.g. ``"east of obstacle 0"``.
        status: How its solve ended, one of :data:`SOLVE_STATUSES`.
        cost: Its final cost.
        iterations: Its solve's iterations.
        constraint_violation: Its largest hard-constraint violation.
        solve_time_ms: Its time (a detour's guiding solve included), ms.
        chosen: Whether the result is this start's.
        obstacle: A detour's obstacle (index in the problem's obstacles);
            ``None`` for the plain start.
        side: A detour's side of the straight path, facing the goal:
            ``"left"`` or ``"right"``; ``None`` for the plain start.
        guide_iterations: A detour's guiding solve's iterations (the cost
            plus a pull along a route past the obstacle); ``None`` for the
            plain start.
        passes: A detour's answer's side of the straight path at its
            obstacle, ``"left"`` or ``"right"``: not ``side`` when its solve
            slid back round the other way; ``None`` for the plain start.
    """

    label: str
    status: str
    cost: float
    iterations: int
    constraint_violation: float
    solve_time_ms: float
    chosen: bool
    obstacle: Optional[int] = None
    side: Optional[str] = None
    guide_iterations: Optional[int] = None
    passes: Optional[str] = None

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/starts/-") -> "StartReport":
        """Parse one entry of ``starts``; unknown members are ignored."""
        data = _object(data, where)

        def optional(name: str, parse: Any) -> Any:
            raw = data.get(name)
            return None if raw is None else parse(raw, f"{where}/{name}")

        return cls(
            label=_string(_require(data, "label", where), f"{where}/label"),
            status=_string(_require(data, "status", where), f"{where}/status"),
            cost=_float(_require(data, "cost", where), f"{where}/cost"),
            iterations=_int(_require(data, "iterations", where), f"{where}/iterations"),
            constraint_violation=_float(
                _require(data, "constraint_violation", where), f"{where}/constraint_violation"
            ),
            solve_time_ms=_float(_require(data, "solve_time_ms", where), f"{where}/solve_time_ms"),
            chosen=_bool(_require(data, "chosen", where), f"{where}/chosen"),
            obstacle=optional("obstacle", _int),
            side=optional("side", _string),
            guide_iterations=optional("guide_iterations", _int),
            passes=optional("passes", _string),
        )

    def to_dict(self) -> Dict[str, Any]:
        """The JSON object the service sends for it (``None`` members left out)."""
        return {f.name: getattr(self, f.name) for f in fields(self) if getattr(self, f.name) is not None}


@dataclass(frozen=True)
class SolveResult:
    """The answer to ``POST /solve``.

    Every ``status`` is a successful solve carrying the best trajectory found;
    check :attr:`converged` (or ``status``) to see how it ended.

    Attributes:
        status: One of :data:`SOLVE_STATUSES`.
        cost: Final cost J.
        initial_cost: Cost of the initial guess.
        iterations: Iterations performed.
        goal_distance: Distance (m) of the final position from the goal position.
        closest_approach: Per obstacle, the smallest distance (m) from its
            centre to the path: the straight segments between consecutive
            states (the path flown under explicit Euler), so a close pass
            between two knots counts.
        states: x_0..x_N, N + 1 rows of the model's NX state components
            (``[x, y, θ, ẋ, ẏ, θ̇]`` for the quadrotor, ``[x, y, θ]`` for
            the unicycle).
        controls: u_0..u_{N−1}, N rows of its NU controls (``[u1, u2]``,
            ``[v, ω]``).
        solve_time_ms: Time spent solving, in ms.
        queue_time_ms: Time spent waiting for a worker, in ms.
        gains: The feedback policy, or ``None`` when ``output.gains`` was false
            or no backward pass completed (no policy to give). Test ``gains is
            None``, not ``iterations == 0``: a 0-iteration answer has gains
            when its first pass completed (a converged warm start,
            ``max_iterations: 0``, or a budget that ran out after that pass).
        trace: One entry per iteration, or ``None`` when ``output.trace`` was false.
        convexified_after_iteration: ``None`` when the solve used the cost's
            exact Hessian throughout; otherwise the iterations completed when
            it fell back to a convex model of the cost (the exact one left no
            descent at any regularisation, e.g. over a very long horizon).
            Where the convex model converges, the solve checks that point
            with the exact Hessian again (see ``convex_model_at_end``).
        convex_model_at_end: ``None`` without a fallback. ``True`` when the
            gains come from the convex model (the solve stopped on it, or the
            exact Hessian could complete no pass about its minimum; never with
            ``converged``, which the exact Hessian confirms); ``False`` when
            the exact Hessian took over again and gave the gains.
        request_id: The ``x-request-id`` of the answer (not part of equality).
        server_timing: The answer's ``Server-Timing`` header, in ms by name:
            ``queue``, ``solve`` and ``encode`` (serialising and compressing
            the answer, which the time budget does not cover); ``None`` for a
            result not read from an answer (not part of equality).
        attempts: How many times the client sent the request to get this
            answer: 1, or more after retries (an overload, a draining
            instance, a connection failure, including one after the request
            was sent). A control loop that must not act on an answer for an
            old state checks it, or makes the client with ``retries=0``
            (not part of equality).
        model: The model solved for (``model.type``: ``"quadrotor_2d"``,
            ``"unicycle"``); ``None`` from a service too old to say.
        integrator: The integrator used (``"euler"``, ``"rk4"``); ``None``
            from a service too old to say.
        model_position: The state entries of the position in the plane,
            as ``GET /models`` gives them for ``model``, when the client
            that made this result had fetched them (:meth:`Client.models`);
            else ``None``, and :attr:`positions` uses what this client
            version knows (not part of equality).
        constraint_violation: The largest violation of the hard
            constraints at the result (0 without any); at most
            ``solver.constraint_tolerance`` unless ``infeasible`` (or
            stopped early). ``None`` from a service too old to report it.
        constraint_report: How each hard constraint holds; ``None`` for a
            problem without hard constraints.
        warnings: What the ``status`` does not say (goal not reached, path
            through an obstacle, negative thrust), as
            :class:`SolveWarning` entries; empty when there is nothing to say.
        starts: The starts solved from (:class:`StartReport`), the plain
            one first; the result, its trace and gains are the one marked
            ``chosen``. One entry for a single solve; empty from a service
            too old to report them. ``solve_time_ms`` is the wall time of
            them all; the sum of theirs is the CPU time.
    """

    status: str
    cost: float
    initial_cost: float
    iterations: int
    goal_distance: float
    closest_approach: List[float]
    states: List[List[float]]
    controls: List[List[float]]
    solve_time_ms: float
    queue_time_ms: float
    gains: Optional[Gains] = None
    trace: Optional[List[TraceEntry]] = None
    convexified_after_iteration: Optional[int] = None
    convex_model_at_end: Optional[bool] = None
    request_id: Optional[str] = field(default=None, compare=False)
    server_timing: Optional[Dict[str, float]] = field(default=None, compare=False)
    attempts: int = field(default=1, compare=False)
    # Last, so that the fields before keep their positions.
    model: Optional[str] = None
    integrator: Optional[str] = None
    model_position: Optional[Tuple[int, int]] = field(default=None, compare=False)
    constraint_violation: Optional[float] = None
    constraint_report: Optional[ConstraintReport] = None
    warnings: List[SolveWarning] = field(default_factory=list)
    starts: List[StartReport] = field(default_factory=list)

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        request_id: Optional[str] = None,
        server_timing: Optional[Dict[str, float]] = None,
        attempts: int = 1,
        model_position: Optional[Tuple[int, int]] = None,
    ) -> "SolveResult":
        """Parse a solve answer (its body; the two headers are passed apart).

        The widths of ``states`` and ``controls`` are the model's: every
        row must be as wide as the first, and the gains must match them.

        Raises:
            ValueError: if a required member is missing or has the wrong
                type or shape.
        """
        if not isinstance(data, Mapping):
            raise ValueError("expected a JSON object")
        status = _require(data, "status", "(result)")
        if not isinstance(status, str):
            raise ValueError(f"/status: expected a string, got {status!r}")
        gains = data.get("gains")
        trace = data.get("trace")
        convexified = data.get("convexified_after_iteration")
        convex_at_end = data.get("convex_model_at_end")
        model = data.get("model")
        integrator = data.get("integrator")
        # In the order of the answer's members, so that the first one wrong is named.
        cost = _float(_require(data, "cost", "(result)"), "/cost")
        initial_cost = _float(_require(data, "initial_cost", "(result)"), "/initial_cost")
        iterations = _int(_require(data, "iterations", "(result)"), "/iterations")
        goal_distance = _float(_require(data, "goal_distance", "(result)"), "/goal_distance")
        closest_approach = _vector(_require(data, "closest_approach", "(result)"), "/closest_approach")
        states = _matrix(_require(data, "states", "(result)"), "/states")
        controls = _matrix(_require(data, "controls", "(result)"), "/controls")
        violation = data.get("constraint_violation")
        report = data.get("constraint_report")
        warnings = data.get("warnings")
        starts = data.get("starts")
        nx = len(states[0]) if states else None
        nu = len(controls[0]) if controls else None
        return cls(
            status=status,
            cost=cost,
            initial_cost=initial_cost,
            iterations=iterations,
            goal_distance=goal_distance,
            closest_approach=closest_approach,
            states=states,
            controls=controls,
            solve_time_ms=_float(_require(data, "solve_time_ms", "(result)"), "/solve_time_ms"),
            queue_time_ms=_float(_require(data, "queue_time_ms", "(result)"), "/queue_time_ms"),
            gains=None if gains is None else Gains.from_dict(gains, state_dim=nx, control_dim=nu),
            trace=None if trace is None else [
                TraceEntry.from_dict(entry, f"/trace/{i}") for i, entry in enumerate(_list(trace, "/trace"))
            ],
            convexified_after_iteration=(
                None if convexified is None else _int(convexified, "/convexified_after_iteration")
            ),
            convex_model_at_end=(
                None if convex_at_end is None else _bool(convex_at_end, "/convex_model_at_end")
            ),
            model=None if model is None else _string(model, "/model"),
            integrator=None if integrator is None else _string(integrator, "/integrator"),
            request_id=request_id,
            server_timing=server_timing,
            attempts=attempts,
            model_position=model_position,
            constraint_violation=None if violation is None else _float(violation, "/constraint_violation"),
            constraint_report=None if report is None else ConstraintReport.from_dict(report),
            warnings=[] if warnings is None else [
                SolveWarning.from_dict(item, f"/warnings/{i}") for i, item in enumerate(_list(warnings, "/warnings"))
            ],
            starts=[] if starts is None else [
                StartReport.from_dict(item, f"/starts/{i}") for i, item in enumerate(_list(starts, "/starts"))
            ],
        )

    def __repr__(self) -> str:
        """A one-line summary: the arrays are counted, not printed.

        The generated repr printed every state, gain and trace row (50 KB for
        the seed, 4.6 MB at N = 10000) wherever a result was shown in a REPL
        or logged. The fields themselves are unchanged.
        """
        gains = "None" if self.gains is None else f"<{len(self.gains.feedforward)} knots>"
        trace = "None" if self.trace is None else f"<{len(self.trace)} rows>"
        approach = self.closest_approach
        nearest = repr(approach) if len(approach) <= 10 else f"<{len(approach)} obstacles, nearest {min(approach)!r}>"
        return (
            f"SolveResult(model={self.model!r}, integrator={self.integrator!r}, "
            f"status={self.status!r}, cost={self.cost!r}, "
            f"iterations={self.iterations}, horizon={self.horizon}, "
            f"goal_distance={self.goal_distance!r}, closest_approach={nearest}, "
            f"solve_time_ms={self.solve_time_ms!r}, queue_time_ms={self.queue_time_ms!r}, "
            f"gains={gains}, trace={trace}, constraint_violation={self.constraint_violation!r}, "
            f"warnings={[w.code for w in self.warnings]!r}, starts={len(self.starts)}, "
            f"request_id={self.request_id!r})"
        )

    @property
    def converged(self) -> bool:
        """Whether the solve met its tolerance (``status == "converged"``)."""
        return self.status == "converged"

    @property
    def infeasible(self) -> bool:
        """Whether the hard constraints could not be met (``status == "infeasible"``)."""
        return self.status == "infeasible"

    @property
    def horizon(self) -> int:
        """Number of control steps N."""
        return len(self.controls)

    def shifted_controls(self, steps: int = 1) -> List[List[float]]:
        """The controls moved ``steps`` knots earlier, the last one repeated
        to keep N rows: the warm start for re-solving ``steps`` knots later
        (receding-horizon MPC), as ``initial_controls`` (``warm_start``
        takes the controls as they are).

        ``result.shifted_controls()`` is ``result.controls[1:] +
        result.controls[-1:]``, as new lists.

        Raises:
            ValueError: unless ``0 <= steps <= N``.
        """
        n = len(self.controls)
        if isinstance(steps, bool) or not isinstance(steps, int) or not 0 <= steps <= n:
            raise ValueError(f"steps must be an integer from 0 to the horizon {n}, got {steps!r}")
        if n == 0:
            return []
        kept = self.controls[steps:]
        return [list(u) for u in kept] + [list(self.controls[-1]) for _ in range(steps)]

    @property
    def position_entries(self) -> Tuple[int, int]:
        """The state entries ``(ix, iy)`` of the position in the plane.

        From ``GET /models`` when the client had fetched it
        (:attr:`model_position`); else this client version's knowledge of
        the service's models (``(0, 1)`` for both ``quadrotor_2d`` and
        ``unicycle``); else, for a model it does not know, ``(0, 1)``.
        """
        if self.model_position is not None:
            return self.model_position
        return _BUILTIN_POSITIONS.get(self.model or DEFAULT_MODEL, _FALLBACK_POSITION)

    @property
    def positions(self) -> List[Tuple[float, float]]:
        """The trajectory's ``(x, y)`` positions in the plane, N + 1 of them
        (the state entries :attr:`position_entries` names)."""
        ix, iy = self.position_entries
        return [(state[ix], state[iy]) for state in self.states]

    def to_warm_start(self) -> Dict[str, Any]:
        """What a problem's ``warm_start`` needs of this result: its
        ``controls`` (as new lists) and its ``model`` (when known)."""
        out: Dict[str, Any] = {"controls": [list(u) for u in self.controls]}
        if self.model is not None:
            out["model"] = self.model
        return out

    @property
    def cost_history(self) -> List[float]:
        """``initial_cost`` followed by the cost after each iteration (empty without a trace)."""
        if self.trace is None:
            return []
        return [self.initial_cost] + [entry.cost for entry in self.trace]

    def as_numpy(self) -> Dict[str, Array]:
        """The arrays of the result as numpy arrays.

        Returns:
            ``states`` (N+1, NX), ``controls`` (N, NU) and ``closest_approach``
            (M,); plus ``feedback`` (N, NU, NX) and ``feedforward`` (N, NU)
            when the result has gains, and ``cost`` (iterations + 1,) when it
            has a trace. NX and NU are the model's (6 and 2 for the
            quadrotor, 3 and 2 for the unicycle).

        Raises:
            ImportError: if numpy is not installed.
        """
        np = _numpy()
        arrays = {
            "states": _array(self.states),
            "controls": _array(self.controls),
            "closest_approach": np.asarray(self.closest_approach, dtype=float),
        }
        if self.gains is not None:
            arrays["feedback"], arrays["feedforward"] = self.gains.as_numpy()
        if self.trace is not None:
            arrays["cost"] = np.asarray(self.cost_history, dtype=float)
        return arrays


@dataclass(frozen=True)
class QuantityInfo:
    """A state component or a control of a model (``GET /models``).

    Attributes:
        name: Its name in the equations (``"θ"``, ``"u1"``).
        unit: Its SI unit (``"rad"``, ``"N"``).
        description: What it is.
    """

    name: str
    unit: str
    description: str

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str) -> "QuantityInfo":
        """Parse one entry of a model's ``state`` or ``control``."""
        if not isinstance(data, Mapping):
            raise ValueError(f"{where}: expected an object")
        return cls(**{f.name: _string(_require(data, f.name, where), f"{where}/{f.name}") for f in fields(cls)})


@dataclass(frozen=True)
class ParameterInfo:
    """A parameter of a model (``GET /models``): a member of ``model``
    beside ``type``.

    Attributes:
        name: The member's name (``"mass"``).
        unit: Its SI unit.
        description: What it is.
        default: Its value when left out.
        minimum: The smallest value accepted.
        maximum: The largest value accepted.
    """

    name: str
    unit: str
    description: str
    default: float
    minimum: float
    maximum: float

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str) -> "ParameterInfo":
        """Parse one entry of a model's ``parameters``."""
        if not isinstance(data, Mapping):
            raise ValueError(f"{where}: expected an object")
        values: Dict[str, Any] = {}
        for f in fields(cls):
            raw = _require(data, f.name, where)
            path = f"{where}/{f.name}"
            values[f.name] = _string(raw, path) if f.type in ("str", str) else _float(raw, path)
        return cls(**values)


@dataclass(frozen=True)
class ModelInfo:
    """One model the service solves for (an entry of ``GET /models``).

    Attributes:
        type: The name ``model.type`` takes (``"quadrotor_2d"``, ``"unicycle"``).
        description: What the model is, its frame and its equations.
        state: The state's components in order (NX of them): the entries of
            ``initial_state``, ``goal_state``, ``weights.state``,
            ``weights.terminal`` and each row of a result's ``states``.
        control: The controls in order (NU): the entries of
            ``weights.control`` and of each row of ``initial_controls`` and
            of a result's ``controls``.
        parameters: The parameters ``model`` takes beside ``type`` (none for
            the unicycle).
        position: The state entries ``(ix, iy)`` of the position in the
            plane, where obstacles are measured from.
        default_problem: The problem ``{"model": {"type": <type>}}`` stands
            for, every member filled in (a new :class:`Problem`, to edit).
    """

    type: str
    description: str
    state: List[QuantityInfo]
    control: List[QuantityInfo]
    parameters: List[ParameterInfo]
    position: Tuple[int, int]
    default_problem: Problem

    @property
    def state_dim(self) -> int:
        """NX, the number of state components."""
        return len(self.state)

    @property
    def control_dim(self) -> int:
        """NU, the number of controls."""
        return len(self.control)

    def model(self, **parameters: float) -> Model:
        """A :class:`Model` of this type with the given parameter values
        (the others left to their defaults); a :class:`QuadrotorModel` for
        ``quadrotor_2d``.

        Raises:
            ValueError: for a parameter this model does not have.
        """
        known = [p.name for p in self.parameters]
        for name in parameters:
            if name not in known:
                close = difflib.get_close_matches(name, known, n=1)
                hint = f"; did you mean {close[0]!r}?" if close else f"; it has: {', '.join(known) or 'none'}"
                raise ValueError(f"model {self.type!r} has no parameter {name!r}{hint}")
        return Model.from_dict({"type": self.type, **parameters})

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], where: str = "/models/-") -> "ModelInfo":
        """Parse one entry of ``GET /models``.

        Raises:
            ValueError: if a member is missing or has the wrong type.
            TypeError: if the default problem's parts are not objects.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"{where}: expected an object")

        def entries(key: str) -> List[Any]:
            return _list(_require(data, key, where), f"{where}/{key}")

        position = entries("position")
        if len(position) != 2:
            raise ValueError(f"{where}/position: expected 2 indices, got {len(position)}")
        default_problem = _require(data, "default_problem", where)
        if not isinstance(default_problem, Mapping):
            raise ValueError(f"{where}/default_problem: expected an object")
        return cls(
            type=_string(_require(data, "type", where), f"{where}/type"),
            description=_string(_require(data, "description", where), f"{where}/description"),
            state=[QuantityInfo.from_dict(q, f"{where}/state/{i}") for i, q in enumerate(entries("state"))],
            control=[QuantityInfo.from_dict(q, f"{where}/control/{i}") for i, q in enumerate(entries("control"))],
            parameters=[
                ParameterInfo.from_dict(p, f"{where}/parameters/{i}") for i, p in enumerate(entries("parameters"))
            ],
            position=(_int(position[0], f"{where}/position/0"), _int(position[1], f"{where}/position/1")),
            default_problem=Problem.from_dict(default_problem),
        )

    def __repr__(self) -> str:
        """One line: the name, the state's and controls' names and the parameters."""
        state = ", ".join(q.name for q in self.state)
        control = ", ".join(q.name for q in self.control)
        parameters = ", ".join(p.name for p in self.parameters)
        return (
            f"ModelInfo(type={self.type!r}, state=[{state}], control=[{control}], "
            f"parameters=[{parameters}], position={self.position})"
        )


def _parse_server_timing(header: Optional[str]) -> Optional[Dict[str, float]]:
    """The durations of a ``Server-Timing`` header, in ms by metric name.

    ``"queue;dur=0.02, solve;dur=0.35"`` gives ``{"queue": 0.02, "solve":
    0.35}``. A metric without a readable ``dur`` is left out; ``None`` when
    the header is absent.
    """
    if header is None:
        return None
    timing: Dict[str, float] = {}
    for metric in header.split(","):
        name, *params = (part.strip() for part in metric.split(";"))
        for param in params:
            key, _, value = param.partition("=")
            if name and key.strip().lower() == "dur":
                try:
                    timing[name] = float(value.strip().strip('"'))
                except ValueError:
                    pass
    return timing
