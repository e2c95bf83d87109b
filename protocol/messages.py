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
from typing import Any, TypeVar, get_args, get_origin

from .errors import ProtocolError

PROTOCOL_VERSION = 1
Cell = tuple[int, int]


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
    blob_name = _bytes_field(expected)
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
        raise ProtocolError(f"{name}: schema version {str(body.get('v'))[:20]!r} is not supported (this side speaks {PROTOCOL_VERSION})")
    kwargs: dict[str, Any] = {}
    hints = _hints(expected)
    for f in dataclasses.fields(expected):
        if f.name == blob_name:
            kwargs[f.name] = blob
            continue
        if f.name not in body:
            if f.default is not dataclasses.MISSING:
                continue
            raise ProtocolError(f"{name}: field {f.name!r} is missing")
        kwargs[f.name] = _convert(body[f.name], hints[f.name], f"{name}.{f.name}")
    return expected(**kwargs)


def _convert(value: Any, tp: Any, where: str) -> Any:
    origin = get_origin(tp)
    if tp is Any:
        return value
    if tp is bool:
        if isinstance(value, bool):
            return value
    elif tp is int:
        if isinstance(value, int) and not isinstance(value, bool):
            return value
    elif tp is float:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    elif tp is str:
        if isinstance(value, str):
            return value
    elif origin is tuple:
        args = get_args(tp)
        if isinstance(value, list) and len(value) == len(args):
            return tuple(_convert(v, a, where) for v, a in zip(value, args))
    elif origin is list:
        if isinstance(value, list):
            (arg,) = get_args(tp)
            return [_convert(v, arg, where) for v in value]
    elif origin is dict:
        if isinstance(value, dict):
            _, varg = get_args(tp)
            return {str(k): _convert(v, varg, where) for k, v in value.items()}
    elif origin in (typing.Union, types.UnionType):
        for arg in get_args(tp):
            try:
                return _convert(value, arg, where)
            except ProtocolError:
                pass
    else:  # pragma: no cover - a schema author's mistake, not bad input
        raise TypeError(f"unsupported schema type {tp} at {where}")
    raise ProtocolError(f"{where}: expected {getattr(tp, '__name__', str(tp))}, got {type(value).__name__}")
