"""Typed, versioned messages: the wire contract between UAV, world and robots.

Every message is a frozen dataclass. On the wire it is one JSON object
`{"type": ..., "v": PROTOCOL_VERSION, "seq": ..., <fields>}`; a message with a
`bytes` field (a camera image) carries those bytes after a NUL byte that JSON
itself never contains. `decode` checks the type name, the version and every
field's type, and raises `ProtocolError` with one line naming the problem, so a
garbage or forged payload on a key is refused, never half-applied.
"""
from __future__ import annotations

import dataclasses
import json
import types
import typing
from dataclasses import dataclass, field
from typing import Any, Callable, TypeVar, get_args, get_origin

from .errors import ProtocolError
from .grid import Cell

PROTOCOL_VERSION = 1


@dataclass(frozen=True)
class Message:
    seq: int = field(default=0, kw_only=True)


@dataclass(frozen=True)
class Plan(Message):
    """UAV -> robot: the cells to occupy at ticks 0..len-1 (cell 0 is the start)."""
    robot: int
    plan_id: str
    path: list[Cell]
    goal: Cell


@dataclass(frozen=True)
class PlanAck(Message):
    robot: int
    plan_id: str
    ok: bool
    error: str = ""


@dataclass(frozen=True)
class Tick(Message):
    """UAV -> all robots: execute step k (move to plan cell k); `ticks` is the makespan."""
    k: int
    ticks: int
    plan_id: str


@dataclass(frozen=True)
class MoveRequest(Message):
    robot: int
    tick: int
    frm: Cell
    to: Cell


@dataclass(frozen=True)
class MoveResult(Message):
    robot: int
    tick: int
    accepted: bool
    cell: Cell
    reason: str = ""


@dataclass(frozen=True)
class MoveBatch(Message):
    """A pool hosting many robots -> world: all its moves of one tick in one query.

    moves: (robot, frm, to) each; answered by one MoveBatchResult.
    """
    tick: int
    moves: list[tuple[int, Cell, Cell]]


@dataclass(frozen=True)
class MoveBatchResult(Message):
    """results: (robot, accepted, cell, reason) for every move of the MoveBatch."""
    tick: int
    results: list[tuple[int, bool, Cell, str]]


@dataclass(frozen=True)
class RobotState(Message):
    robot: int
    tick: int
    cell: Cell
    status: str  # idle | ready | stepping | done | error
    plan_id: str = ""
    error: str = ""


@dataclass(frozen=True)
class Done(Message):
    robot: int
    tick: int
    cell: Cell


@dataclass(frozen=True)
class CameraRequest(Message):
    """Ask the world's camera for the image seen from the vehicle's current pose."""
    pass


@dataclass(frozen=True)
class CameraFrame(Message):
    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    north_m: float  # camera position in the local NED frame whose origin is the grid's top-left corner
    east_m: float
    down_m: float
    yaw_rad: float
    time_s: float
    png: bytes


@dataclass(frozen=True)
class WorldInfoRequest(Message):
    pass


@dataclass(frozen=True)
class WorldInfo(Message):
    """Site calibration, known to the UAV before it flies (not ground truth about robots)."""
    width: int  # grid cells
    height: int
    cell_size_m: float
    home_lat: float
    home_lon: float
    home_alt_m: float


@dataclass(frozen=True)
class RecordRequest(Message):
    pass


@dataclass(frozen=True)
class Record(Message):
    """World -> anyone, for scoring after the mission: what physically happened."""
    ticks: int
    collisions: int
    refused: list[dict[str, Any]]
    executed: dict[str, list[Cell]]
    truth: dict[str, Any]


@dataclass(frozen=True)
class MissionStatus(Message):
    phase: str
    tick: int = 0
    ticks: int = 0
    done: int = 0
    robots: int = 0
    message: str = ""


@dataclass(frozen=True)
class MissionEnd(Message):
    completed: bool
    reason: str = ""


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.__name__: cls
    for cls in (Plan, PlanAck, Tick, MoveRequest, MoveResult, MoveBatch, MoveBatchResult, RobotState, Done, CameraRequest,
                CameraFrame, WorldInfoRequest, WorldInfo, RecordRequest, Record, MissionStatus, MissionEnd)
}

M = TypeVar("M", bound=Message)
_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _bytes_field(cls: type) -> str | None:
    for f in dataclasses.fields(cls):
        if _hints(cls)[f.name] is bytes:
            return f.name
    return None


def encode(msg: Message) -> bytes:
    cls = type(msg)
    blob_name = _bytes_field(cls)
    body: dict[str, Any] = {"type": cls.__name__, "v": PROTOCOL_VERSION}
    for f in dataclasses.fields(cls):
        if f.name != blob_name:
            body[f.name] = getattr(msg, f.name)
    head = json.dumps(body, separators=(",", ":")).encode()
    if blob_name is None:
        return head
    return head + b"\0" + getattr(msg, blob_name)


def decode(data: bytes | bytearray | memoryview, expected: type[M]) -> M:
    """Bytes -> message of type `expected`, or ProtocolError naming what is wrong."""
    data = bytes(data)
    name = expected.__name__
    blob_name, fields = _schema(expected)
    head, blob = data, b""
    if blob_name is not None:
        head, sep, blob = data.partition(b"\0")
        if not sep:
            raise ProtocolError(f"{name}: payload lacks its binary part")
    try:
        body = json.loads(head)
    except (UnicodeDecodeError, ValueError):
        raise ProtocolError(f"{name}: payload is not JSON ({len(data)} bytes: {data[:24]!r})") from None
    if not isinstance(body, dict):
        raise ProtocolError(f"{name}: payload is not a JSON object")
    if body.get("type") != name:
        raise ProtocolError(f"expected a {name} message, got type {str(body.get('type'))[:40]!r}")
    if body.get("v") != PROTOCOL_VERSION:
        raise ProtocolError(f"{name}: schema version {str(body.get('v'))[:20]!r} is not supported "
                            f"(this side speaks {PROTOCOL_VERSION})")
    kwargs: dict[str, Any] = {}
    for fname, required, conv in fields:
        if fname == blob_name:
            kwargs[fname] = blob
        elif fname in body:
            kwargs[fname] = conv(body[fname])
        elif required:
            raise ProtocolError(f"{name}: field {fname!r} is missing")
    return expected(**kwargs)


_SCHEMAS: dict[type, tuple[str | None, list[tuple[str, bool, Callable[[Any], Any]]]]] = {}


def _schema(cls: type) -> tuple[str | None, list[tuple[str, bool, Callable[[Any], Any]]]]:
    """Per message type, once: the blob field and a compiled converter per field (decode is on the hot path)."""
    if cls not in _SCHEMAS:
        hints = _hints(cls)
        fields = [(f.name, f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING,
                   _converter(hints[f.name], f"{cls.__name__}.{f.name}")) for f in dataclasses.fields(cls)]
        _SCHEMAS[cls] = (_bytes_field(cls), fields)
    return _SCHEMAS[cls]


def _fail(where: str, tp: Any, value: Any) -> ProtocolError:
    return ProtocolError(f"{where}: expected {getattr(tp, '__name__', str(tp))}, got {type(value).__name__}")


def _converter(tp: Any, where: str) -> Callable[[Any], Any]:
    origin = get_origin(tp)
    if tp is Any or tp is bytes:  # bytes travel after the NUL, never through JSON
        return lambda v: v
    if tp is bool:
        def conv(v: Any) -> Any:
            if v is True or v is False:
                return v
            raise _fail(where, tp, v)
        return conv
    if tp is int:
        def conv(v: Any) -> Any:
            if type(v) is int:
                return v
            raise _fail(where, tp, v)
        return conv
    if tp is float:
        def conv(v: Any) -> Any:
            if type(v) is float or type(v) is int:
                return float(v)
            raise _fail(where, tp, v)
        return conv
    if tp is str:
        def conv(v: Any) -> Any:
            if type(v) is str:
                return v
            raise _fail(where, tp, v)
        return conv
    if origin is tuple:
        args = get_args(tp)
        if all(a is int for a in args):  # cells: the most common shape by far
            n = len(args)

            def conv(v: Any) -> Any:
                if type(v) is list and len(v) == n and all(type(x) is int for x in v):
                    return tuple(v)
                raise _fail(where, tp, v)
            return conv
        parts = [_converter(a, where) for a in args]

        def conv(v: Any) -> Any:
            if type(v) is list and len(v) == len(parts):
                return tuple(c(x) for c, x in zip(parts, v))
            raise _fail(where, tp, v)
        return conv
    if origin is list:
        item = _converter(get_args(tp)[0], where)

        def conv(v: Any) -> Any:
            if type(v) is list:
                return [item(x) for x in v]
            raise _fail(where, tp, v)
        return conv
    if origin is dict:
        value = _converter(get_args(tp)[1], where)

        def conv(v: Any) -> Any:
            if type(v) is dict:
                return {str(k): value(x) for k, x in v.items()}
            raise _fail(where, tp, v)
        return conv
    if origin in (typing.Union, types.UnionType):
        options = [_converter(a, where) for a in get_args(tp)]

        def conv(v: Any) -> Any:
            for c in options:
                try:
                    return c(v)
                except ProtocolError:
                    pass
            raise _fail(where, tp, v)
        return conv
    raise TypeError(f"unsupported schema type {tp} at {where}")  # a schema author's mistake, not bad input
