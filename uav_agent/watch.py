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
# MAVSDK names ArduCopter's GUIDED, the mode its position targets fly in, OFFBOARD (and LOITER and
# BRAKE both HOLD): for ArduPilot that one is the mission's own.
FOREIGN_BY_AUTOPILOT = {"ARDUPILOT": FOREIGN_MODES - {"OFFBOARD"}}
# A mode that means the autopilot itself took the vehicle down or home: the agent leaves it to it.
FAILSAFE_MODES = {"LAND", "RETURN_TO_LAUNCH"}
# A fault seen this soon after the link came back from a loss is said to follow it (the autopilot's
# datalink-loss failsafe acts while the link is down, and its STATUSTEXT then never comes).
GAP_SAID_S = 10.0


class VehicleWatch:
    def __init__(self, flight: Any, on_fault: Callable[[str], None], period_s: float = 0.2) -> None:
        self.flight = flight
        self.on_fault = on_fault
        self.period_s = period_s
        self.fault: str | None = None
        self.taken_by: str | None = None   # the autopilot's own mode, a disarm or the ground: not the mission's
        self._airborne = threading.Event()
        self._lifting = False   # taking off: still on the ground is no fault, a foreign mode is
        self._judging = threading.Lock()   # the loop and `now` record one fault, once
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="vehicle-watch", daemon=True)
        self._thread.start()

    def expect_airborne(self, airborne: bool, taking_off: bool = False) -> None:
        """From now on the vehicle must be in the air (`taking_off`: it is about to be; on the ground is
        no fault until it has been seen in the air), or not watched."""
        self._lifting = airborne and taking_off
        (self._airborne.set if airborne else self._airborne.clear)()

    def _check(self) -> str | None:
        return self._taken()[1]

    def _taken(self) -> tuple[str | None, str | None]:
        """(what took the vehicle: a mode, "disarmed", "on the ground"; the fault's line), or (None, None)."""
        f = self.flight
        if not f.armed:
            return "disarmed", "the vehicle was disarmed by someone else" + _gap(f)
        if not f.in_air:
            if not self._lifting:
                return "on the ground", "the vehicle is on the ground though the mission did not land it" + _gap(f)
        else:
            self._lifting = False
        mode = f.flight_mode
        foreign = FOREIGN_BY_AUTOPILOT.get(getattr(f, "autopilot", ""), FOREIGN_MODES) - getattr(f, "own_modes", set())
        if mode in foreign:
            return mode, f"the vehicle switched to {mode} mode, which the mission did not command" + _why(f)
        return None, None

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            self.now()

    def now(self) -> str | None:
        """The fault, judged on the caller's thread from the latest telemetry (the flight's guard asks before
        every command and at every poll of a wait: it must not wait for the loop's next turn)."""
        with self._judging:
            if not self._airborne.is_set() or self.fault is not None:
                return self.fault
            try:
                lost = getattr(self.flight, "link_lost_for", None)
                if lost is not None:   # kept up to date, so a fault after a lost link says so
                    lost(GAP_SAID_S)
                taken, why = self._taken()
            except Exception as exc:  # noqa: BLE001 - a lost link is a fault like any other
                taken, why = None, f"the vehicle's telemetry failed: {exc}"
            # The mission may have cleared the flag (its own landing) while we were reading.
            if why is None or not self._airborne.is_set():
                return None
            self.taken_by = taken
            self.fault = why
        self.on_fault(why)
        return why

    @property
    def failsafe(self) -> bool:
        """The autopilot took the vehicle (a failsafe's or a pilot's mode, a disarm): the mission must
        not command it any more, not even to land."""
        return self.taken_by is not None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)


def _why(flight: Any) -> str:
    """What the autopilot says of it: the battery (a failsafe's usual reason) and its last STATUSTEXT."""
    parts = []
    pct = getattr(flight, "battery_pct", -1.0)
    if isinstance(pct, (int, float)) and pct >= 0:
        parts.append(f"battery {pct:.0f} %")
    text = getattr(flight, "status_text", "")
    if text:
        parts.append(f"the autopilot says {text!r}")
    if _gap(flight):
        parts.append(_gap(flight)[2:-1])
    return f" ({'; '.join(parts)})" if parts else ""


def _gap(flight: Any) -> str:
    """What a lost link explains: the autopilot's datalink-loss failsafe acted, and what it said meanwhile
    never came."""
    lost = getattr(flight, "link_lost_for", None)
    gap = lost(GAP_SAID_S) if callable(lost) else 0.0
    if not (isinstance(gap, (int, float)) and gap > 0):
        return ""
    return f" (after its MAVLink link was lost for {gap:.0f} s: its datalink-loss failsafe)"
