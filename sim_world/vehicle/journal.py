"""What the vehicle has to say: notable events for whoever runs it, warnings for its operator,
and STATUSTEXT for the ground stations."""
from __future__ import annotations

import threading
from typing import Callable

from protocol.log import Throttled

# MAV_SEVERITY values, named as PX4's mavlink_log_* calls use them
EMERGENCY, ALERT, CRITICAL, ERROR, WARNING, NOTICE, INFO = 0, 1, 2, 3, 4, 5, 6


class Journal:
    """Events stamped with simulated time; warnings through the one throttle every process uses
    (a flood of garbage must not become a flood of lines); `say` also tells the ground
    stations, once a `speaker` (the link's STATUSTEXT sender) is attached."""

    def __init__(self, lock: threading.RLock, sim_time: Callable[[], float]):
        self._lock = lock
        self._sim_time = sim_time
        self._events: list[tuple[float, str]] = []
        self._said: list[tuple[int, str]] = []
        self.warn = Throttled("vehicle")
        self.speaker: Callable[[int, str], None] | None = None

    @property
    def events(self) -> list[tuple[float, str]]:
        with self._lock:
            return list(self._events)

    @property
    def said(self) -> list[tuple[int, str]]:
        """(severity, text) of every STATUSTEXT, oldest first."""
        with self._lock:
            return list(self._said)

    def event(self, text: str) -> None:
        with self._lock:
            self._events.append((round(self._sim_time(), 3), text))

    def say(self, severity: int, text: str) -> None:
        """An event that the ground stations also see, as STATUSTEXT with `severity`."""
        with self._lock:
            self.event(text)
            self._said.append((severity, text))
            speaker = self.speaker
        if speaker is not None:
            speaker(severity, text)
