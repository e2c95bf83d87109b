"""The autopilot: arming, flight modes and the targets they set; it flies the airframe
(it is the dynamics' `Pilot`) and decides what a touchdown means."""
from __future__ import annotations

import math
import threading
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from .dynamics import Contact, Dynamics, Setpoint, Vec3
from .journal import Journal
from .modes import LandedState, Mode
from .offboard import Offboard
from .params import Params

TAKEOFF_DONE_M = 0.1  # takeoff ends within this distance of the takeoff altitude
LAND_SLOW_ALT_M = 2.0  # below this altitude a landing descends at the land speed
MIN_TAKEOFF_ALT_M = 0.5


class Autopilot:
    """Arming, the flight mode, the target it flies to and the cruise speed. Actions return
    a MAV_RESULT; all of them hold the lock so that each is one decision."""

    def __init__(self, lock: threading.RLock, journal: Journal, dynamics: Dynamics, params: Params,
                 offboard: Offboard, cruise_speed_m_s: float):
        self._lock = lock
        self._journal = journal
        self._dynamics = dynamics
        self._params = params
        self._offboard = offboard
        self._armed = False
        self._mode = Mode.HOLD
        self._target: Vec3 = dynamics.position
        self._target_yaw = 0.0
        self._speed_xy = cruise_speed_m_s  # DO_CHANGE_SPEED and DO_REPOSITION set it
        self._touchdown_at: float | None = None  # simulated time the vehicle last touched down
        # The modes this vehicle flies and how each is entered; the others need an RC or a
        # mission, which it lacks.
        self._mode_entries: dict[Mode, Callable[[], int]] = {
            Mode.HOLD: self._enter_hold_mode,
            Mode.TAKEOFF: lambda: self.takeoff(None, None),
            Mode.LAND: self.land,
            Mode.OFFBOARD: self._enter_offboard,
        }
        params.watch("MPC_XY_VEL_MAX", self._cap_cruise_speed)

    # --- state ---------------------------------------------------------------------------

    @property
    def armed(self) -> bool:
        with self._lock:
            return self._armed

    @property
    def mode(self) -> Mode:
        with self._lock:
            return self._mode

    @property
    def landed_state(self) -> LandedState:
        with self._lock:
            if (self._armed and self._mode == Mode.TAKEOFF
                    and self._dynamics.altitude < -self._target[2] - TAKEOFF_DONE_M):
                return LandedState.TAKING_OFF
            if not self._dynamics.airborne:
                return LandedState.ON_GROUND
            if self._mode == Mode.LAND:
                return LandedState.LANDING
            return LandedState.IN_AIR

    def status(self) -> tuple[bool, Mode, LandedState]:
        """(armed, mode, landed state) read together: what a heartbeat must announce."""
        with self._lock:
            return self._armed, self._mode, self.landed_state

    # --- actions ---------------------------------------------------------------------------

    def arm(self, arm: bool, force: bool) -> int:
        with self._lock:
            airborne = self._dynamics.airborne
            if arm:
                if self._armed:
                    return mavlink.MAV_RESULT_ACCEPTED
                if airborne and not force:
                    return mavlink.MAV_RESULT_DENIED
                self._armed = True
                self._touchdown_at = None
                if self._mode == Mode.HOLD:
                    self._target = self._dynamics.position
                self._journal.event("armed")
                return mavlink.MAV_RESULT_ACCEPTED
            if not self._armed:
                return mavlink.MAV_RESULT_ACCEPTED
            if airborne and not force:
                return mavlink.MAV_RESULT_DENIED
            self._disarm("disarmed" + (" in the air (forced)" if airborne else ""))
            return mavlink.MAV_RESULT_ACCEPTED

    def takeoff(self, alt_m: float | None, yaw: float | None) -> int:
        """Climb straight up to `alt_m` above home (None: MIS_TAKEOFF_ALT), then hold."""
        with self._lock:
            if not self._armed:
                return mavlink.MAV_RESULT_DENIED
            if alt_m is None:
                alt_m = self._params.get("MIS_TAKEOFF_ALT")
            alt_m = min(max(alt_m, MIN_TAKEOFF_ALT_M), self._dynamics.ceiling)
            north, east, _ = self._dynamics.position
            self._mode = Mode.TAKEOFF
            self._target = (north, east, -alt_m)
            if yaw is not None:
                self._target_yaw = yaw
            self._journal.event(f"takeoff to {alt_m:.1f} m")
            return mavlink.MAV_RESULT_ACCEPTED

    def land(self) -> int:
        with self._lock:
            if self._mode != Mode.LAND:
                self._mode = Mode.LAND
                self._journal.event("landing")
            north, east, _ = self._dynamics.position
            self._target = (north, east, 0.0)
            return mavlink.MAV_RESULT_ACCEPTED

    def loiter(self) -> int:
        with self._lock:
            if not self._armed:
                return mavlink.MAV_RESULT_DENIED
            self._enter_hold()
            return mavlink.MAV_RESULT_ACCEPTED

    def reposition(self, north: float | None, east: float | None, down: float | None, yaw: float | None,
                   speed_m_s: float | None) -> int:
        """Fly to a point and hold there; None keeps the current coordinate, yaw or speed."""
        with self._lock:
            if not self._armed:
                return mavlink.MAV_RESULT_DENIED
            here_n, here_e, here_d = self._dynamics.position
            north = here_n if north is None else north
            east = here_e if east is None else east
            down = self._dynamics.clamp_down(here_d if down is None else down)
            if self._mode != Mode.HOLD:
                self._journal.event(f"mode {self._mode.name} -> HOLD (reposition)")
            self._mode = Mode.HOLD
            self._target = (north, east, down)
            if yaw is not None:
                self._target_yaw = yaw
            if speed_m_s is not None:
                self._speed_xy = min(speed_m_s, self._params.get("MPC_XY_VEL_MAX"))
            return mavlink.MAV_RESULT_ACCEPTED

    def set_mode(self, main: int, sub: int) -> int:
        """Switch to PX4 mode (main, sub) if this vehicle flies it."""
        mode = Mode.from_custom_mode(main, sub)
        enter = self._mode_entries.get(mode)
        if enter is None:
            self._journal.warn(f"refused mode main={main} sub={sub} ({mode.name if mode else 'unknown'})")
            return mavlink.MAV_RESULT_DENIED
        with self._lock:
            if mode == self._mode:
                return mavlink.MAV_RESULT_ACCEPTED
            return enter()

    def change_speed(self, kind: int, speed: float) -> int:
        """DO_CHANGE_SPEED: kind 0 or 1 the cruise speed, 2 the climb, 3 the descent limit."""
        if not (math.isfinite(speed) and speed > 0):
            return mavlink.MAV_RESULT_ACCEPTED  # -1 means "no change"
        with self._lock:
            if kind in (0, 1):
                self._speed_xy = min(speed, self._params.get("MPC_XY_VEL_MAX"))
            elif kind in (2, 3):
                # capped from above only: a commanded crawl below the parameter's minimum is kept
                self._params.set("MPC_Z_VEL_MAX_UP" if kind == 2 else "MPC_Z_VEL_MAX_DN", speed, clamp_low=False)
            else:
                return mavlink.MAV_RESULT_DENIED
        return mavlink.MAV_RESULT_ACCEPTED

    # --- flying (the dynamics' Pilot; called under the lock) --------------------------------

    def setpoint(self, dt: float, wall_now: float) -> Setpoint | None:
        if not self._armed:
            return None
        up, down = self._params.get("MPC_Z_VEL_MAX_UP"), self._params.get("MPC_Z_VEL_MAX_DN")
        speed = min(self._speed_xy, self._params.get("MPC_XY_VEL_MAX"))
        if self._mode == Mode.OFFBOARD:
            if self._offboard.lost(wall_now):
                self._journal.event("offboard setpoints lost")
                self._enter_hold()
            else:
                target = self._offboard.target(self._dynamics.position, dt, speed, up, down)
                if target is not None:
                    self._target = target
            yaw = self._offboard.yaw
            if yaw is not None:
                self._target_yaw = yaw
        if self._mode == Mode.LAND:
            north, east, _ = self._dynamics.position
            self._target = (north, east, 0.0)
            if self._dynamics.altitude <= LAND_SLOW_ALT_M:
                down = min(down, self._params.get("MPC_LAND_SPEED"))
            speed = 0.0
        if self._mode == Mode.TAKEOFF:
            speed = 0.0  # a vertical climb, like PX4's takeoff
        target = (self._target[0], self._target[1], self._dynamics.clamp_down(self._target[2]))
        return Setpoint(target, self._target_yaw, speed, up, down)

    def on_moved(self, setpoint: Setpoint) -> None:
        alt = self._dynamics.altitude
        if self._mode == Mode.TAKEOFF and abs(alt + setpoint.target[2]) <= TAKEOFF_DONE_M:
            self._journal.event(f"takeoff complete at {alt:.1f} m")
            self._enter_hold()

    def on_contact(self, contact: Contact | None) -> None:
        """Like PX4's commander: auto-disarm COM_DISARM_LAND simulated seconds after touchdown."""
        now = self._dynamics.sim_time
        if contact is Contact.LIFTOFF:
            self._touchdown_at = None
        elif contact is Contact.TOUCHDOWN:
            self._touchdown_at = now
        elif (self._armed and not self._dynamics.airborne and self._mode == Mode.LAND
              and self._touchdown_at is None):
            self._touchdown_at = now  # told to land while still on the ground
        if (self._armed and self._touchdown_at is not None and not self._dynamics.airborne
                and now - self._touchdown_at >= self._params.get("COM_DISARM_LAND")):
            self._disarm("disarmed after landing")

    # --- transitions (the caller holds the lock) ----------------------------------------------

    def _disarm(self, why: str) -> None:
        self._armed = False
        self._touchdown_at = None
        if self._mode in (Mode.LAND, Mode.TAKEOFF):
            self._mode = Mode.HOLD  # so that the next arm + takeoff starts clean
        self._journal.event(why)

    def _enter_hold(self) -> None:
        """Switch to HOLD, braking at the current position."""
        if self._mode != Mode.HOLD:
            self._journal.event(f"mode {self._mode.name} -> HOLD")
        self._mode = Mode.HOLD
        self._target = self._dynamics.position

    def _enter_hold_mode(self) -> int:
        self._enter_hold()
        return mavlink.MAV_RESULT_ACCEPTED

    def _enter_offboard(self) -> int:
        if not self._offboard.streaming(time.monotonic()):
            return mavlink.MAV_RESULT_DENIED  # PX4 only switches once setpoints are streaming
        self._mode = Mode.OFFBOARD
        self._journal.event("mode OFFBOARD")
        return mavlink.MAV_RESULT_ACCEPTED

    def _cap_cruise_speed(self, max_speed: float) -> None:
        self._speed_xy = min(self._speed_xy, max_speed)
