"""The vehicle's pose for observers: a thread reads the autopilot's telemetry about 5 times a second
and publishes a `VehiclePose` from take-off until landed, so a view or a recording sees the drone move
between camera images.

It never holds the mission back: a telemetry read or a put that fails drops that one pose (with a
throttled warning), and the mission does not wait for the thread except for a short join at close.
"""
from __future__ import annotations

import threading
import time
from typing import Any, Callable

from protocol.log import Throttled
from protocol.messages import VehiclePose

PERIOD_S = 0.2


def read_pose(flight: Any, time_s: float, seq: int = 0) -> VehiclePose:
    """One `VehiclePose` from the flight's telemetry (its NED frame is the floor's: origin at the grid's corner)."""
    north, east, down = flight.position_ned()
    roll, pitch, yaw = flight.attitude_rad()
    return VehiclePose(time_s=max(0.0, time_s), north_m=north, east_m=east, down_m=down, yaw_rad=yaw,
                       roll_rad=roll, pitch_rad=pitch, armed=flight.armed, in_air=flight.in_air,
                       mode=flight.flight_mode[:64], battery_pct=flight.battery_pct, seq=seq)


class PoseFeed:
    """Publish the vehicle's pose every `period_s` while `flying(True)` holds."""

    def __init__(self, flight: Any, publish: Callable[[VehiclePose], None], t0: float | None = None,
                 period_s: float = PERIOD_S) -> None:
        self.flight = flight
        self.publish = publish
        self.period_s = period_s
        self.sent = 0
        self._t0 = time.monotonic() if t0 is None else t0   # time.monotonic() at the mission's start
        self._warn = Throttled("uav pose feed", interval_s=5.0)
        self._flying = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="pose-feed", daemon=True)
        self._thread.start()

    def flying(self, on: bool) -> None:
        (self._flying.set if on else self._flying.clear)()

    def _loop(self) -> None:
        # The first pose goes out as soon as the flag is set: observers see the vehicle on the ground
        # before it climbs.
        while not self._stop.is_set():
            if not self._flying.wait(0.1):
                continue
            try:
                self.publish(read_pose(self.flight, round(time.monotonic() - self._t0, 3), self.sent + 1))
                self.sent += 1
            except Exception as exc:  # noqa: BLE001 - a lost pose is only a gap in the view
                self._warn(f"pose not published: {exc}")
            self._stop.wait(self.period_s)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
