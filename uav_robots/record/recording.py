"""mission.mcap: a mission in the MCAP format, JSON-encoded channels with JSON schemas, so Foxglove opens it.

Written from what an observer received on the wire (plans, ticks, robot states, done flags, mission
status, end and events, the UAV's camera images and pose feed, the world's movers after each tick on a
floor with people, forklifts or pallets: `/world/movers`) plus the world's floor (details.json's `truth` rows,
the map the robots moved on). Camera images use
Foxglove's `foxglove.CompressedImage`, the vehicle's pose `foxglove.PoseInFrame` (from its VehiclePose feed,
about 5 Hz; from each image's pose when a UAV sends no feed), the floor `foxglove.Grid`;
fleet messages keep the protocol's own schemas (protocol/schemas/).

Frame `floor`: x east and y north in metres from the grid's top-left corner, z up; cell (x, y) is centred
at (x + 0.5, -(y + 0.5)) * cell size.
"""
from __future__ import annotations

import base64
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from protocol import messages
from protocol.codec import decode, encode
from protocol.messages import CameraFrame, StateBatch, VehiclePose
from protocol.schemas import SCHEMA_DIR

from .observer import Sample

MCAP = "mission.mcap"

# The protocol topic each key's tail goes to, and the message type it carries.
_TOPICS = {"tick": ("/fleet/tick", "Tick"), "plan": ("/fleet/plan", "Plan"), "ack": ("/fleet/ack", "PlanAck"),
           "state": ("/fleet/state", "RobotState"), "done": ("/fleet/done", "Done"),
           "mission/status": ("/mission/status", "MissionStatus"), "mission/end": ("/mission/end", "MissionEnd"),
           "mission/event": ("/mission/event", "MissionEvent"), "world/movers": ("/world/movers", "FloorMovers")}

_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_VEC3 = {"type": "object", "properties": {a: {"type": "number"} for a in "xyz"}}
_QUAT = {"type": "object", "properties": {a: {"type": "number"} for a in "xyzw"}}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}
# Foxglove recognises these by name; the schemas state the fields this file uses.
FOXGLOVE_SCHEMAS: dict[str, dict[str, Any]] = {
    "foxglove.CompressedImage": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"},
        "data": {"type": "string", "contentEncoding": "base64"}, "format": {"type": "string"}}},
    "foxglove.PoseInFrame": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE}},
    "foxglove.Grid": {"type": "object", "properties": {
        "timestamp": _TIME, "frame_id": {"type": "string"}, "pose": _POSE, "column_count": {"type": "integer"},
        "cell_size": {"type": "object", "properties": {"x": {"type": "number"}, "y": {"type": "number"}}},
        "row_stride": {"type": "integer"}, "cell_stride": {"type": "integer"},
        "fields": {"type": "array", "items": {"type": "object", "properties": {
            "name": {"type": "string"}, "offset": {"type": "integer"}, "type": {"type": "integer"}}}},
        "data": {"type": "string", "contentEncoding": "base64"}}},
}
UINT8 = 1   # foxglove.NumericType


def _stamp(ns: int) -> dict[str, int]:
    return {"sec": ns // 10**9, "nsec": ns % 10**9}


def _topic(prefix: str, key: str) -> tuple[str, str] | None:
    tail = key[len(prefix) + 1:] if key.startswith(prefix + "/") else ""
    if tail.startswith("robot/"):
        tail = tail.rsplit("/", 1)[-1]
    return _TOPICS.get(tail)


# What replay.render draws, with /map.
DRAWN_TOPICS = frozenset({"/fleet/state", "/fleet/plan", "/fleet/tick", "/world/movers"})


def drawn(prefix: str, key: str) -> bool:
    """Whether a sample on `key` is recorded as a message replay.render draws."""
    if key.startswith(prefix + "/robots/") and key.endswith("/states"):
        return True
    topic = _topic(prefix, key)
    return topic is not None and topic[0] in DRAWN_TOPICS


def _free(rows: list[str]) -> np.ndarray:
    return np.array([[c != "@" for c in r] for r in rows], bool)


def _grid(rows: list[str], cell_m: float, ns: int) -> dict[str, Any]:
    free = _free(rows).astype(np.uint8)
    h, w = free.shape
    return {"timestamp": _stamp(ns), "frame_id": "floor",
            "pose": {"position": {"x": 0.0, "y": -h * cell_m, "z": 0.0},
                     "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}},
            "column_count": w, "cell_size": {"x": cell_m, "y": cell_m}, "row_stride": w, "cell_stride": 1,
            "fields": [{"name": "free", "offset": 0, "type": UINT8}],
            # Grid rows grow along +y (north); the map's rows grow southwards.
            "data": base64.b64encode(free[::-1].tobytes()).decode()}


def _pose(north_m: float, east_m: float, down_m: float, yaw_rad: float, ns: int) -> dict[str, Any]:
    yaw = math.pi / 2 - yaw_rad   # NED yaw (clockwise from north) -> a rotation about z-up, from east
    return {"timestamp": _stamp(ns), "frame_id": "floor",
            "pose": {"position": {"x": east_m, "y": north_m, "z": -down_m},
                     "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}}}


def _camera(frame: CameraFrame, ns: int) -> tuple[dict[str, Any], dict[str, Any]]:
    image = {"timestamp": _stamp(ns), "frame_id": "camera", "format": frame.encoding,
             "data": base64.b64encode(frame.png).decode()}
    return image, _pose(frame.north_m, frame.east_m, frame.down_m, frame.yaw_rad, ns)


def write_mcap(path: Path, samples: Iterable[Sample], fleet_prefix: str, rows: list[str] | None,
               cell_m: float) -> dict[str, int]:
    """Write the recording; returns the message count per topic."""
    from mcap.writer import Writer

    samples = sorted(samples, key=lambda s: s.time_ns)
    t0 = samples[0].time_ns if samples else 0
    counts: dict[str, int] = {}
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="uav-robots")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}

        def channel(topic: str, schema: str) -> int:
            if schema not in schemas:
                body = FOXGLOVE_SCHEMAS.get(schema)
                data = (json.dumps(body) if body is not None
                        else (SCHEMA_DIR / f"{schema}.schema.json").read_text()).encode()
                schemas[schema] = w.register_schema(name=schema, encoding="jsonschema", data=data)
            if topic not in channels:
                channels[topic] = w.register_channel(topic=topic, message_encoding="json",
                                                     schema_id=schemas[schema])
            return channels[topic]

        def put(topic: str, schema: str, ns: int, body: bytes | dict[str, Any]) -> None:
            data = body if isinstance(body, bytes) else json.dumps(body, separators=(",", ":")).encode()
            seq = counts.get(topic, 0)
            w.add_message(channel(topic, schema), log_time=ns, publish_time=ns, data=data, sequence=seq)
            counts[topic] = seq + 1

        if rows:
            put("/map", "foxglove.Grid", t0, _grid(rows, cell_m, t0))
        # The vehicle's own pose feed when it has one; an older UAV's images say where it was.
        fed = any(s.key.endswith("/uav/pose") for s in samples)
        for s in samples:
            if s.key.endswith("/uav/pose"):
                try:
                    p = decode(s.payload, VehiclePose)
                except Exception:  # noqa: BLE001 - a recorder keeps what it can read
                    continue
                put("/uav/pose", "foxglove.PoseInFrame", s.time_ns, _pose(p.north_m, p.east_m, p.down_m, p.yaw_rad,
                                                                           s.time_ns))
                continue
            if s.key.endswith("/uav/frame"):
                try:
                    frame = decode(s.payload, CameraFrame)
                except Exception:  # noqa: BLE001 - a recorder keeps what it can read
                    continue
                image, pose = _camera(frame, s.time_ns)
                put("/uav/camera", "foxglove.CompressedImage", s.time_ns, image)
                if not fed:
                    put("/uav/pose", "foxglove.PoseInFrame", s.time_ns, pose)
                continue
            if s.key.startswith(fleet_prefix + "/robots/") and s.key.endswith("/states"):
                try:
                    batch = decode(s.payload, StateBatch)
                except Exception:  # noqa: BLE001 - a recorder keeps what it can read
                    continue
                # A pool's batch is recorded as the RobotStates it stands for: a replay reads one kind.
                for st in batch.robot_states():
                    put("/fleet/state", "RobotState", s.time_ns, encode(st))
                continue
            topic = _topic(fleet_prefix, s.key)
            if topic is not None:
                try:
                    decode(s.payload, getattr(messages, topic[1]))
                except Exception:  # noqa: BLE001 - garbage or forged bytes on a fleet key: a recorder keeps what it can read
                    continue
                put(topic[0], topic[1], s.time_ns, s.payload)
        w.finish()
    return counts


@dataclass
class Recording:
    """What a replay needs, read back from mission.mcap."""
    free: np.ndarray                                          # bool [rows, cols], True on the floor
    cells: dict[int, dict[int, tuple[int, int]]] = field(default_factory=dict)   # robot -> tick -> cell
    goals: dict[int, tuple[int, int]] = field(default_factory=dict)
    paths: dict[int, list[tuple[int, int]]] = field(default_factory=dict)        # the latest plan's path
    starts: dict[int, tuple[int, int]] = field(default_factory=dict)             # the first plan's start
    ticks: int = 0
    events: list[dict[str, Any]] = field(default_factory=list)
    phases: list[tuple[int, str]] = field(default_factory=list)                   # (log time ns, phase)
    images: list[tuple[int, bytes]] = field(default_factory=list)                 # (log time ns, JPEG)
    poses: list[tuple[int, dict[str, float]]] = field(default_factory=list)       # (log time ns, UAV position)
    tick_times: list[tuple[int, int]] = field(default_factory=list)              # (log time ns, k)
    horizon: int = 0                                          # the last tick of any recorded plan
    end: dict[str, Any] | None = None
    counts: dict[str, int] = field(default_factory=dict)
    # tick -> the floor's movers after it, {id: (kind, cell)}: as heard (the world's FloorMovers, a tick
    # now and then merged into the next), or every tick from the world's record (`take_trace`)
    movers: dict[int, dict[int, tuple[str, tuple[int, int]]]] = field(default_factory=dict)
    contacts: list[int] = field(default_factory=list)        # the ticks of robot-mover contacts, when known


def read_mcap(path: Path) -> Recording:
    from mcap.reader import make_reader

    free = None
    rec = Recording(np.zeros((0, 0), bool))
    with open(path, "rb") as f:
        # mcap's own log-time order keeps a heap of Python objects (2 s of a 1,000-robot mission's
        # 180,000 messages); a stable sort of the file's order gives the same order (ties keep
        # their place in the file, as mcap breaks them) in a fraction of it.
        messages = list(make_reader(f).iter_messages(log_time_order=False))
        messages.sort(key=lambda m: m[2].log_time)
        for schema, channel, message in messages:
            topic = channel.topic
            rec.counts[topic] = rec.counts.get(topic, 0) + 1
            if topic == "/uav/camera":
                rec.images.append((message.log_time, base64.b64decode(json.loads(message.data)["data"])))
                continue
            try:
                body = json.loads(message.data.split(b"\0", 1)[0])
            except ValueError:   # a recording written by another tool: what cannot be read is skipped
                continue
            if topic == "/uav/pose":
                p = body["pose"]["position"]
                rec.poses.append((message.log_time, {"east_m": p["x"], "north_m": p["y"], "alt_m": p["z"]}))
            elif topic == "/mission/end":
                rec.end = {"completed": body["completed"], "reason": body.get("reason", "")}
            elif topic == "/map":
                grid = np.frombuffer(base64.b64decode(body["data"]), np.uint8)
                free = grid.reshape(-1, body["column_count"])[::-1].astype(bool)
            elif topic in DRAWN_TOPICS:
                _take(rec, topic, body, message.log_time)
            elif topic == "/mission/status":
                rec.phases.append((message.log_time, body["phase"]))
            elif topic == "/mission/event":
                rec.events.append(body)
    if free is None:
        raise ValueError(f"{path}: no /map channel: not a uav-robots recording")
    rec.free = free
    return rec


def _take(rec: Recording, topic: str, body: dict[str, Any], log_time: int) -> None:
    """A drawn message (`DRAWN_TOPICS`) into `rec`."""
    if topic == "/fleet/state":
        rec.cells.setdefault(body["robot"], {})[body["tick"]] = tuple(body["cell"])
        rec.ticks = max(rec.ticks, body["tick"])
    elif topic == "/world/movers":
        # Not in `ticks`: the robots' states and the Ticks say how long the mission was.
        rec.movers[body["tick"]] = {mid: (kind, tuple(cell)) for mid, kind, cell in body["movers"]}
    elif topic == "/fleet/plan":
        rec.goals[body["robot"]] = tuple(body["goal"])
        rec.paths[body["robot"]] = [tuple(c) for c in body["path"]]
        rec.starts.setdefault(body["robot"], tuple(body["path"][0]))
        rec.horizon = max(rec.horizon, body.get("start_tick", 0) + len(body["path"]) - 1)
    else:   # /fleet/tick
        rec.ticks = max(rec.ticks, body["k"])
        rec.tick_times.append((log_time, body["k"]))


def drawn_recording(samples: Iterable[Sample], fleet_prefix: str, rows: list[str]) -> Recording:
    """What `read_mcap` gives `replay.render` from `write_mcap` of `samples` on the map `rows`, without
    writing and reading a file: the drawn messages only, the same skipped (those that do not decode)."""
    rec = Recording(_free(rows))
    for s in sorted(samples, key=lambda s: s.time_ns):
        if s.key.startswith(fleet_prefix + "/robots/") and s.key.endswith("/states"):
            try:
                batch = decode(s.payload, StateBatch)
            except Exception:  # noqa: BLE001 - as write_mcap: what does not decode is not recorded
                continue
            for st in batch.robot_states():
                _take(rec, "/fleet/state", {"robot": st.robot, "tick": st.tick, "cell": st.cell}, s.time_ns)
            continue
        topic = _topic(fleet_prefix, s.key)
        if topic is None or topic[0] not in DRAWN_TOPICS:
            continue
        try:
            decode(s.payload, getattr(messages, topic[1]))
            body = json.loads(s.payload.split(b"\0", 1)[0])
        except Exception:  # noqa: BLE001 - as write_mcap and read_mcap
            continue
        _take(rec, topic[0], body, s.time_ns)
    return rec


def last_tick(report: dict[str, Any] | None, rec: Recording) -> int:
    """The last tick a replay draws: the mission's, as the UAV and the world recorded it (the report's
    `ticks`, each robot's executed path, the first plan's makespan); without a report of the UAV's, the
    last tick of the recorded plans. Never what a Tick or a state claims: one forged Tick(k=100000)
    would otherwise cost a 100,001-frame video."""
    known: list[int] = []
    if report:
        if isinstance(report.get("ticks"), int):
            known.append(report["ticks"])
        known += [len(cells) - 1 for cells in (report.get("executed") or {}).values() if cells]
        known += [len(r["path"]) - 1 for r in (report.get("plan") or {}).get("robots", []) if r.get("path")]
    return max(known) if known else rec.horizon


def bound(rec: Recording, last: int) -> int:
    """Drops from `rec` every state and tick claiming a tick after `last`; returns how many."""
    dropped = 0
    for rid in list(rec.cells):
        by_tick = rec.cells[rid]
        late = [t for t in by_tick if t > last]
        for t in late:
            del by_tick[t]
        dropped += len(late)
        if not by_tick:
            del rec.cells[rid]
    late = [t for t in rec.movers if t > last]
    for t in late:
        del rec.movers[t]
    dropped += len(late)
    kept = [(ns, k) for ns, k in rec.tick_times if k <= last]
    dropped += len(rec.tick_times) - len(kept)
    rec.tick_times = kept
    rec.ticks = max([k for _, k in kept] + [t for by_tick in rec.cells.values() for t in by_tick] + [0])
    return dropped


def movers_per_tick(rec: Recording) -> list[dict[int, tuple[str, tuple[int, int]]]]:
    """The floor's movers at ticks 0..rec.ticks: a tick none was heard for keeps the last heard (the world
    merged it into the next: nobody moved as far as a viewer knows); none before the first."""
    out, last = [], {}
    for t in range(rec.ticks + 1):
        last = rec.movers.get(t, last)
        out.append(last)
    return out


_PLURAL = {"person": "people", "forklift": "forklifts", "pallet": "pallets"}


def mover_kinds(kinds: Iterable[str]) -> str:
    """How many of each kind, in words: "2 people, 1 forklift"."""
    counts: dict[str, int] = {}
    for kind in kinds:
        counts[kind] = counts.get(kind, 0) + 1
    return ", ".join(f"{n} {kind if n == 1 else _PLURAL.get(kind, kind)}" for kind, n in sorted(counts.items()))


def take_trace(rec: Recording, report: dict[str, Any] | None) -> bool:
    """The movers of every tick from the world's record (report.json's `truth.movers`: each mover's cell
    after every tick, the robot-mover contacts) in place of those heard; True if a replay then draws them
    otherwise than from the recording alone (a tick the world's publisher merged into the next). A record
    without a trace, or one that does not read, leaves `rec` as heard."""
    truth = ((report or {}).get("truth") or {}).get("movers") or {}
    try:
        traced = _traced(truth)
        contacts = sorted(int(c["tick"]) for c in truth.get("contacts", []))
    except (AttributeError, KeyError, TypeError, ValueError):
        return False
    if not traced:
        return False
    heard = movers_per_tick(rec)
    rec.movers, rec.contacts = traced, contacts
    return movers_per_tick(rec) != heard or bool(contacts)


def _traced(truth: dict[str, Any]) -> dict[int, dict[int, tuple[str, tuple[int, int]]]]:
    """tick -> {id: (kind, cell)} from the world's trace (index t: the cell after tick t)."""
    kinds = {str(m["id"]): (str(m["kind"]), int(m.get("appears", 0))) for m in truth.get("movers", [])}
    traced: dict[int, dict[int, tuple[str, tuple[int, int]]]] = {}
    for mid, cells in (truth.get("trace") or {}).items():
        kind, appears = kinds.get(mid, ("", 0))
        for t, (x, y) in enumerate(cells):
            if t >= appears:      # a pallet dropped mid-mission is not on the floor before
                traced.setdefault(t, {})[int(mid)] = (kind, (int(x), int(y)))
    return traced


def dropped_line(dropped: int, last: int) -> str:
    return (f"uav-robots: {dropped} message(s) claiming a tick after the mission's last ({last}: the report's "
            f"ticks, the executed paths, the plans) left out of the video")
