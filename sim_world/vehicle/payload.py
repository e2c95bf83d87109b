"""The payload a mission commands: camera triggers and the gimbal, as PX4's mission does them.

The world's camera is shot on request over Zenoh (or as a MAVLink camera of its own) and is
fixed to the body, so nothing here moves or exposes it. What a mission's camera items ask for is
kept as PX4's camera_trigger driver does it: each trigger is counted, recorded (simulated time,
position) and announced as CAMERA_TRIGGER; distance and interval triggering run while the vehicle
flies. Gimbal items set the attitude a gimbal would take, recorded for whoever reads it.
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from .motion import Vec3
from .journal import Journal

m = mavlink


@dataclass(frozen=True)
class Trigger:
    """One camera trigger: its sequence number, simulated time and local NED position."""

    seq: int
    time_s: float
    pos: Vec3


class Payload:
    """Camera triggering (single, by distance, by interval) and the gimbal's commanded attitude.
    `on_item` takes a mission item's command and parameters, `fly` the vehicle's progress."""

    def __init__(self, lock: threading.RLock, journal: Journal, announce: Callable[[Trigger], None]):
        self._lock = lock
        self._journal = journal
        self._announce = announce
        self.triggers: list[Trigger] = []
        self._distance_m = 0.0      # trigger every this many metres flown (0: off)
        self._interval_s = 0.0      # trigger every this many seconds (0: off)
        self._left = 0              # images still due from an interval capture (0: unlimited)
        self._last_pos: Vec3 | None = None
        self._flown = 0.0
        self._last_time = 0.0
        self.gimbal_deg: tuple[float, float] = (0.0, 0.0)  # (pitch, yaw) last commanded
        self.recording = False

    def on_item(self, command: int, p: tuple, pos: Vec3, now: float) -> None:
        """Act on a camera or gimbal item (params p[0..6]) reached at `pos`, simulated time `now`."""
        with self._lock:
            if command == m.MAV_CMD_IMAGE_START_CAPTURE:
                interval, count = _finite(p[1]), int(_finite(p[2]))
                if interval > 0:
                    self._interval_s, self._left, self._last_time = interval, count, now
                    self._journal.event(f"camera: capture every {interval:g} s"
                                        + (f", {count} images" if count else ""))
                for _ in range(1 if interval > 0 else max(1, count)):
                    self._trigger(pos, now)
                    if self._left:
                        self._left -= 1
                        if not self._left:
                            self._interval_s = 0.0
            elif command == m.MAV_CMD_IMAGE_STOP_CAPTURE:
                self._interval_s, self._left = 0.0, 0
            elif command == m.MAV_CMD_DO_SET_CAM_TRIGG_INTERVAL:
                cycle_ms = _finite(p[0])
                self._interval_s, self._left, self._last_time = (cycle_ms / 1000 if cycle_ms > 0 else 0.0), 0, now
            elif command == m.MAV_CMD_DO_SET_CAM_TRIGG_DIST:
                self._distance_m, self._flown, self._last_pos = max(0.0, _finite(p[0])), 0.0, pos
                self._journal.event(f"camera: trigger every {self._distance_m:g} m" if self._distance_m
                                    else "camera: distance triggering off")
                if _finite(p[2]) == 1:   # "trigger once immediately"
                    self._trigger(pos, now)
            elif command == m.MAV_CMD_DO_DIGICAM_CONTROL:
                if _finite(p[4]) == 1:   # shoot
                    self._trigger(pos, now)
            elif command == m.MAV_CMD_VIDEO_START_CAPTURE:
                self.recording = True
            elif command == m.MAV_CMD_VIDEO_STOP_CAPTURE:
                self.recording = False
            elif command == m.MAV_CMD_DO_MOUNT_CONTROL:
                self._point(_finite(p[0]), _finite(p[2]))
            elif command == m.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW:
                self._point(p[0] if math.isfinite(p[0]) else self.gimbal_deg[0],
                            p[1] if math.isfinite(p[1]) else self.gimbal_deg[1])

    def fly(self, pos: Vec3, now: float) -> None:
        """The vehicle is at `pos` at simulated time `now`: trigger what distance or time has made due."""
        with self._lock:
            if self._distance_m > 0:
                if self._last_pos is not None:
                    self._flown += math.dist(pos, self._last_pos)
                self._last_pos = pos
                if self._flown >= self._distance_m:
                    self._flown -= self._distance_m * math.floor(self._flown / self._distance_m)
                    self._trigger(pos, now)
            if self._interval_s > 0 and now - self._last_time >= self._interval_s:
                self._last_time = now
                self._trigger(pos, now)
                if self._left:
                    self._left -= 1
                    if not self._left:
                        self._interval_s = 0.0

    def _point(self, pitch: float, yaw: float) -> None:
        self.gimbal_deg = (pitch, yaw)
        self._journal.event(f"gimbal: pitch {pitch:g} deg, yaw {yaw:g} deg")

    def _trigger(self, pos: Vec3, now: float) -> None:
        trigger = Trigger(len(self.triggers), round(now, 3), tuple(round(v, 3) for v in pos))
        self.triggers.append(trigger)
        self._announce(trigger)


def _finite(value: float) -> float:
    return value if math.isfinite(value) else 0.0
