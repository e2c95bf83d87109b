"""The UAV watches its own vehicle: an unplanned disarm, landing or mode change is a fault, never a success.

The mission says when the vehicle must be airborne (from take-off to its own
landing); a thread reads the autopilot's telemetry (MAVSDK) meanwhile, and the
first thing that contradicts the plan becomes an event and `fault`.
"""
from __future__ import annotations

import threading
from typing import Any, Callable

# Modes the UAV never commands during a mission: someone else (a ground station, a failsafe) did.
# The mission flies in HOLD (position targets), TAKEOFF and LAND only after it commanded them.
FOREIGN_MODES = {"LAND", "RETURN_TO_LAUNCH", "MANUAL", "STABILIZED", "ACRO", "ALTCTL", "POSCTL", "MISSION",
                 "OFFBOARD", "FOLLOW_ME", "RATTITUDE"}


class VehicleWatch:
    def __init__(self, flight: Any, on_fault: Callable[[str], None], period_s: float = 0.2) -> None:
        self.flight = flight
        self.on_fault = on_fault
        self.period_s = period_s
        self.fault: str | None = None
        self._airborne = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="vehicle-watch", daemon=True)
        self._thread.start()

    def expect_airborne(self, airborne: bool) -> None:
        (self._airborne.set if airborne else self._airborne.clear)()

    def _check(self) -> str | None:
        f = self.flight
        if not f.armed:
            return "the vehicle was disarmed by someone else"
        if not f.in_air:
            return "the vehicle is on the ground though the mission did not land it"
        mode = f.flight_mode
        if mode in FOREIGN_MODES:
            return f"the vehicle switched to {mode} mode, which the mission did not command"
        return None

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            if not self._airborne.is_set() or self.fault is not None:
                continue
            try:
                why = self._check()
            except Exception as exc:  # noqa: BLE001 - a lost link is a fault like any other
                why = f"the vehicle's telemetry failed: {exc}"
            # The mission may have cleared the flag (its own landing) while we were reading.
            if why is not None and self._airborne.is_set():
                self.fault = why
                self.on_fault(why)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
