"""AUTO.MISSION: the uploaded items and how the vehicle flies them, one handler per MAV_CMD.

Each handler looks at the current item and where the vehicle is and answers with a `Leg`:
where to fly now, how, and whether the item is done. `Mission.steer` advances through the
items, announcing MISSION_ITEM_REACHED and MISSION_CURRENT through its callbacks; the
autopilot applies the leg. Items are kept as MISSION_ITEM_INT fields so that a download
returns exactly what was uploaded.

Besides the flight items (`HANDLERS`), the DO items QGroundControl's survey and MAVSDK's
Mission plugin put between them (`ACTIONS`: speed, camera, gimbal) are done as they are
reached, by the autopilot's `act`; any other command is refused at upload.
"""
from __future__ import annotations

import enum
import math
import threading
from dataclasses import dataclass
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from protocol.geo import geo_to_ned

from .motion import Vec3
from .params import Params

m = mavlink
GLOBAL_FRAMES = {m.MAV_FRAME_GLOBAL: False, m.MAV_FRAME_GLOBAL_INT: False,
                 m.MAV_FRAME_GLOBAL_RELATIVE_ALT: True, m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: True}  # frame -> relative
MAX_ITEMS = 1000


@dataclass(frozen=True)
class Item:
    """One mission item, as MISSION_ITEM_INT carries it (x, y: degrees * 1e7)."""

    seq: int
    frame: int
    command: int
    current: int
    autocontinue: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float

    @classmethod
    def of(cls, msg) -> "Item":
        """From MISSION_ITEM_INT, or legacy MISSION_ITEM (degrees as floats)."""
        if msg.get_type() == "MISSION_ITEM":
            x, y = round(msg.x * 1e7), round(msg.y * 1e7)
            frame = {m.MAV_FRAME_GLOBAL: m.MAV_FRAME_GLOBAL_INT,
                     m.MAV_FRAME_GLOBAL_RELATIVE_ALT: m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT}.get(msg.frame, msg.frame)
        else:
            x, y, frame = msg.x, msg.y, msg.frame
        return cls(msg.seq, frame, msg.command, msg.current, msg.autocontinue, msg.param1, msg.param2, msg.param3,
                   msg.param4, x, y, msg.z)


class Leg(enum.Enum):
    """How a leg is flown."""

    HOLD = "hold"  # stay on the current target
    FLY = "fly"  # to the target at cruise speed
    CLIMB = "climb"  # straight up or down to the target's altitude
    LAND = "land"  # descend where the vehicle is
    RETURN = "return"  # hand over to RTL


@dataclass(frozen=True)
class Step:
    """What the current item asks for now: how to fly, where, and whether it is done."""

    leg: Leg
    target: Vec3 | None
    done: bool = False


@dataclass
class Context:
    """What an item handler may look at."""

    pos: Vec3
    airborne: bool
    sim_time: float
    params: Params
    home: tuple[float, float, float]  # lat, lon, alt AMSL
    arrived_at: float | None  # simulated time the vehicle first got within reach of this item


def item_position(item: Item, ctx: Context) -> Vec3:
    """The item's point in local NED; lat/lon 0,0 means "where the vehicle is" (as in PX4)."""
    lat, lon, alt_amsl = ctx.home
    here_n, here_e, _ = ctx.pos
    if item.x == 0 and item.y == 0:
        north, east = here_n, here_e
    else:
        north, east = geo_to_ned(item.x / 1e7, item.y / 1e7, lat, lon)
    alt = item.z if GLOBAL_FRAMES[item.frame] else item.z - alt_amsl
    return north, east, -alt


def _within(ctx: Context, target: Vec3, radius: float) -> bool:
    n, e, d = ctx.pos
    return (math.hypot(target[0] - n, target[1] - e) <= radius
            and abs(target[2] - d) <= ctx.params.get("NAV_MC_ALT_RAD"))


def _takeoff(item: Item, ctx: Context) -> Step:
    _, _, down = item_position(item, ctx)
    alt = max(-down, ctx.params.get("MIS_TAKEOFF_ALT"))  # PX4 raises a low takeoff to the minimum
    target = (ctx.pos[0], ctx.pos[1], -alt)
    return Step(Leg.CLIMB, target, done=_within(ctx, target, math.inf))


def _waypoint(item: Item, ctx: Context) -> Step:
    """Fly there; done within the acceptance radius (param2, else NAV_ACC_RAD) after the hold
    time (param1 s)."""
    target = item_position(item, ctx)
    radius = item.param2 if math.isfinite(item.param2) and item.param2 > 0 else ctx.params.get("NAV_ACC_RAD")
    return Step(Leg.FLY, target, done=_held(ctx, _within(ctx, target, radius), item.param1))


def _loiter_time(item: Item, ctx: Context) -> Step:
    target = item_position(item, ctx)
    return Step(Leg.FLY, target, done=_held(ctx, _within(ctx, target, ctx.params.get("NAV_ACC_RAD")), item.param1))


def _held(ctx: Context, there: bool, seconds: float) -> bool:
    if not there:
        return False
    if ctx.arrived_at is None:
        ctx.arrived_at = ctx.sim_time
    hold = seconds if math.isfinite(seconds) and seconds > 0 else 0.0
    return ctx.sim_time - ctx.arrived_at >= hold


def _land(item: Item, ctx: Context) -> Step:
    """Fly over the landing point at the current altitude, then land; done on the ground."""
    north, east, _ = item_position(item, ctx)
    n, e, d = ctx.pos
    if math.hypot(north - n, east - e) > ctx.params.get("NAV_ACC_RAD") and ctx.arrived_at is None:
        return Step(Leg.FLY, (north, east, d))
    ctx.arrived_at = ctx.sim_time if ctx.arrived_at is None else ctx.arrived_at
    return Step(Leg.LAND, (north, east, 0.0), done=not ctx.airborne)


def _return(item: Item, ctx: Context) -> Step:
    return Step(Leg.RETURN, None, done=True)


def _delay(item: Item, ctx: Context) -> Step:
    """NAV_DELAY: hold where the last item left the vehicle for param1 seconds."""
    return Step(Leg.HOLD, None, done=_held(ctx, True, item.param1))


def _loiter_unlimited(item: Item, ctx: Context) -> Step:
    return Step(Leg.FLY, item_position(item, ctx))


# MAV_CMD -> how the item is flown.
HANDLERS: dict[int, Callable[[Item, Context], Step]] = {
    m.MAV_CMD_NAV_TAKEOFF: _takeoff,
    m.MAV_CMD_NAV_WAYPOINT: _waypoint,
    m.MAV_CMD_NAV_LOITER_TIME: _loiter_time,
    m.MAV_CMD_NAV_LOITER_UNLIM: _loiter_unlimited,
    m.MAV_CMD_NAV_LAND: _land,
    m.MAV_CMD_NAV_RETURN_TO_LAUNCH: _return,
    m.MAV_CMD_NAV_DELAY: _delay,
}
# Flight items that name no place: their frame and coordinates are not looked at.
PLACELESS = {m.MAV_CMD_NAV_RETURN_TO_LAUNCH, m.MAV_CMD_NAV_DELAY}
# DO items done as they are reached (by the autopilot's `act`), whatever their frame: the speed
# and the camera and gimbal actions of QGroundControl's survey and MAVSDK's mission items.
ACTIONS = {
    m.MAV_CMD_DO_CHANGE_SPEED,
    m.MAV_CMD_IMAGE_START_CAPTURE, m.MAV_CMD_IMAGE_STOP_CAPTURE, m.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
    m.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL, m.MAV_CMD_DO_DIGICAM_CONTROL, m.MAV_CMD_DO_DIGICAM_CONFIGURE,
    m.MAV_CMD_SET_CAMERA_MODE, m.MAV_CMD_VIDEO_START_CAPTURE, m.MAV_CMD_VIDEO_STOP_CAPTURE,
    m.MAV_CMD_DO_MOUNT_CONTROL, m.MAV_CMD_DO_MOUNT_CONFIGURE, m.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
    m.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
}


def check_item(item: Item) -> int:
    """MAV_MISSION_ACCEPTED, or the MAV_MISSION_RESULT that refuses the item (any other command: MAV_MISSION_UNSUPPORTED)."""
    if item.command in ACTIONS:
        return m.MAV_MISSION_ACCEPTED
    if item.command not in HANDLERS:
        return m.MAV_MISSION_UNSUPPORTED
    if item.command == m.MAV_CMD_NAV_DELAY and not (math.isfinite(item.param1) and item.param1 >= 0):
        return m.MAV_MISSION_INVALID_PARAM1  # a delay until a time of day: not flown here
    if item.command in PLACELESS:
        return m.MAV_MISSION_ACCEPTED
    if item.frame not in GLOBAL_FRAMES:
        return m.MAV_MISSION_UNSUPPORTED_FRAME
    if not math.isfinite(item.z):
        return m.MAV_MISSION_INVALID_PARAM7
    if not (abs(item.x) <= 90e7 and abs(item.y) <= 180e7):
        return m.MAV_MISSION_INVALID_PARAM5_X
    return m.MAV_MISSION_ACCEPTED


class Mission:
    """The stored mission and the progress through it. `on_reached(seq)` and `on_current(seq)`
    are called (under the lock) when an item is done and when the current item changes."""

    def __init__(self, lock: threading.RLock, params: Params, home: tuple[float, float, float],
                 on_reached: Callable[[int], None], on_current: Callable[[int], None]):
        self._lock = lock
        self._params = params
        self._home = home
        self._on_reached = on_reached
        self._on_current = on_current
        self._items: list[Item] = []
        self._current = 0
        self._arrived_at: float | None = None
        self.finished = False

    @property
    def items(self) -> list[Item]:
        with self._lock:
            return list(self._items)

    @property
    def current(self) -> int:
        with self._lock:
            return self._current

    def replace(self, items: list[Item]) -> None:
        with self._lock:
            self._items = list(items)
            self._restart(0)

    def set_current(self, seq: int) -> bool:
        with self._lock:
            if not 0 <= seq < len(self._items):
                return False
            self._restart(seq)
            return True

    def _restart(self, seq: int) -> None:
        self._current, self._arrived_at, self.finished = seq, None, False
        self._on_current(seq)

    def points(self, here: Vec3) -> list[Vec3]:
        """The local NED points of the items that name one (for the geofence's check)."""
        ctx = self._context(here, True, 0.0)
        return [item_position(i, ctx) for i in self.items if i.command in HANDLERS and i.command not in PLACELESS]

    def _context(self, pos: Vec3, airborne: bool, sim_time: float) -> Context:
        return Context(pos, airborne, sim_time, self._params, self._home, self._arrived_at)

    def steer(self, pos: Vec3, airborne: bool, sim_time: float, act: Callable[[Item], None]) -> Step | None:
        """The current item's step, after moving past every item already done (`act` doing each
        DO item); None once the mission is over (the autopilot holds)."""
        with self._lock:
            while not self.finished and self._current < len(self._items):
                item = self._items[self._current]
                if item.command in ACTIONS:
                    act(item)
                    self._advance(item)
                    continue
                if not airborne and item.command not in (m.MAV_CMD_NAV_TAKEOFF, m.MAV_CMD_NAV_LAND):
                    # on the ground with a mission that does not start with a takeoff: climb first, as PX4 does
                    return Step(Leg.CLIMB, (pos[0], pos[1], -self._params.get("MIS_TAKEOFF_ALT")))
                ctx = self._context(pos, airborne, sim_time)
                step = HANDLERS[item.command](item, ctx)
                self._arrived_at = ctx.arrived_at
                if not step.done:
                    return step
                self._advance(item)
                if step.leg is Leg.LAND:
                    # a mission ends on the ground after its landing: DO items after it are done, the rest is not flown
                    while self._current < len(self._items) and self._items[self._current].command in ACTIONS:
                        act(self._items[self._current])
                        self._advance(self._items[self._current])
                    self.finished = True
                    return None
                if step.leg is Leg.RETURN:
                    self.finished = self._current >= len(self._items)
                    return step
            self.finished = True
            return None

    def _advance(self, item: Item) -> None:
        """`item` is done: say so, and make the next one current (if there is one)."""
        self._on_reached(item.seq)
        self._current += 1
        self._arrived_at = None
        if self._current < len(self._items):
            self._on_current(self._current)
