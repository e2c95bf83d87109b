"""What happened during a mission that a person must know: faults, what the UAV saw, what it did."""
from __future__ import annotations

import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(frozen=True)
class Event:
    tick: int                  # the fleet's tick when it happened (0 before execution)
    time_s: float              # seconds since the mission started
    kind: str                  # robot-lost, robot-stalled, robot-error, deviation, done-contradicted, replan, ...
    robots: tuple[int, ...]
    what: str                  # what was seen
    action: str = ""           # what the UAV did about it
    unix: float = 0.0          # wall clock, to compare with outside observations


@dataclass
class EventLog:
    events: list[Event] = field(default_factory=list)
    t0: float = field(default_factory=time.monotonic)   # time.monotonic() at the mission's start: events count from it
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def add(self, tick: int, kind: str, robots: list[int] | tuple[int, ...], what: str, action: str = "") -> Event:
        e = Event(tick, round(time.monotonic() - self.t0, 3), kind, tuple(sorted(robots)), what, action,
                  round(time.time(), 3))
        with self._lock:
            self.events.append(e)
        return e

    def of(self, kind: str) -> list[Event]:
        with self._lock:
            return [e for e in self.events if e.kind == kind]

    def as_dicts(self) -> list[dict[str, Any]]:
        with self._lock:
            return [{**asdict(e), "robots": list(e.robots)} for e in self.events]
