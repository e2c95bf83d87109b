"""What the vehicle has to say: notable events for whoever runs it, warnings for its operator."""
from __future__ import annotations

import threading
from typing import Callable

from protocol.log import Throttled


class Journal:
    """Events stamped with simulated time; warnings through the one throttle every process uses
    (a flood of garbage must not become a flood of lines)."""

    def __init__(self, lock: threading.RLock, sim_time: Callable[[], float]):
        self._lock = lock
        self._sim_time = sim_time
        self._events: list[tuple[float, str]] = []
        self.warn = Throttled("vehicle")

    @property
    def events(self) -> list[tuple[float, str]]:
        with self._lock:
            return list(self._events)

    def event(self, text: str) -> None:
        with self._lock:
            self._events.append((round(self._sim_time(), 3), text))
