"""The autopilot's safety: PX4 commander's failsafes (battery, geofence, datalink) and preflight checks.

A part of `Autopilot` (autopilot.py), kept apart from its guidance and mode changes; the failsafes
run under the vehicle's lock from `Autopilot.setpoint` while the vehicle is armed and in the air.
"""
from __future__ import annotations

import threading

from pymavlink.dialects.v20 import common as mavlink

from .battery import Battery, Charge
from .datalink import Datalink
from .dynamics import Dynamics
from .geofence import Geofence
from .journal import CRITICAL, EMERGENCY, INFO, Journal
from .modes import Mode
from .params import Params

GF_ACTIONS = {2: Mode.HOLD, 3: Mode.RTL, 4: Mode.LAND, 5: Mode.LAND}  # GF_ACTION; 4 (terminate) lands here
DLL_ACTIONS = {1: Mode.HOLD, 2: Mode.RTL, 3: Mode.LAND}  # NAV_DLL_ACT
FLOWN_BACK = (Mode.LAND, Mode.RTL)  # failsafes never turn these into something else


class Safety:
    """Failsafes and preflight checks; mixed into Autopilot."""

    # The autopilot's parts and state these methods use (Autopilot.__init__ sets them).
    _lock: threading.RLock
    _journal: Journal
    _dynamics: Dynamics
    _params: Params
    _battery: Battery
    _datalink: Datalink
    _fence: Geofence
    _armed: bool
    _mode: Mode
    _breached: bool
    _link_lost: bool
    _pending: tuple[Mode, float, str] | None
    _kept: tuple[Mode, str] | None
    _armed_wall: float


    def _failsafes(self, charge: Charge | None, wall_now: float) -> None:
        act = int(self._params.get("COM_LOW_BAT_ACT"))
        if charge is Charge.CRITICAL and act in (2, 3):
            self._failsafe(Mode.RTL if act == 3 else Mode.LAND, "critical battery", keep=True)
        elif charge is Charge.EMERGENCY and act in (2, 3):
            self._failsafe(Mode.LAND, "emergency battery", keep=True)
        if self._battery.remaining <= 0.0 and (self._kept is None or self._kept[0] != Mode.LAND):
            # an empty pack cannot wait for the operator's choice of action
            self._journal.say(EMERGENCY, "Battery depleted: landing")
            self._failsafe(Mode.LAND, "battery depleted", keep=True)
        outside = self._fence.violation(self._position())
        if outside is not None and not self._breached:
            self._journal.say(CRITICAL, f"Geofence violated: {outside}")
            action = GF_ACTIONS.get(int(self._params.get("GF_ACTION")))
            if action is not None:
                self._failsafe(action, "geofence")
        self._breached = outside is not None
        self._check_datalink(wall_now)
        if self._pending is not None and wall_now >= self._pending[1]:
            mode, _, why = self._pending
            self._pending = None
            self._failsafe(mode, why)

    def _check_datalink(self, wall_now: float) -> None:
        action = DLL_ACTIONS.get(int(self._params.get("NAV_DLL_ACT")))
        lost = self._datalink.silent_for(wall_now) > self._params.get("COM_DL_LOSS_T")
        if lost and not self._link_lost and action is not None:
            if self._mode in FLOWN_BACK:
                self._journal.say(CRITICAL, "Data link lost")
            else:
                delay = self._params.get("COM_FAIL_ACT_T")
                self._journal.say(CRITICAL, "Data link lost: holding" + (
                    f", {action.name} in {delay:g} s" if action is not Mode.HOLD else ""))
                self._enter_hold("data link lost")
                if action is not Mode.HOLD:
                    self._pending = (action, wall_now + delay, "data link lost")
        elif not lost and self._link_lost:
            self._journal.say(INFO, "Data link regained")
            if self._pending is not None and self._pending[2] == "data link lost":
                self._pending = None
        self._link_lost = lost and action is not None

    def land_now(self, why: str) -> None:
        """Land where it is, kept as a failsafe's landing is (the process is told to stop in the air)."""
        with self._lock:
            if self._armed and self._dynamics.airborne:
                self._failsafe(Mode.LAND, why, keep=True)

    def _failsafe(self, mode: Mode, why: str, keep: bool = False) -> None:
        """Fly `mode` because of `why`; a landing or return already under way is kept (a land
        is never turned back into a return). With `keep` (a battery failsafe) the mode flown is
        kept until disarmed: commands that would leave it are denied."""
        if keep and self._mode in (Mode.LAND, Mode.RTL) and (self._kept is None or self._mode == Mode.LAND):
            self._kept = (self._mode, why)  # a return or landing already flown is now the failsafe's
        if self._mode == mode or self._mode == Mode.LAND or (self._mode == Mode.RTL and mode != Mode.LAND):
            return
        self._journal.say(CRITICAL, f"Failsafe: {why}, {mode.name}")
        if mode == Mode.RTL and self.rtl(why) == mavlink.MAV_RESULT_ACCEPTED:
            flown = Mode.RTL
        elif mode == Mode.HOLD:
            self._enter_hold(why)
            flown = Mode.HOLD
        else:
            self.land()
            flown = Mode.LAND
        if keep:
            self._kept = (flown, why)

    def _preflight_battery(self) -> str | None:
        """Why the battery forbids arming (PX4: at or below BAT_LOW_THR, or below COM_ARM_BAT_MIN), or None."""
        left = self._battery.remaining
        low, minimum = self._params.get("BAT_LOW_THR"), self._params.get("COM_ARM_BAT_MIN")
        if self._battery.charge_of(left) >= Charge.LOW:
            return f"low battery ({left:.0%}, BAT_LOW_THR {low:.0%})"
        if left < minimum:
            return f"battery {left:.0%} < COM_ARM_BAT_MIN {minimum:.0%}"
        return None

    def _preflight_timeout(self, wall_now: float) -> bool:
        """Disarm a vehicle armed on the ground that did not take off within COM_DISARM_PRFLT s."""
        limit = self._params.get("COM_DISARM_PRFLT")
        if limit > 0 and wall_now - self._armed_wall >= limit and self._mode not in (Mode.TAKEOFF, Mode.MISSION):
            self._disarm(f"disarmed: no takeoff within {limit:g} s of arming")
            return True
        return False
