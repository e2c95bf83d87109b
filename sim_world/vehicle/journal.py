"""What the vehicle has to say: notable events for whoever runs it, warnings for its operator."""
from __future__ import annotations

import sys
import threading
import time
from typing import Callable


class Journal:
    """Events stamped with simulated time, and warnings to stderr at most once per second
    (a flood of garbage must not become a flood of lines; the rest are counted)."""

    def __init__(self, lock: threading.RLock, sim_time: Callable[[], float]):
        self._lock = lock
        self._sim_time = sim_time
        self._events: list[tuple[float, str]] = []
        self._last_warn = 0.0
        self._suppressed_warnings = 0

    @property
    def events(self) -> list[tuple[float, str]]:
        with self._lock:
            return list(self._events)

    def event(self, text: str) -> None:
        with self._lock:
            self._events.append((round(self._sim_time(), 3), text))

    def warn(self, text: str) -> None:
        now = time.monotonic()
        with self._lock:
            if now - self._last_warn < 1.0:
                self._suppressed_warnings += 1
                return
            suppressed, self._suppressed_warnings = self._suppressed_warnings, 0
            self._last_warn = now
        more = f" ({suppressed} more suppressed)" if suppressed else ""
        print(f"vehicle: {text}{more}", file=sys.stderr, flush=True)
