"""MAVLink's mission microservice, as PX4's mavlink_mission.cpp serves it: upload (MISSION_COUNT ->
MISSION_REQUEST_INT ... -> MISSION_ACK, the vehicle re-requesting a missing item every
RETRY_S and giving up after PROTOCOL_TIMEOUT_S), download (MISSION_REQUEST_LIST ->
MISSION_COUNT -> MISSION_ITEM_INT per request), MISSION_CLEAR_ALL and MISSION_SET_CURRENT.
Only the flight plan (MAV_MISSION_TYPE_MISSION) is kept; fences and rally points are refused."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink

from .journal import CRITICAL, INFO, WARNING, Journal
from .link import Channel, Link
from .mission import MAX_ITEMS, Item, Mission, check_item

m = mavlink
RETRY_S = 0.25  # PX4's MAVLINK_MISSION_RETRY_TIMEOUT_DEFAULT
PROTOCOL_TIMEOUT_S = 5.0  # PX4's MAVLINK_MISSION_PROTOCOL_TIMEOUT_DEFAULT
RESULT_NAMES = {v: k for k, v in vars(m).items() if k.startswith("MAV_MISSION_") and isinstance(v, int)
                and k not in ("MAV_MISSION_TYPE_MISSION", "MAV_MISSION_TYPE_FENCE", "MAV_MISSION_TYPE_RALLY",
                              "MAV_MISSION_TYPE_ALL")}
COMMAND_NAMES = {v: k[len("MAV_CMD_"):] for k, v in vars(m).items() if k.startswith("MAV_CMD_") and isinstance(v, int)}
FRAME_NAMES = {v: k[len("MAV_FRAME_"):] for k, v in vars(m).items() if k.startswith("MAV_FRAME_") and isinstance(v, int)}


@dataclass
class _Upload:
    """An upload in progress: who sends it, on which channel, and what has arrived."""

    channel: Channel | None
    system: int
    component: int
    count: int
    items: list[Item] = field(default_factory=list)
    last_request: float = 0.0
    last_progress: float = 0.0


class MissionService:
    """Serves the mission protocol over the link for `mission`. `tick(now)` (wall time) drives the
    upload's retries and timeout."""

    def __init__(self, lock: threading.RLock, journal: Journal, link: Link, mission: Mission):
        self._lock = lock
        self._journal = journal
        self._link = link
        self._mission = mission
        self._upload: _Upload | None = None
        self.handlers = {
            "MISSION_COUNT": self.on_count,
            "MISSION_ITEM_INT": self.on_item,
            "MISSION_ITEM": self.on_item,
            "MISSION_REQUEST_LIST": self.on_request_list,
            "MISSION_REQUEST_INT": self.on_request,
            "MISSION_REQUEST": self.on_request,
            "MISSION_CLEAR_ALL": self.on_clear_all,
            "MISSION_SET_CURRENT": self.on_set_current,
        }

    # --- upload --------------------------------------------------------------------------

    def on_count(self, msg) -> None:
        if not self._plan_type(msg):
            return
        if msg.count > MAX_ITEMS:
            self._ack(msg, m.MAV_MISSION_NO_SPACE, f"Mission rejected: {msg.count} items, at most {MAX_ITEMS}")
            return
        with self._lock:
            busy = self._upload
            if busy is not None and (busy.system, busy.component) != (msg.get_srcSystem(), msg.get_srcComponent()):
                self._ack(msg, m.MAV_MISSION_DENIED, "Mission upload refused: another transfer is in progress")
                return
            if msg.count == 0:
                self._upload = None
                self._mission.replace([])
                self._ack(msg, m.MAV_MISSION_ACCEPTED)
                return
            now = time.monotonic()
            self._upload = _Upload(self._link.current, msg.get_srcSystem(), msg.get_srcComponent(), msg.count,
                                   last_progress=now)
            self._request_next(now)

    def on_item(self, msg) -> None:
        with self._lock:
            up = self._upload
            if up is None or (msg.get_srcSystem(), msg.get_srcComponent()) != (up.system, up.component):
                return  # not ours (PX4 ignores it too)
            if getattr(msg, "mission_type", 0) != m.MAV_MISSION_TYPE_MISSION:
                return
            expected = len(up.items)
            if msg.seq < expected:
                return  # a duplicate of an item already stored: our re-request crossed it
            if msg.seq > expected:
                self._abort(m.MAV_MISSION_INVALID_SEQUENCE, f"Mission rejected: item {msg.seq}, expected {expected}")
                return
            item = Item.of(msg)
            result = check_item(item)
            if result != m.MAV_MISSION_ACCEPTED:
                self._abort(result, f"Mission rejected: item {item.seq} "
                                    f"{COMMAND_NAMES.get(item.command, item.command)} ({item.command}) frame "
                                    f"{FRAME_NAMES.get(item.frame, item.frame)}: {RESULT_NAMES.get(result, result)}")
                return
            up.items.append(item)
            now = time.monotonic()
            up.last_progress = now
            if len(up.items) < up.count:
                self._request_next(now)
                return
            self._upload = None
            self._mission.replace(up.items)
            self._send_ack(up, m.MAV_MISSION_ACCEPTED)
            self._journal.say(INFO, f"Mission uploaded: {up.count} items")

    def tick(self, now: float) -> None:
        """Re-request a missing item, or give the upload up once the ground station went quiet."""
        with self._lock:
            up = self._upload
            if up is None:
                return
            if now - up.last_progress > PROTOCOL_TIMEOUT_S:
                self._abort(m.MAV_MISSION_OPERATION_CANCELLED,
                            f"Mission upload timed out at item {len(up.items)} of {up.count}", severity=WARNING)
            elif now - up.last_request >= RETRY_S:
                self._request_next(now)

    def _request_next(self, now: float) -> None:
        up = self._upload
        up.last_request = now
        self._link.send(self._link.encoder.mission_request_int_encode(up.system, up.component, len(up.items),
                                                                      m.MAV_MISSION_TYPE_MISSION), up.channel)

    def _abort(self, result: int, why: str, severity: int = CRITICAL) -> None:
        up, self._upload = self._upload, None
        self._send_ack(up, result)
        self._journal.say(severity, why)

    def _send_ack(self, up: _Upload, result: int) -> None:
        self._link.send(self._link.encoder.mission_ack_encode(up.system, up.component, result,
                                                              m.MAV_MISSION_TYPE_MISSION), up.channel)

    # --- download, clear, current ---------------------------------------------------------

    def on_request_list(self, msg) -> None:
        if not self._plan_type(msg):
            return
        count = len(self._mission.items)
        self._link.reply(self._link.encoder.mission_count_encode(msg.get_srcSystem(), msg.get_srcComponent(), count,
                                                                 m.MAV_MISSION_TYPE_MISSION))

    def on_request(self, msg) -> None:
        if not self._plan_type(msg):
            return
        items = self._mission.items
        if not 0 <= msg.seq < len(items):
            self._ack(msg, m.MAV_MISSION_INVALID_SEQUENCE, f"Mission item {msg.seq} requested, have {len(items)}")
            return
        i = items[msg.seq]
        enc = self._link.encoder
        to = (msg.get_srcSystem(), msg.get_srcComponent())
        current = int(msg.seq == self._mission.current)
        if msg.get_type() == "MISSION_REQUEST":  # the legacy request gets the legacy item (degrees as floats)
            frame = {m.MAV_FRAME_GLOBAL_INT: m.MAV_FRAME_GLOBAL,
                     m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: m.MAV_FRAME_GLOBAL_RELATIVE_ALT}.get(i.frame, i.frame)
            reply = enc.mission_item_encode(*to, i.seq, frame, i.command, current, i.autocontinue, i.param1,
                                            i.param2, i.param3, i.param4, i.x / 1e7, i.y / 1e7, i.z,
                                            m.MAV_MISSION_TYPE_MISSION)
        else:
            reply = enc.mission_item_int_encode(*to, i.seq, i.frame, i.command, current, i.autocontinue, i.param1,
                                                i.param2, i.param3, i.param4, i.x, i.y, i.z,
                                                m.MAV_MISSION_TYPE_MISSION)
        self._link.reply(reply)

    def on_clear_all(self, msg) -> None:
        if getattr(msg, "mission_type", 0) not in (m.MAV_MISSION_TYPE_MISSION, m.MAV_MISSION_TYPE_ALL):
            self._plan_type(msg)
            return
        self._mission.replace([])
        self._ack(msg, m.MAV_MISSION_ACCEPTED)
        self._journal.say(INFO, "Mission cleared")

    def on_set_current(self, msg) -> None:
        if not self._mission.set_current(msg.seq):
            self._journal.say(CRITICAL, f"Mission item {msg.seq} does not exist: current item unchanged")

    def _plan_type(self, msg) -> bool:
        """Whether `msg` is about the flight plan; a fence or rally transfer is refused."""
        kind = getattr(msg, "mission_type", 0)
        if kind == m.MAV_MISSION_TYPE_MISSION:
            return True
        self._ack(msg, m.MAV_MISSION_UNSUPPORTED, f"Mission type {kind} (fence, rally) is not supported", kind)
        return False

    def _ack(self, msg, result: int, why: str | None = None, kind: int = m.MAV_MISSION_TYPE_MISSION) -> None:
        self._link.reply(self._link.encoder.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), result,
                                                               kind))
        if why:
            self._journal.say(CRITICAL if result != m.MAV_MISSION_ACCEPTED else INFO, why)
