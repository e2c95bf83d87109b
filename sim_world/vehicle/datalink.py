"""The datalink-loss detector: when a ground station or offboard controller last sent a heartbeat.

Like PX4's commander, the link counts as lost only once it had been there: a vehicle no
ground station ever talked to has no link to lose. Wall time, since the ground station's
heartbeats run on it.
"""
from __future__ import annotations

import math
import threading
import time

from pymavlink.dialects.v20 import common as mavlink


class Datalink:
    def __init__(self, lock: threading.RLock):
        self._lock = lock
        self._last = -math.inf

    def on_heartbeat(self, msg) -> None:
        """A heartbeat from another system; autopilots (another vehicle, a camera) do not count."""
        if msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
            with self._lock:
                self._last = time.monotonic()

    def heard(self) -> bool:
        """Whether a controller's heartbeat ever came."""
        with self._lock:
            return self._last != -math.inf

    def silent_for(self, now: float) -> float:
        """Seconds since the controller's last heartbeat; 0 if there never was one."""
        with self._lock:
            return 0.0 if self._last == -math.inf else now - self._last
