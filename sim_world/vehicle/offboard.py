"""Offboard control: the setpoint stream a companion computer sends, and when it counts as lost."""
from __future__ import annotations

import math
import threading
import time
from collections import deque

from pymavlink.dialects.v20 import common as mavlink

from .dynamics import Dynamics, Vec3
from .journal import Journal
from .link import Link

OFFBOARD_LOSS_S = 1.0  # PX4's COM_OF_LOSS_T: no setpoint for this long -> hold
OFFBOARD_MIN_RATE_WINDOW_S = 1.0  # two setpoints within this window = a >= 2 Hz stream


class Offboard:
    """The latest SET_POSITION_TARGET_LOCAL_NED and when the last two arrived (wall time,
    since the ground station's own timeouts run on it)."""

    def __init__(self, lock: threading.RLock, journal: Journal, link: Link, dynamics: Dynamics):
        self._lock = lock
        self._journal = journal
        self._link = link
        self._dynamics = dynamics
        self._times: deque[float] = deque(maxlen=2)
        self._pos: Vec3 | None = None
        self._vel: Vec3 | None = None
        self._yaw: float | None = None

    def on_setpoint(self, msg) -> None:
        mask = msg.type_mask
        frame = msg.coordinate_frame
        if frame not in (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_NED):
            self._journal.warn(f"offboard setpoint in unsupported frame {frame} ignored")
            return
        pos = None if mask & 0b111 else (msg.x, msg.y, msg.z)
        vel = None if mask & 0b111000 else (msg.vx, msg.vy, msg.vz)
        yaw = None if mask & mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE else msg.yaw
        values = [v for v in (*(pos or ()), *(vel or ()), yaw if yaw is not None else 0.0)]
        if not all(math.isfinite(v) for v in values):
            self._link.bad("offboard setpoint with non-finite values ignored")
            return
        with self._lock:
            if frame == mavlink.MAV_FRAME_BODY_NED and vel is not None:
                heading = self._dynamics.state().yaw
                c, s = math.cos(heading), math.sin(heading)
                vel = (c * vel[0] - s * vel[1], s * vel[0] + c * vel[1], vel[2])
            if frame == mavlink.MAV_FRAME_BODY_NED and pos is not None:
                pos = None  # body-frame positions are offsets PX4 does not take either
            self._times.append(time.monotonic())
            self._pos, self._vel, self._yaw = pos, vel, yaw

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

    @property
    def yaw(self) -> float | None:
        with self._lock:
            return self._yaw

    def target(self, pos: Vec3, dt: float, speed_xy: float, speed_up: float, speed_down: float) -> Vec3 | None:
        """Where the setpoint puts the vehicle after `dt` s from `pos`, None if it names no
        place (a yaw alone). A velocity setpoint becomes the point it reaches, within limits."""
        with self._lock:
            if self._pos is not None:
                return self._pos
            if self._vel is None:
                return None
            vn, ve, vd = self._vel
        scale = min(1.0, speed_xy / math.hypot(vn, ve)) if math.hypot(vn, ve) > 0 else 1.0
        vd = max(-speed_up, min(speed_down, vd))
        n, e, d = pos
        return (n + vn * scale * dt, e + ve * scale * dt, d + vd * dt)
