"""Typed, versioned messages: the wire contract between UAV, world and robots.

Every message is a frozen dataclass. On the wire it is one UTF-8 JSON object
`{"type": ..., "v": SCHEMA_VERSION, "seq": ..., <fields>}`; a message with a
`bytes` field (a camera image) carries those bytes after a NUL byte that JSON
itself never contains. `decode` checks the size, the type name, the version and
every field's type and bounds, and raises `ProtocolError` with one line naming
the problem, so a garbage or forged payload on a key is refused, never
half-applied, and never costs a receiver more than the limits of protocol/bounds.py.

This module is the catalogue: which messages exist and their fields. The bounds
live in the field annotations (`Range`, `MaxLen`, `Pattern` inside `Annotated`:
protocol/bounds.py); the codec (`encode`, `decode`, the size limits:
protocol/codec.py) and the JSON Schemas (`protocol.schemas`) are derived from them.
"""
from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar, Literal, NamedTuple

from .bounds import (MAX_GRID_SIDE, MAX_MOVERS, MAX_IMAGE_BYTES, MAX_IMAGE_SIDE, MAX_LANDMARKS, MAX_MESSAGE_BYTES, MAX_RECORD_BYTES,
                     MAX_REFUSED, MAX_ROBOT_ID, MAX_ROBOTS, MAX_TICKS, Cell, Count, Finite, MaxLen, NonNegative, Object,
                     Path, Positive, Range, RobotId, RobotKey, Robots, Text, TickNo, unwrap)

# `v` of every message: the version of the message format. No field was removed or retyped since 1,
# so a reader of 1 decodes every message of today (docs/protocol.md, Versioning).
SCHEMA_VERSION = 1
# The version of the rules of docs/protocol.md a robot keeps, which it states in PlanAck.protocol
# (absent: 1). 2 is today's document; its changelog says what changed from 1.
PROTOCOL_VERSION = 2
MAX_PROTOCOL = 1_000

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


MoverKind = Literal["person", "forklift", "pallet"]


@dataclass(frozen=True)
class FloorMovers(Message):
    """World -> observers, after each tick: the uncooperative movers on the floor (id, kind, cell).
    Ground truth for views and recorders; no one must listen, and the UAV must not."""
    tick: TickNo
    movers: Annotated[list[tuple[Annotated[int, Range(0, MAX_MOVERS - 1)], MoverKind, Cell]], MaxLen(MAX_MOVERS)]


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
                CameraFrame, WorldInfoRequest, WorldInfo, RecordRequest, Record, FloorMovers, MissionStatus, MissionEnd,
                MissionEvent, VehiclePose)
}


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


def bytes_field(cls: type[Message]) -> str | None:
    return next((f.name for f in wire_fields(cls) if unwrap(f.type)[0] is bytes), None)

