"""The fault mavlink-loss:SECONDS+DURATION (protocol/faults.py, link.mavlink): from SECONDS simulated
seconds after liftoff, for DURATION simulated seconds, the flight link (the companion's: the UAV
agent's) carries nothing either way, as a radio out of range or a cut cable does. The ground
station's and the pose reader's links stay up: they are other radios.

Counted from liftoff (with the link heard once: a link never up is not lost), not boot: how long a vehicle waits on the ground (a companion starting, a
fleet coming alive) varies from run to run, its flight much less, so a window lands in the same
part of the mission every time. Nothing else changes: the autopilot's own datalink-loss failsafe
(safety.py, PX4's COM_DL_LOSS_T then NAV_DLL_ACT) sees the companion's heartbeats stop and acts.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Callable

from .journal import Journal

BEFORE, DOWN, OVER = "before", "down", "over"


@dataclass
class LinkLoss:
    start_s: float                               # simulated seconds after liftoff
    duration_s: float                            # simulated seconds
    clock: Callable[[], tuple[float, bool]]      # (simulated seconds, airborne with the link heard)
    journal: Journal
    dropped: int = 0                             # messages lost, both ways
    _liftoff: float | None = None
    _state: str = BEFORE
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def down(self) -> bool:
        """Whether the flight link is down now; counts the message the caller then drops. Called
        holding no channel's lock (the journal takes the vehicle's)."""
        now, airborne = self.clock()
        said = None
        with self._lock:
            if self._liftoff is None:
                if not airborne:
                    return False
                self._liftoff = now
            since = now - self._liftoff
            down = self._state != OVER and since >= self.start_s and since < self.start_s + self.duration_s
            if down and self._state == BEFORE:
                self._state = DOWN
                said = (f"fault injected: the flight link carries nothing for {self.duration_s:g} s, from "
                        f"{since:.0f} s after liftoff")
            elif not down and self._state == DOWN:
                self._state = OVER
                said = f"fault over: the flight link is back ({self.dropped} message(s) lost)"
            if down:
                self.dropped += 1
        if said is not None:
            self.journal.event(said)
        return down
