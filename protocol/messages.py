"""Typed, versioned messages: the wire contract between UAV, world and robots.

Every message is a frozen dataclass. On the wire it is one UTF-8 JSON object
`{"type": ..., "v": SCHEMA_VERSION, "seq": ..., <fields>}`; a message with a
`bytes` field (a camera image) carries those bytes after a NUL byte that JSON
itself never contains. `decode` checks the size, the type name, the version and
every field's type and bounds, and raises `ProtocolError` with one line naming
the problem, so a garbage or forged payload on a key is refused, never
half-applied, and never costs a receiver more than the limits below.

The bounds live in the field annotations (`Range`, `MaxLen`, `Pattern` inside
`Annotated`); the decoder and the JSON Schemas (`protocol.schemas`) are both
derived from them.
"""
from __future__ import annotations

import dataclasses
import json
import re
import sys
import types
import typing
from dataclasses import dataclass, field
from typing import Annotated, Any, Callable, ClassVar, Literal, NamedTuple, TypeVar, get_args, get_origin

from . import grid
from .errors import ProtocolError

# `v` of every message: the version of the message format. No field was removed or retyped since 1,
# so a reader of 1 decodes every message of today (docs/protocol.md, Versioning).
SCHEMA_VERSION = 1
# The version of the rules of docs/protocol.md a robot keeps, which it states in PlanAck.protocol
# (absent: 1). 2 is today's document; its changelog says what changed from 1.
PROTOCOL_VERSION = 2
MAX_PROTOCOL = 1_000

# Limits: every number that sizes a receiver's memory or work is bounded when a message is
# decoded. docs/protocol.md repeats them for other implementations.
# Each type's JSON text is at most its own limit (json_limit): the longest its bounded fields can
# write plus MARGIN_BYTES for optional fields a newer sender adds, and never more than its cap.
MAX_MESSAGE_BYTES = 8 * 2**20    # the cap of every type but Record's (a full MoveBatchResult fits)
MAX_RECORD_BYTES = 128 * 2**20   # Record's cap: it holds every robot's executed path
MARGIN_BYTES = 4_096             # room for fields this side does not know, in every type's limit
MAX_IMAGE_BYTES = 64 * 2**20     # a CameraFrame's PNG, after the NUL
MAX_DEPTH = 32                   # nested arrays and objects, the message's own object included
MAX_COUNT = 2**53 - 1            # seq and counters: the largest integer every JSON reader holds exactly
MAX_ROBOT_ID = 9_999_999         # seven decimal digits, also as Record.executed's keys
MAX_ROBOTS = 65_536              # entries of a MoveBatch, a MoveBatchResult, Record.executed
MAX_TICKS = 100_000              # tick numbers and makespans
MAX_PATH_CELLS = MAX_TICKS + 1   # a planned or executed path: one cell per tick from 0
MAX_GRID_SIDE = grid.MAX_GRID_SIDE  # cells per floor row or column (kept in grid.py: maps check it too)
MAX_IMAGE_SIDE = 16_384          # camera image width and height, pixels
MAX_TEXT_CHARS = 4_096           # any string
MAX_REFUSED = 1_000_000          # entries of Record.refused
MAX_KEYS = 256                   # keys of a free-form object (Record.truth, an entry of Record.refused)
MAX_LANDMARKS = 65_536           # entries of WorldInfo.landmarks
MAX_FLOAT = sys.float_info.max


@dataclass(frozen=True)
class Range:
    """A number's inclusive bounds; `open_lo` excludes the lower one (a positive float)."""
    lo: int | float
    hi: int | float
    open_lo: bool = False


@dataclass(frozen=True)
class MaxLen:
    """At most `n` characters of a string, items of an array, keys of an object or bytes of a binary tail."""
    n: int


@dataclass(frozen=True)
class Pattern:
    """A string's whole text matches `regex` (written so that JSON Schema reads it the same)."""
    regex: str


Count = Annotated[int, Range(0, MAX_COUNT)]
RobotId = Annotated[int, Range(0, MAX_ROBOT_ID)]
RobotKey = Annotated[str, MaxLen(len(str(MAX_ROBOT_ID))), Pattern("0|[1-9][0-9]*")]  # an id as str(id) writes it
Robots = Annotated[int, Range(0, MAX_ROBOTS)]
TickNo = Annotated[int, Range(0, MAX_TICKS)]
Coord = Annotated[int, Range(0, MAX_GRID_SIDE - 1)]
Cell = tuple[Coord, Coord]  # protocol.grid.Cell with bounded coordinates
Path = Annotated[list[Cell], MaxLen(MAX_PATH_CELLS)]
Text = Annotated[str, MaxLen(MAX_TEXT_CHARS)]
Finite = Annotated[float, Range(-MAX_FLOAT, MAX_FLOAT)]
Positive = Annotated[float, Range(0.0, MAX_FLOAT, open_lo=True)]
Object = Annotated[dict[Text, Any], MaxLen(MAX_KEYS)]
NonNegative = Annotated[float, Range(0.0, MAX_FLOAT)]
Status = Literal["idle", "ready", "stepping", "done", "error"]
ImageEncoding = Literal["png", "jpeg"]
# (marker id, centre east_m, centre north_m) in the local NED frame of CameraFrame
Landmark = tuple[Annotated[int, Range(0, MAX_ROBOT_ID)], Finite, Finite]


@dataclass(frozen=True)
class Message:
    json_cap_bytes: ClassVar[int] = MAX_MESSAGE_BYTES   # its JSON text's limit is json_limit(type), at most this
    seq: Count = field(default=0, kw_only=True)


@dataclass(frozen=True)
class Plan(Message):
    """UAV -> robot: path[i] is the cell to occupy at tick start_tick + i (path[0] is where it stands).

    A replan during a mission starts at the tick the fleet holds at; every tick after it
    names the new plan_id, so all robots switch at the same boundary.
    """
    robot: RobotId
    plan_id: Text
    path: Path
    goal: Cell
    start_tick: TickNo = 0
    # The moves the path uses: 4 (orthogonal) or 8 (diagonals too); 0 = not stated, the
    # robot's own configuration applies (what an older UAV means).
    connectivity: Literal[0, 4, 8] = 0


@dataclass(frozen=True)
class PlanAck(Message):
    robot: RobotId
    plan_id: Text
    ok: bool
    error: Text = ""
    # The protocol version (the document's rules) the robot keeps; absent: 1, a robot written before
    # there was a version to state. Ours state PROTOCOL_VERSION.
    protocol: Annotated[int, Range(1, MAX_PROTOCOL)] = 1


@dataclass(frozen=True)
class Tick(Message):
    """UAV -> all robots: execute step k (move to plan cell k); `ticks` is the makespan.

    `batch_states`: this UAV also reads StateBatch, so a pool may report all its robots' states
    of the tick in one message (absent, as from an older UAV: one RobotState per robot).
    """
    k: Annotated[int, Range(1, MAX_TICKS)]
    ticks: TickNo
    plan_id: Text
    batch_states: bool = False


@dataclass(frozen=True)
class MoveRequest(Message):
    robot: RobotId
    tick: TickNo
    frm: Cell
    to: Cell


@dataclass(frozen=True)
class MoveResult(Message):
    robot: RobotId
    tick: TickNo
    accepted: bool
    cell: Cell
    reason: Text = ""


@dataclass(frozen=True)
class MoveBatch(Message):
    """A pool hosting many robots -> world: all its moves of one tick in one query.

    moves: (robot, frm, to) each; answered by one MoveBatchResult.
    """
    tick: TickNo
    moves: Annotated[list[tuple[RobotId, Cell, Cell]], MaxLen(MAX_ROBOTS)]


@dataclass(frozen=True)
class MoveBatchResult(Message):
    """results: (robot, accepted, cell, reason) for every move of the MoveBatch."""
    tick: TickNo
    results: Annotated[list[tuple[RobotId, bool, Cell, Text]], MaxLen(MAX_ROBOTS)]


@dataclass(frozen=True)
class MoveAhead(Message):
    """Robot(s) -> world, put (not asked) on `world/ahead/<ids>` before the tick: the moves of tick `tick`.

    moves: (robot, frm, to) each. `plan_id` is the plan they follow: if `Tick(tick)` names
    another plan, each is judged as a stay. Of several for one robot and tick the last put wins.
    Answered, once the world has judged the tick, by one MovesJudged on `world/judged/<ids>`.
    """
    tick: Annotated[int, Range(1, MAX_TICKS)]
    plan_id: Text
    moves: Annotated[list[tuple[RobotId, Cell, Cell]], MaxLen(MAX_ROBOTS)]


@dataclass(frozen=True)
class MovesJudged(Message):
    """World -> the robots of `world/judged/<ids>`: the world's answer to their MoveAhead of one tick.

    results: (robot, accepted, cell, reason) for every move of theirs judged at `tick`; `plan_id`
    and `batch_states` are the Tick's, so that a robot moving ahead need not read the Tick itself.
    """
    tick: TickNo
    plan_id: Text
    results: Annotated[list[tuple[RobotId, bool, Cell, Text]], MaxLen(MAX_ROBOTS)]
    batch_states: bool = False


@dataclass(frozen=True)
class RobotState(Message):
    robot: RobotId
    tick: TickNo
    cell: Cell
    status: Status
    plan_id: Text = ""
    error: Text = ""


@dataclass(frozen=True)
class StateBatch(Message):
    """A pool -> UAV: the RobotStates of one tick of all its robots that executed it, in one put.

    states: (robot, cell, status, plan_id, error) each, as in RobotState; sent only in answer to a
    Tick with batch_states (a UAV that reads it), on the pool's own key."""
    tick: TickNo
    states: Annotated[list[tuple[RobotId, Cell, Status, Text, Text]], MaxLen(MAX_ROBOTS)]

    def robot_states(self) -> list[RobotState]:
        """Each entry as the RobotState it stands for."""
        return [RobotState(robot=r, tick=self.tick, cell=c, status=st, plan_id=p, error=e)
                for r, c, st, p, e in self.states]


@dataclass(frozen=True)
class Done(Message):
    robot: RobotId
    tick: TickNo
    cell: Cell


@dataclass(frozen=True)
class CameraRequest(Message):
    """Ask the world's camera for the image seen from the vehicle's current pose."""
    # Optional (v1-compatible): only the camera's calibration and the pose estimate, like a
    # camera's information message: the reply is a CameraFrame without image bytes. A world
    # that sends the image anyway is still understood.
    calibration_only: bool = False
    # Optional (v1-compatible): a region of interest in sensor pixels, read out alone as a
    # machine-vision camera's ROI does (0 wide: the whole image). The reply is that crop: its
    # width, height and principal point (cx, cy less the region's corner) say so; a world that
    # sends the whole image anyway is still understood.
    roi_x: Annotated[int, Range(0, MAX_IMAGE_SIDE)] = 0
    roi_y: Annotated[int, Range(0, MAX_IMAGE_SIDE)] = 0
    roi_width: Annotated[int, Range(0, MAX_IMAGE_SIDE)] = 0
    roi_height: Annotated[int, Range(0, MAX_IMAGE_SIDE)] = 0


@dataclass(frozen=True)
class CameraFrame(Message):
    width: Annotated[int, Range(1, MAX_IMAGE_SIDE)]
    height: Annotated[int, Range(1, MAX_IMAGE_SIDE)]
    fx: Positive
    fy: Positive
    cx: Finite
    cy: Finite
    north_m: Finite  # camera position in the local NED frame whose origin is the grid's top-left corner
    east_m: Finite
    down_m: Finite
    yaw_rad: Finite
    time_s: Finite
    png: Annotated[bytes, MaxLen(MAX_IMAGE_BYTES)]  # the image bytes, PNG or JPEG as `encoding` says
    # Optional (v1-compatible) calibration and estimate quality. The pose above is the
    # vehicle's own estimate at exposure, never ground truth; the sigmas are its stated
    # 1-sigma uncertainty, as an autopilot's EKF reports it.
    k1: Finite = 0.0   # Brown-Conrady distortion in OpenCV's order (k1, k2, p1, p2, k3)
    k2: Finite = 0.0
    p1: Finite = 0.0
    p2: Finite = 0.0
    k3: Finite = 0.0
    roll_rad: Finite = 0.0    # estimated attitude at exposure (camera fixed to the body, nadir)
    pitch_rad: Finite = 0.0
    pose_sigma_m: NonNegative = 0.0
    yaw_sigma_deg: NonNegative = 0.0
    encoding: ImageEncoding = "png"


@dataclass(frozen=True)
class WorldInfoRequest(Message):
    pass


@dataclass(frozen=True)
class WorldInfo(Message):
    """Site calibration, known to the UAV before it flies (not ground truth about robots)."""
    width: Annotated[int, Range(1, MAX_GRID_SIDE)]  # grid cells
    height: Annotated[int, Range(1, MAX_GRID_SIDE)]
    cell_size_m: Positive
    home_lat: Annotated[float, Range(-90.0, 90.0)]
    home_lon: Annotated[float, Range(-180.0, 180.0)]
    home_alt_m: Finite
    # Surveyed fiducials on the floor plane (optional): an OpenCV ArUco dictionary name such as
    # "DICT_APRILTAG_36h11" ("" = none), the side of each marker's black square, and each marker's
    # id and centre; a marker's top edge faces north.
    landmark_family: Text = ""
    landmark_size_m: NonNegative = 0.0
    landmarks: Annotated[list[Landmark], MaxLen(MAX_LANDMARKS)] = field(default_factory=list)


@dataclass(frozen=True)
class RecordRequest(Message):
    pass


@dataclass(frozen=True)
class Record(Message):
    """World -> anyone, for scoring after the mission: what physically happened."""
    json_cap_bytes: ClassVar[int] = MAX_RECORD_BYTES
    ticks: TickNo
    collisions: Count
    refused: Annotated[list[Object], MaxLen(MAX_REFUSED)]
    executed: Annotated[dict[RobotKey, Path], MaxLen(MAX_ROBOTS)]
    truth: Object


@dataclass(frozen=True)
class MissionStatus(Message):
    phase: Text
    tick: TickNo = 0
    ticks: TickNo = 0
    done: Robots = 0
    robots: Robots = 0
    message: Text = ""


@dataclass(frozen=True)
class MissionEnd(Message):
    completed: bool
    reason: Text = ""


@dataclass(frozen=True)
class MissionEvent(Message):
    """Something the UAV saw or did that a person must know (a fault, a replan, a verification)."""
    tick: TickNo
    time_s: NonNegative            # since the mission started
    kind: Text                     # robot-lost, robot-stalled, deviation, replan, done-contradicted, abort, ...
    robots: Annotated[list[RobotId], MaxLen(MAX_ROBOTS)]
    what: Text
    action: Text = ""


@dataclass(frozen=True)
class VehiclePose(Message):
    """UAV -> observers: the vehicle's own estimate, a few times a second from take-off until landed.

    Position in CameraFrame's local NED frame (origin at the grid's top-left corner). Nobody must
    listen; a view or a recorder shows the drone move between images with it.
    """
    time_s: NonNegative     # since the mission started
    north_m: Finite
    east_m: Finite
    down_m: Finite
    yaw_rad: Finite
    roll_rad: Finite = 0.0
    pitch_rad: Finite = 0.0
    armed: bool = False
    in_air: bool = False
    mode: Annotated[str, MaxLen(64)] = ""        # the autopilot's mode as MAVSDK names it (HOLD, LAND, ...)
    battery_pct: Annotated[float, Range(-1.0, 100.0)] = -1.0   # remaining charge; -1 = unknown


MESSAGE_TYPES: dict[str, type[Message]] = {
    cls.__name__: cls
    for cls in (Plan, PlanAck, Tick, MoveRequest, MoveResult, MoveBatch, MoveBatchResult, MoveAhead, MovesJudged, RobotState, StateBatch, Done, CameraRequest,
                CameraFrame, WorldInfoRequest, WorldInfo, RecordRequest, Record, MissionStatus, MissionEnd,
                MissionEvent, VehiclePose)
}

M = TypeVar("M", bound=Message)


class WireField(NamedTuple):
    name: str
    type: Any        # with its Annotated bounds
    required: bool


_FIELDS: dict[type, list[WireField]] = {}


def wire_fields(cls: type[Message]) -> list[WireField]:
    """A message type's fields in wire order (`seq` first), with their bounded types."""
    if cls not in _FIELDS:
        hints = typing.get_type_hints(cls, include_extras=True)
        _FIELDS[cls] = [WireField(f.name, hints[f.name],
                                  f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING)
                        for f in dataclasses.fields(cls)]
    return _FIELDS[cls]


def unwrap(tp: Any) -> tuple[Any, tuple[Any, ...]]:
    """Annotated[T, *bounds] -> (T, bounds); any other type -> (it, ())."""
    if get_origin(tp) is Annotated:
        return tp.__origin__, tp.__metadata__
    return tp, ()


def bound(meta: tuple[Any, ...], kind: type) -> Any:
    return next((m for m in meta if isinstance(m, kind)), None)


def _bytes_field(cls: type[Message]) -> str | None:
    return next((f.name for f in wire_fields(cls) if unwrap(f.type)[0] is bytes), None)


def encode(msg: Message) -> bytes:
    cls = type(msg)
    codec = _codec(cls)
    body: dict[str, Any] = {"type": cls.__name__, "v": SCHEMA_VERSION}
    for name, _required, _conv in codec.fields:
        body[name] = getattr(msg, name)
    head = _ENCODER.encode(body).encode()
    if codec.blob is None:
        return head
    return head + b"\0" + getattr(msg, codec.blob)


_ENCODER = json.JSONEncoder(separators=(",", ":"))


class _NotANumber(Exception):
    """NaN or Infinity in the text: Python's json reads them, JSON has no such tokens."""


def _refuse_constant(token: str) -> Any:
    raise _NotANumber(token)


_JSON = json.JSONDecoder(parse_constant=_refuse_constant)


def decode(data: bytes | bytearray | memoryview, expected: type[M], entries: int | None = None) -> M:
    """Bytes -> message of type `expected`, or ProtocolError naming what is wrong. `entries`: for a
    batch (one list of per-robot entries), how many robots the receiver asked about or its key names:
    the payload may then take only `batch_limit(expected, entries)` bytes."""
    name = expected.__name__
    codec = _codec(expected)
    limit = codec.max_payload if entries is None else min(codec.max_payload, batch_limit(expected, entries))
    if len(data) > limit:  # before copying or parsing anything
        raise ProtocolError(f"{name}: payload of {len(data)} bytes is over the limit of {limit}"
                            + ("" if entries is None else f" for {entries} robot(s)"))
    data = bytes(data)
    head, blob = data, b""
    if codec.blob is not None:
        head, sep, blob = data.partition(b"\0")
        if not sep:
            raise ProtocolError(f"{name}: payload lacks its binary part")
        if len(head) > codec.max_json:
            raise ProtocolError(f"{name}: JSON part of {len(head)} bytes is over the limit of {codec.max_json}")
        if len(blob) > codec.max_blob:
            raise ProtocolError(f"{name}: binary part of {len(blob)} bytes is over the limit of {codec.max_blob}")
    try:
        body = _JSON.decode(head.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise ProtocolError(f"{name}: payload is not JSON (not UTF-8 at byte {exc.start}: {data[:24]!r})") from None
    except ValueError as exc:  # malformed JSON, or an integer of more digits than Python converts
        why = exc.msg if isinstance(exc, json.JSONDecodeError) else "a number too long"
        raise ProtocolError(f"{name}: payload is not JSON ({why}; {len(data)} bytes: {data[:24]!r})") from None
    except _NotANumber as exc:
        raise ProtocolError(f"{name}: payload is not JSON ({exc.args[0]} is not a JSON number)") from None
    except RecursionError:  # the parser recurses per level: a nesting bomb ends here, not in the caller
        raise ProtocolError(f"{name}: payload nests deeper than {MAX_DEPTH} levels") from None
    if type(body) is not dict:
        raise ProtocolError(f"{name}: payload is not a JSON object")
    if body.get("type") != name:
        if "type" not in body:
            raise ProtocolError(f"expected a {name} message, got an object without a 'type'")
        raise ProtocolError(f"expected a {name} message, got type {str(body.get('type'))[:40]!r}")
    v = body.get("v")
    if type(v) is not int or v != SCHEMA_VERSION:
        raise ProtocolError(f"{name}: schema version {str(v)[:20]!r} is not supported "
                            f"(this side speaks {SCHEMA_VERSION})")
    kwargs: dict[str, Any] = {}
    for fname, required, conv in codec.fields:
        if fname in body:
            kwargs[fname] = conv(body[fname])
        elif required:
            raise ProtocolError(f"{name}: field {fname!r} is missing")
    if len(body) > len(kwargs) + 2:
        _check_unknown(name, body, codec.known)
    if codec.blob is not None:
        kwargs[codec.blob] = blob
    return expected(**kwargs)


def _check_unknown(name: str, body: dict[str, Any], known: frozenset[str]) -> None:
    """Unknown fields are ignored (a newer sender may add optional ones), but not their depth."""
    for key, value in body.items():
        if key not in known and type(value) in (list, dict) and _deeper_than(value, MAX_DEPTH - 1):
            raise ProtocolError(f"{name}: field {key[:40]!r} nests deeper than {MAX_DEPTH} levels")


class _Codec(NamedTuple):
    blob: str | None
    fields: list[tuple[str, bool, Callable[[Any], Any]]]
    known: frozenset[str]
    max_json: int      # the JSON text's limit, json_limit
    max_blob: int
    max_payload: int


_CODECS: dict[type, _Codec] = {}


def _codec(cls: type[Message]) -> _Codec:
    """Per message type, once: a compiled converter per field (decode is on the hot path of every tick)."""
    if cls not in _CODECS:
        blob = _bytes_field(cls)
        fields = [(f.name, f.required, _converter(f.type, f"{cls.__name__}.{f.name}", 1))
                  for f in wire_fields(cls) if f.name != blob]
        max_blob = sum(_need(bound(unwrap(f.type)[1], MaxLen), "binary tail", f.name).n
                       for f in wire_fields(cls) if f.name == blob)
        longest = _longest_json(cls)
        max_json = cls.json_cap_bytes if longest is None else min(
            cls.json_cap_bytes, -(-(longest + MARGIN_BYTES) // 1024) * 1024)   # whole KiB
        _CODECS[cls] = _Codec(blob, fields, frozenset({"type", "v"} | {f[0] for f in fields}), max_json, max_blob,
                              max_json + (0 if blob is None else 1 + max_blob))
    return _CODECS[cls]


def batch_limit(cls: type[Message], entries: int) -> int:
    """The most bytes a batch message (MoveBatch, MoveBatchResult, MoveAhead, MovesJudged, StateBatch)
    may take when it is for `entries` robots: its other fields at their longest, that many of its
    longest entry, and the margin for unknown fields; never more than `json_limit`. A batch's type
    allows 65,536 entries of free text, some 3 GB, capped at 8 MiB; a lone robot's answer needs 54 KiB."""
    total = len(_ENCODER.encode({"type": cls.__name__})) + len(',"v":') + _VERSION_CHARS
    for f in wire_fields(cls):
        base, meta = unwrap(f.type)
        if get_origin(base) is list:
            (item,) = get_args(base)
            n = max(0, min(entries, bound(meta, MaxLen).n))
            value = 2 + n * _longest_value(item) + max(0, n - 1)
        else:
            value = _longest_value(f.type)
        total += len(_ENCODER.encode(f.name)) + 2 + value
    return min(json_limit(cls), -(-(total + MARGIN_BYTES) // 1024) * 1024)


def json_limit(cls: type[Message]) -> int:
    """The most bytes a `cls` message's JSON text may take (a CameraFrame's before its NUL): checked by
    `decode` on the payload's length before it parses anything (docs/protocol.md, Limits)."""
    return _codec(cls).max_json


# The longest JSON text a value takes, as any JSON writer may write it without whitespace: a float
# in 24 characters (-2.2250738585072014e-308), a string character in 12 (a code point beyond the
# BMP escaped as a surrogate pair, \ud83d\ude00), a patterned string's in 1 (our patterns spell ASCII).
_FLOAT_CHARS = 24
_ESCAPED_CHAR = 12
_VERSION_CHARS = 6   # "v": a small integer


def _longest_json(cls: type[Message]) -> int | None:
    """The longest JSON text of a `cls` message's bounded fields (its binary tail aside); None if a
    field is free-form (Any), so only the type's cap bounds it."""
    blob = _bytes_field(cls)
    total = len(_ENCODER.encode({"type": cls.__name__})) + len(',"v":') + _VERSION_CHARS
    for f in wire_fields(cls):
        if f.name == blob:
            continue
        n = _longest_value(f.type)
        if n is None:
            return None
        total += len(_ENCODER.encode(f.name)) + 2 + n   # ,"name":value
    return total


def _longest_value(tp: Any) -> int | None:
    base, meta = unwrap(tp)
    origin = get_origin(base)
    if base is bool:
        return len("false")
    if base is int:
        r = bound(meta, Range)
        return max(len(str(r.lo)), len(str(r.hi)))
    if base is float:
        return _FLOAT_CHARS
    if base is str:
        return 2 + bound(meta, MaxLen).n * (1 if bound(meta, Pattern) is not None else _ESCAPED_CHAR)
    if origin is Literal:
        return max(len(json.dumps(a)) for a in get_args(base))
    if origin is tuple:
        parts = [_longest_value(a) for a in get_args(base)]
        return None if None in parts else 1 + sum(parts) + len(parts)   # [a,b,c]
    if origin is list or origin is dict:
        n = bound(meta, MaxLen).n
        parts = [_longest_value(a) for a in get_args(base)]
        if None in parts:
            return None
        item = sum(parts) + (len(parts) - 1)    # a value, or "key":value
        return 2 + n * item + max(0, n - 1)
    if origin in (typing.Union, types.UnionType):
        parts = [_longest_value(a) for a in get_args(base)]
        return None if None in parts else max(parts)
    return None   # Any: free-form


def _deeper_than(value: Any, limit: int) -> bool:
    """Whether `value` nests more than `limit` arrays and objects; level by level, so no recursion."""
    level = [value]
    for _ in range(limit):
        level = [y for x in level if type(x) in (list, dict) for y in (x.values() if type(x) is dict else x)]
        if not level:
            return False
    return any(type(x) in (list, dict) for x in level)


def _show(v: Any) -> str:
    """A received value in an error line: short whatever it is."""
    if type(v) is int:
        return str(v) if v.bit_length() <= 64 else f"a {v.bit_length()}-bit int"
    if type(v) is float:
        return repr(v)
    if type(v) is str:
        return repr(v) if len(v) <= 24 else f"str of {len(v)} characters"
    if type(v) is list and len(v) <= 4 and all(type(x) in (int, float, bool) or x is None for x in v):
        text = json.dumps(v)  # a cell, say: its values are the news
        if len(text) <= 48:
            return text
    if type(v) in (list, dict):
        return f"{type(v).__name__} of {len(v)}"
    return "null" if v is None else type(v).__name__


def _fail(where: str, expected: str, value: Any) -> ProtocolError:
    return ProtocolError(f"{where}: expected {expected}, got {_show(value)}")


def _need(meta: Any, what: str, where: str) -> Any:
    if meta is None:  # every field that sizes memory must say its bound: a schema author's mistake
        raise TypeError(f"{where}: unbounded {what} in a message schema")
    return meta


def _converter(tp: Any, where: str, outer: int) -> Callable[[Any], Any]:
    """A checking converter for a JSON value of type `tp` that sits inside `outer` arrays/objects."""
    base, meta = unwrap(tp)
    origin = get_origin(base)
    if base is Any:
        return _any_converter(where, MAX_DEPTH - outer)
    if base is bool:
        def conv(v: Any) -> Any:
            if v is True or v is False:
                return v
            raise _fail(where, "bool", v)
        return conv
    if base is int or base is float:
        return _number_converter(base, _need(bound(meta, Range), "number", where), where)
    if base is str:
        return _text_converter(_need(bound(meta, MaxLen), "string", where).n, bound(meta, Pattern), where)
    if origin is Literal:
        # Literal strings or integers; `type(v) in kinds` keeps true out of an integer enum.
        allowed = frozenset(get_args(base))
        kinds = {type(a) for a in allowed}
        expected = "one of " + ", ".join(sorted(map(str, allowed)))

        def conv(v: Any) -> Any:
            if type(v) in kinds and v in allowed:
                return v
            raise _fail(where, expected, v)
        return conv
    if origin is tuple:
        return _tuple_converter(get_args(base), where, outer)
    if origin is list:
        return _list_converter(get_args(base)[0], _need(bound(meta, MaxLen), "list", where).n, where, outer)
    if origin is dict:
        return _dict_converter(get_args(base), _need(bound(meta, MaxLen), "object", where).n, where, outer)
    if origin in (typing.Union, types.UnionType):
        options = [_converter(a, where, outer) for a in get_args(base)]

        def conv(v: Any) -> Any:
            for c in options:
                try:
                    return c(v)
                except ProtocolError:
                    pass
            raise _fail(where, " or ".join(str(a) for a in get_args(base)), v)
        return conv
    raise TypeError(f"unsupported schema type {tp} at {where}")  # a schema author's mistake, not bad input


def _any_converter(where: str, room: int) -> Callable[[Any], Any]:
    def conv(v: Any) -> Any:
        if type(v) in (list, dict) and _deeper_than(v, room):
            raise ProtocolError(f"{where}: nests deeper than {MAX_DEPTH} levels")
        return v
    return conv


def _number_converter(base: type, r: Range, where: str) -> Callable[[Any], Any]:
    lo, hi = r.lo, r.hi
    if base is int:
        expected = f"int in [{lo}, {hi}]"

        def conv(v: Any) -> Any:
            if type(v) is int and lo <= v <= hi:
                return v
            raise _fail(where, expected, v)
        return conv
    # JSON writes 2.0 as 2 in some languages: ints are numbers too. NaN fails every comparison.
    expected = ("finite float" if lo == -MAX_FLOAT and hi == MAX_FLOAT else
                f"finite float {'>' if r.open_lo else '>='} {lo:g}" if hi == MAX_FLOAT else
                f"float in {'(' if r.open_lo else '['}{lo:g}, {hi:g}]")
    if r.open_lo:
        def conv(v: Any) -> Any:
            if (type(v) is float or type(v) is int) and lo < v <= hi:
                return float(v)
            raise _fail(where, expected, v)
        return conv

    def conv(v: Any) -> Any:
        if (type(v) is float or type(v) is int) and lo <= v <= hi:
            return float(v)
        raise _fail(where, expected, v)
    return conv


def _unicode(text: str) -> bool:
    """JSON escapes can spell lone surrogates, which no UTF-8 writer (nor a log line) accepts."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def _text_converter(n: int, pattern: Pattern | None, where: str) -> Callable[[Any], Any]:
    match = re.compile(pattern.regex).fullmatch if pattern is not None else None

    def conv(v: Any) -> Any:
        if type(v) is not str or len(v) > n:
            _check_sized(v, str, n, where)   # raises, naming the problem
        if not (v.isascii() or _unicode(v)):
            raise ProtocolError(f"{where}: text holds a lone surrogate, not Unicode")
        if match is not None and match(v) is None:
            raise _fail(where, f"text matching {pattern.regex}", v)
        return v
    return conv


def _tuple_converter(args: tuple[Any, ...], where: str, outer: int) -> Callable[[Any], Any]:
    n = len(args)
    first, meta = unwrap(args[0])
    if n == 2 and first is int and args[0] == args[1]:  # cells: the most common shape by far, inlined
        r = _need(bound(meta, Range), "number", where)
        lo, hi, expected = r.lo, r.hi, f"[int, int] in [{r.lo}, {r.hi}]"

        def conv(v: Any) -> Any:
            if type(v) is list and len(v) == 2:
                x, y = v
                if type(x) is int and type(y) is int and lo <= x <= hi and lo <= y <= hi:
                    return (x, y)
            raise _fail(where, expected, v)
        return conv
    parts = [_converter(a, f"{where}[{i}]", outer + 1) for i, a in enumerate(args)]
    # The batches' entries (3 to 5 fields, thousands a tick at 1,000 robots) unpacked without a
    # generator: a third of a StateBatch's decoding.
    if n == 3:
        c0, c1, c2 = parts

        def conv3(v: Any) -> Any:
            if type(v) is list and len(v) == 3:
                a, b, c = v
                return c0(a), c1(b), c2(c)
            raise _fail(where, f"list of {n}", v)
        return conv3
    if n == 4:
        c0, c1, c2, c3 = parts

        def conv4(v: Any) -> Any:
            if type(v) is list and len(v) == 4:
                a, b, c, d = v
                return c0(a), c1(b), c2(c), c3(d)
            raise _fail(where, f"list of {n}", v)
        return conv4
    if n == 5:
        c0, c1, c2, c3, c4 = parts

        def conv5(v: Any) -> Any:
            if type(v) is list and len(v) == 5:
                a, b, c, d, e = v
                return c0(a), c1(b), c2(c), c3(d), c4(e)
            raise _fail(where, f"list of {n}", v)
        return conv5

    def conv(v: Any) -> Any:
        if type(v) is list and len(v) == n:
            return tuple(c(x) for c, x in zip(parts, v))
        raise _fail(where, f"list of {n}", v)
    return conv


def _list_converter(item_tp: Any, n: int, where: str, outer: int) -> Callable[[Any], Any]:
    item = _converter(item_tp, f"{where}[i]", outer + 1)

    def conv(v: Any) -> Any:
        _check_sized(v, list, n, where)
        try:
            return [item(x) for x in v]
        except ProtocolError as exc:
            raise _indexed(exc, item, enumerate(v), f"{where}[i]", "[{}]") from None
    return conv


def _dict_converter(args: tuple[Any, Any], n: int, where: str, outer: int) -> Callable[[Any], Any]:
    key = _converter(args[0], f"{where} key", outer + 1)
    value = _converter(args[1], f"{where}[k]", outer + 1)

    def conv(v: Any) -> Any:
        _check_sized(v, dict, n, where)
        try:
            return {key(k): value(x) for k, x in v.items()}
        except ProtocolError as exc:
            for k in v:
                key(k)
            raise _indexed(exc, value, v.items(), f"{where}[k]", "[{!r}]") from None
    return conv


_KINDS = {list: ("list", "items"), dict: ("object", "keys"), str: ("str", "characters")}


def _check_sized(v: Any, kind: type, n: int, where: str) -> None:
    if type(v) is not kind:
        raise _fail(where, _KINDS[kind][0], v)
    if len(v) > n:
        raise ProtocolError(f"{where}: {len(v)} {_KINDS[kind][1]}, more than the limit of {n}")


def _indexed(first: ProtocolError, conv: Callable[[Any], Any], items: Any, placeholder: str,
             fmt: str) -> ProtocolError:
    """The error naming the item that failed: found by converting again, as the fast path keeps no index."""
    for at, x in items:
        try:
            conv(x)
        except ProtocolError as exc:
            return ProtocolError(str(exc).replace(placeholder, placeholder[:-3] + fmt.format(at), 1))
    return first
