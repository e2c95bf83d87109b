"""The battery: charge drawn by the load over simulated time, the voltage it sags to, and
PX4's warning levels (BAT_LOW_THR, BAT_CRIT_THR, BAT_EMERGEN_THR of BAT1_CAPACITY)."""
from __future__ import annotations

import enum
import math
import threading

from .journal import CRITICAL, EMERGENCY, WARNING, Journal
from .params import Params

IDLE_A = 0.3  # avionics with the motors off
ARMED_GROUND_A = 1.5  # motors spinning on the ground
CELL_FULL_V, CELL_EMPTY_V = 4.2, 3.5
SAG_OHM = 0.01  # the pack's internal resistance: the voltage drops under load


class Charge(enum.IntEnum):
    """MAV_BATTERY_CHARGE_STATE values."""

    OK = 1
    LOW = 2
    CRITICAL = 3
    EMERGENCY = 4


WARNINGS = {Charge.LOW: (WARNING, "Low battery level! Return advised"),
            Charge.CRITICAL: (CRITICAL, "Critical battery level!"),
            Charge.EMERGENCY: (EMERGENCY, "Emergency battery level! Land now")}


def load_current(hover_a: float, armed: bool, airborne: bool, speed_xy: float, climb: float) -> float:
    """Amperes drawn: hovering costs `hover_a`, flying fast and climbing cost more."""
    if not armed:
        return IDLE_A
    if not airborne:
        return ARMED_GROUND_A
    return hover_a * (1.0 + 0.03 * speed_xy + 0.1 * max(0.0, climb))


class Battery:
    """Charge used (mAh) and the current load; `drain` steps it and announces a new level once."""

    def __init__(self, lock: threading.RLock, journal: Journal, params: Params,
                 drop: tuple[float, float] | None = None):
        self._lock = lock
        self._journal = journal
        self._params = params
        self._used_mah = 0.0
        self._current_a = IDLE_A
        self._charge = Charge.OK
        # The injected fault `battery:PCT@SECONDS` (protocol/faults.py): (fraction left, seconds in the air).
        self._drop = drop
        self._airborne_s = 0.0

    def drain(self, dt: float, armed: bool, airborne: bool, vel: tuple[float, float, float]) -> Charge | None:
        """Draw the load for `dt` simulated seconds; the new charge state if it just got worse."""
        p = self._params
        with self._lock:
            self._current_a = load_current(p.get("SIM_BAT_HOVER_A"), armed, airborne, math.hypot(vel[0], vel[1]),
                                           -vel[2])
            self._used_mah += self._current_a * dt / 3.6
            if airborne:
                self._airborne_s += dt
            if self._drop is not None and self._airborne_s >= self._drop[1]:
                left, self._drop = self._drop[0], None
                self._used_mah = max(self._used_mah, (1.0 - left) * p.get("BAT1_CAPACITY"))
                self._journal.event(f"fault injected: the pack holds {left:.0%} after {self._airborne_s:.0f} s "
                                    "in the air")
            charge = self.charge_of(self.remaining)
            if charge <= self._charge:
                self._charge = charge  # a fuller pack (a new BAT1_CAPACITY) starts its warnings over
                return None
            self._charge = charge
        severity, text = WARNINGS[charge]
        self._journal.say(severity, text)
        return charge

    def charge_of(self, remaining: float) -> Charge:
        p = self._params
        if remaining <= p.get("BAT_EMERGEN_THR"):
            return Charge.EMERGENCY
        if remaining <= p.get("BAT_CRIT_THR"):
            return Charge.CRITICAL
        if remaining <= p.get("BAT_LOW_THR"):
            return Charge.LOW
        return Charge.OK

    @property
    def remaining(self) -> float:
        """Fraction of BAT1_CAPACITY left, 0..1."""
        with self._lock:
            return max(0.0, 1.0 - self._used_mah / self._params.get("BAT1_CAPACITY"))

    @property
    def cells(self) -> int:
        return int(self._params.get("BAT1_N_CELLS"))

    @property
    def capacity_mah(self) -> float:
        return self._params.get("BAT1_CAPACITY")

    @property
    def charge(self) -> Charge:
        with self._lock:
            return self._charge

    def reading(self) -> tuple[float, float, float, float]:
        """(volts, amperes, mAh used, remaining 0..1) at one instant."""
        with self._lock:
            remaining = self.remaining
            cells = self._params.get("BAT1_N_CELLS")
            volts = cells * (CELL_EMPTY_V + (CELL_FULL_V - CELL_EMPTY_V) * remaining) - self._current_a * SAG_OHM
            return volts, self._current_a, self._used_mah, remaining
