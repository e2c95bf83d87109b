"""Offboard control: the setpoint stream a companion computer sends, and when it counts as lost.

SET_POSITION_TARGET_LOCAL_NED and SET_POSITION_TARGET_GLOBAL_INT, as PX4's offboard mode takes
them: per axis group (horizontal, vertical) a position, else a velocity, else an acceleration
(flown as the velocity it integrates to); a yaw or a yaw rate. Frames: LOCAL_NED,
LOCAL_OFFSET_NED (positions from where the vehicle is), BODY_NED (velocities and accelerations
turned by the heading), BODY_OFFSET_NED (both), and the global frames with AMSL or relative
altitude. What this vehicle cannot fly (a force setpoint, half a horizontal axis pair, another
frame, non-finite numbers, a global setpoint without GPS) is refused and said as STATUSTEXT
("Offboard refused: <why>", once per reason until a setpoint is accepted again), never silently dropped; a refused
setpoint does not feed the stream, so offboard mode is not entered on, or is left for hold
after, setpoints it cannot fly.
"""
from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from protocol.geo import geo_to_ned

from .config import VehicleConfig
from .dynamics import Dynamics
from .journal import WARNING, Journal
from .link import Link
from .motion import Vec3

m = mavlink
OFFBOARD_LOSS_S = 1.0  # PX4's COM_OF_LOSS_T: no setpoint for this long -> hold
OFFBOARD_MIN_RATE_WINDOW_S = 1.0  # two setpoints within this window = a >= 2 Hz stream
LOCAL_FRAMES = (m.MAV_FRAME_LOCAL_NED, m.MAV_FRAME_LOCAL_OFFSET_NED, m.MAV_FRAME_BODY_NED, m.MAV_FRAME_BODY_OFFSET_NED)
GLOBAL_FRAMES = {m.MAV_FRAME_GLOBAL: False, m.MAV_FRAME_GLOBAL_INT: False,
                 m.MAV_FRAME_GLOBAL_RELATIVE_ALT: True, m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: True}  # -> relative
FRAME_NAMES = {v: k[len("MAV_FRAME_"):] for k, v in vars(m).items() if k.startswith("MAV_FRAME_") and isinstance(v, int)}
YAW_IGNORE, YAW_RATE_IGNORE = m.POSITION_TARGET_TYPEMASK_YAW_IGNORE, m.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
FORCE_SET = m.POSITION_TARGET_TYPEMASK_FORCE_SET

Axes = tuple  # three floats, None where the setpoint leaves the axis alone


@dataclass(frozen=True)
class Wish:
    """One accepted setpoint in local NED: per axis a position, velocity or acceleration (None: not given)."""

    pos: Axes
    vel: Axes
    acc: Axes
    yaw: float | None
    yaw_rate: float | None


def _group(values: tuple, ignore_bits: int, mask: int) -> Axes:
    """The three values the mask does not ignore (bit i of `ignore_bits` per axis), None for the others."""
    return tuple(None if mask & (ignore_bits << i) else v for i, v in enumerate(values))


def _rotate(values: Axes, yaw: float) -> Axes:
    """Body-frame (forward, right, down) values turned into NED by the heading."""
    if values[0] is None or values[1] is None:
        return values
    c, s = math.cos(yaw), math.sin(yaw)
    return c * values[0] - s * values[1], s * values[0] + c * values[1], values[2]


def _why_not(wish: Wish) -> str | None:
    """Why a setpoint cannot be flown, None if it can."""
    for name, axes in (("position", wish.pos), ("velocity", wish.vel), ("acceleration", wish.acc)):
        if (axes[0] is None) != (axes[1] is None):
            return f"{name}: x or y alone"
    values = [v for axes in (wish.pos, wish.vel, wish.acc) for v in axes if v is not None]
    values += [v for v in (wish.yaw, wish.yaw_rate) if v is not None]
    if not all(math.isfinite(v) for v in values):
        return "non-finite values"
    return None


class Offboard:
    """The latest accepted setpoint and when the last two arrived (wall time, since the ground
    station's own timeouts run on it). `command` turns it into what the autopilot flies."""

    def __init__(self, config: VehicleConfig, lock: threading.RLock, journal: Journal, link: Link,
                 dynamics: Dynamics):
        self._config = config
        self._lock = lock
        self._journal = journal
        self._link = link
        self._dynamics = dynamics
        self._times: deque[float] = deque(maxlen=2)
        self._wish: Wish | None = None
        self._vel_cmd: list[float | None] = [None, None, None]  # an acceleration setpoint's integrated velocity
        self._yaw: float | None = None
        self._refusals: set[str] = set()
        self.refused = 0

    # --- the messages --------------------------------------------------------------------

    def on_setpoint(self, msg) -> None:
        """SET_POSITION_TARGET_LOCAL_NED."""
        frame = msg.coordinate_frame
        if frame not in LOCAL_FRAMES:
            self._refuse(f"frame {FRAME_NAMES.get(frame, frame)}")
            return
        self._take(msg, frame, (msg.x, msg.y, msg.z))

    def on_global_setpoint(self, msg) -> None:
        """SET_POSITION_TARGET_GLOBAL_INT: positions as latitude, longitude (degrees * 1e7), altitude."""
        cfg = self._config
        frame = msg.coordinate_frame
        if frame not in GLOBAL_FRAMES:
            self._refuse(f"frame {FRAME_NAMES.get(frame, frame)}")
            return
        pos = (None, None, None)
        if not msg.type_mask & 0b111:
            if not cfg.gps:
                self._refuse("global position without GPS")
                return
            if not (abs(msg.lat_int) <= 90e7 and abs(msg.lon_int) <= 180e7):
                self._refuse("latitude/longitude out of range")
                return
            north, east = geo_to_ned(msg.lat_int / 1e7, msg.lon_int / 1e7, cfg.home_lat, cfg.home_lon)
            pos = (north, east, -(msg.alt if GLOBAL_FRAMES[frame] else msg.alt - cfg.home_alt_m))
        self._take(msg, m.MAV_FRAME_LOCAL_NED, pos)

    def _take(self, msg, frame: int, pos: tuple) -> None:
        mask = msg.type_mask
        if mask & FORCE_SET:
            self._refuse("force setpoint")
            return
        with self._lock:
            here = self._dynamics.position
            heading = self._dynamics.state().yaw
            wish = Wish(_group(pos, 0b1, mask), _group((msg.vx, msg.vy, msg.vz), 0b1000, mask),
                        _group((msg.afx, msg.afy, msg.afz), 0b1000000, mask),
                        None if mask & YAW_IGNORE else msg.yaw, None if mask & YAW_RATE_IGNORE else msg.yaw_rate)
            why = _why_not(wish)
            if why is not None:
                self._refuse(why)
                return
            body = frame in (m.MAV_FRAME_BODY_NED, m.MAV_FRAME_BODY_OFFSET_NED)
            offset = frame in (m.MAV_FRAME_LOCAL_OFFSET_NED, m.MAV_FRAME_BODY_OFFSET_NED)
            p = _rotate(wish.pos, heading) if frame == m.MAV_FRAME_BODY_OFFSET_NED else wish.pos
            if offset:
                p = tuple(None if v is None else v + h for v, h in zip(p, here))
            wish = Wish(p, _rotate(wish.vel, heading) if body else wish.vel,
                        _rotate(wish.acc, heading) if body else wish.acc, wish.yaw, wish.yaw_rate)
            self._times.append(time.monotonic())
            if self._wish is None or any((a is None) != (b is None) for a, b in zip(self._wish.acc, wish.acc)):
                self._vel_cmd = [None, None, None]
            self._wish = wish
            self._refusals.clear()

    def _refuse(self, why: str) -> None:
        with self._lock:
            self.refused += 1
            new = why not in self._refusals
            self._refusals.add(why)
        if new:
            self._journal.say(WARNING, f"Offboard refused: {why}")

    # --- the stream ----------------------------------------------------------------------

    def streaming(self, now: float) -> bool:
        """At least two setpoints within the last second, the newest within the loss timeout:
        PX4 only enters offboard mode on such a stream."""
        with self._lock:
            times = self._times
            return (len(times) == 2 and now - times[0] <= OFFBOARD_MIN_RATE_WINDOW_S
                    and now - times[1] <= OFFBOARD_LOSS_S)

    def lost(self, now: float) -> bool:
        with self._lock:
            return now - (self._times[-1] if self._times else -math.inf) > OFFBOARD_LOSS_S

    def yaw(self, current: float, dt: float) -> float | None:
        """The heading to fly this step: the setpoint's yaw, or the current target turned by its yaw rate."""
        with self._lock:
            wish = self._wish
            if wish is None:
                return None
            if wish.yaw is not None:
                return wish.yaw
            if wish.yaw_rate is not None:
                return current + wish.yaw_rate * dt
            return None

    def command(self, hold: Vec3, vel: Vec3, dt: float, speed_xy: float, up: float,
                down: float) -> tuple[Vec3, tuple | None] | None:
        """(target, velocity) for this step: per axis the setpoint's position (the target; `hold`
        where it names none), or its velocity, or the velocity its acceleration has integrated to
        since it began (within the speed limits). None without a setpoint."""
        with self._lock:
            wish = self._wish
            if wish is None:
                return None
            target = tuple(p if p is not None else h for p, h in zip(wish.pos, hold))
            velocity: list[float | None] = [None, None, None]
            for i in range(3):
                if wish.pos[i] is not None:
                    continue
                if wish.vel[i] is not None:
                    velocity[i] = wish.vel[i]
                elif wish.acc[i] is not None:
                    start = self._vel_cmd[i] if self._vel_cmd[i] is not None else vel[i]
                    self._vel_cmd[i] = start + wish.acc[i] * dt
                    velocity[i] = self._vel_cmd[i]
            # the integrated velocity stays within the limits, so that braking starts at once
            vn, ve = velocity[0], velocity[1]
            if vn is not None and ve is not None and math.hypot(vn, ve) > speed_xy > 0:
                k = speed_xy / math.hypot(vn, ve)
                velocity[0], velocity[1] = vn * k, ve * k
            if velocity[2] is not None:
                velocity[2] = max(-up, min(down, velocity[2]))
            for i in range(3):
                if self._vel_cmd[i] is not None:
                    self._vel_cmd[i] = velocity[i]
            if all(v is None for v in velocity):
                return target, None
            return target, tuple(velocity)
