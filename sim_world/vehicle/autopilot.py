"""The autopilot: arming, flight modes and the targets they set, the failsafes; it flies the
airframe (it is the dynamics' `Pilot`) and decides what a touchdown means.

Every mode change and every refusal is said as STATUSTEXT (severities as PX4's
mavlink_log_info / _critical use them). Failsafes, as PX4's commander: a critical battery
(COM_LOW_BAT_ACT), a geofence breach (GF_ACTION) and a datalink loss (NAV_DLL_ACT after
COM_DL_LOSS_T, holding COM_FAIL_ACT_T first so that an operator can take over). A battery
failsafe's return or landing (and the landing of a depleted battery, whatever COM_LOW_BAT_ACT
says) is kept: until the vehicle is down and disarmed, a takeoff, goto, mode change, mission or
offboard start is denied; only a LAND, and a forced disarm, are taken.

Preflight, as PX4's arming checks: no arming at or below BAT_LOW_THR (or below COM_ARM_BAT_MIN),
no takeoff at a critical battery; armed on the ground without taking off, it disarms after
COM_DISARM_PRFLT seconds, and after a touchdown after COM_DISARM_LAND.

The targets each mode flies to are guidance.py's, the failsafes and preflight checks safety.py's.
The autopilot lives in its estimate's frame (`Estimator.believed`): it holds where it believes
it is; the airframe flies the true point that is (`Estimator.truth_of`).
"""
from __future__ import annotations

import math
import threading
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from .battery import Battery, Charge
from .datalink import Datalink
from .dynamics import Contact, Dynamics
from .estimator import Estimator
from .geofence import Geofence
from .guidance import TAKEOFF_DONE_M, Guidance
from .journal import CRITICAL, INFO, Journal
from .mission import Mission
from .modes import LandedState, Mode
from .motion import Setpoint, Vec3
from .offboard import Offboard
from .params import Params
from .payload import Payload
from .safety import Safety

LAND_SLOW_ALT_M = 2.0  # below this altitude a landing descends at the land speed


class Autopilot(Guidance, Safety):
    """Arming, the flight mode, the target it flies to and the cruise speed. Actions return
    a MAV_RESULT; all of them hold the lock so that each is one decision."""

    def __init__(self, lock: threading.RLock, journal: Journal, dynamics: Dynamics, params: Params,
                 offboard: Offboard, battery: Battery, datalink: Datalink, mission: Mission, cruise_speed_m_s: float,
                 estimator: Estimator | None = None, payload: Payload | None = None, gps: bool = True,
                 ready_after_s: float = 0.0):
        self._lock = lock
        self._ready_after_s = ready_after_s
        self._estimator = estimator
        self._payload = payload
        self._gps = gps
        self._journal = journal
        self._dynamics = dynamics
        self._params = params
        self._offboard = offboard
        self._battery = battery
        self._datalink = datalink
        self._mission = mission
        self._fence = Geofence(params)
        self._armed = False
        self._mode = Mode.HOLD
        self._target: Vec3 = dynamics.position
        self._velocity: tuple | None = None  # an offboard velocity (per axis, None: fly to the target)
        self._target_yaw = dynamics.pose()[3]   # it keeps the heading it booted with until told another
        self._speed_xy = cruise_speed_m_s  # DO_CHANGE_SPEED and DO_REPOSITION set it
        self._touchdown_at: float | None = None  # simulated time the vehicle last touched down
        self._landing = False  # descending to land (LAND, the end of RTL or of a mission)
        self._rtl_phase = "climb"
        self._rtl_alt = 0.0
        self._breached = False
        self._link_lost = False
        self._clamping = False
        self._pending: tuple[Mode, float, str] | None = None  # a failsafe action due at a wall time
        self._kept: tuple[Mode, str] | None = None  # a battery failsafe's RTL or LAND, kept until disarmed
        self._armed_wall = 0.0  # wall time of arming (COM_DISARM_PRFLT runs on the operator's clock)
        self._flew = False  # took off since arming
        # The modes this vehicle flies and how each is entered; the others need an RC, which it lacks.
        self._mode_entries: dict[Mode, Callable[[], int]] = {
            Mode.HOLD: self._enter_hold_mode,
            Mode.POSCTL: self._enter_position,
            Mode.TAKEOFF: lambda: self.takeoff(None, None),
            Mode.LAND: self.land,
            Mode.RTL: self.rtl,
            Mode.MISSION: self._enter_mission,
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
            if self._landing or self._mode == Mode.LAND:
                return LandedState.LANDING
            return LandedState.IN_AIR

    @property
    def fence_enabled(self) -> bool:
        return self._fence.enabled

    @property
    def fence_breached(self) -> bool:
        with self._lock:
            return self._breached

    @property
    def kept(self) -> tuple[Mode, str] | None:
        """The battery failsafe's mode and reason while it is kept, else None."""
        with self._lock:
            return self._kept

    def _position(self) -> Vec3:
        """Where the autopilot believes it is (its estimate without the samples' noise)."""
        here = self._dynamics.position
        return here if self._estimator is None else self._estimator.believed(here)

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
                    return self._refuse("Arming denied: the vehicle is in the air")
                settling = self._ready_after_s - self._dynamics.sim_time
                if settling > 0 and not force:
                    return self._refuse(f"Arming denied: estimator not ready ({settling:.0f} s)")
                low = None if force else self._preflight_battery()
                if low is not None:
                    return self._refuse(f"Arming denied: {low}")
                self._armed = True
                self._touchdown_at = None
                self._armed_wall = time.monotonic()
                self._flew = airborne
                if self._mode in (Mode.HOLD, Mode.POSCTL):
                    self._target = self._position()
                self._journal.event("armed" + (" (forced)" if force else ""))
                return mavlink.MAV_RESULT_ACCEPTED
            if not self._armed:
                return mavlink.MAV_RESULT_ACCEPTED
            if airborne and not force:
                return self._refuse("Disarming denied: the vehicle is in the air")
            self._disarm("disarmed" + (" in the air (forced)" if airborne else ""))
            return mavlink.MAV_RESULT_ACCEPTED

    def takeoff(self, alt_m: float | None, yaw: float | None) -> int:
        """Climb straight up to `alt_m` above home (None: MIS_TAKEOFF_ALT, which is also the
        lowest takeoff PX4 flies), then hold."""
        with self._lock:
            if not self._armed:
                return self._refuse("Takeoff denied: disarmed")
            if self._kept is not None:
                return self._deny_kept("Takeoff")
            if self._battery.charge_of(self._battery.remaining) >= Charge.CRITICAL:
                return self._refuse(f"Takeoff denied: battery {self._battery.remaining:.0%}, critical")
            minimum = self._params.get("MIS_TAKEOFF_ALT")
            if alt_m is None:
                alt_m = minimum
            elif alt_m < minimum:
                if alt_m < minimum - 0.1:
                    self._journal.say(CRITICAL, f"Using minimum takeoff altitude: {minimum:.2f} m")
                alt_m = minimum
            alt_m = min(alt_m, self._dynamics.ceiling, self._fence_ceiling())
            north, east, _ = self._position()
            self._switch(Mode.TAKEOFF)
            self._target = (north, east, -alt_m)
            if yaw is not None:
                self._target_yaw = yaw
            self._journal.event(f"takeoff to {alt_m:.1f} m")
            return mavlink.MAV_RESULT_ACCEPTED

    def land(self) -> int:
        with self._lock:
            if self._kept is not None:
                self._kept = (Mode.LAND, self._kept[1])  # a battery failsafe's landing, now: kept as such
            self._switch(Mode.LAND)
            north, east, _ = self._position()
            self._target = (north, east, 0.0)
            return mavlink.MAV_RESULT_ACCEPTED

    def rtl(self, why: str | None = None) -> int:
        """Return to launch: climb to RTL_RETURN_ALT (or stay higher), fly home, land, disarm."""
        with self._lock:
            if self._kept is not None and self._kept[0] != Mode.RTL:
                return self._deny_kept("Return")
            if not (self._armed and self._dynamics.airborne):
                return self._refuse("Return denied: not flying")
            if not self._gps:
                return self._refuse("Return denied: no global position (no GPS)")
            ceiling = min(self._dynamics.ceiling, self._fence_ceiling())
            self._rtl_alt = min(max(self._dynamics.altitude, self._params.get("RTL_RETURN_ALT")), ceiling)
            self._rtl_phase = "climb"
            self._switch(Mode.RTL, why)
            return mavlink.MAV_RESULT_ACCEPTED

    def loiter(self) -> int:
        with self._lock:
            if not self._armed:
                return self._refuse("Hold denied: disarmed")
            if self._kept is not None:
                return self._deny_kept("Hold")
            self._enter_hold()
            return mavlink.MAV_RESULT_ACCEPTED

    def reposition(self, north: float | None, east: float | None, down: float | None, yaw: float | None,
                   speed_m_s: float | None) -> int:
        """Fly to a point and hold there; None keeps the current coordinate, yaw or speed."""
        with self._lock:
            if not self._armed:
                return self._refuse("Reposition denied: disarmed")
            if self._kept is not None:
                return self._deny_kept("Reposition")
            here_n, here_e, here_d = self._position()
            north = here_n if north is None else north
            east = here_e if east is None else east
            down = self._dynamics.clamp_down(here_d if down is None else down)
            outside = self._fence.violation((north, east, down))
            if outside is not None:
                return self._refuse(f"Reposition denied: target outside the geofence ({outside})")
            self._switch(Mode.HOLD, "reposition")
            self._target = (north, east, down)
            if yaw is not None and self._params.get("SIM_GOTO_YAW"):   # 0: as ArduCopter, which ignores it
                self._target_yaw = yaw
            if speed_m_s is not None:
                self._speed_xy = min(speed_m_s, self._params.get("MPC_XY_VEL_MAX"))
            return mavlink.MAV_RESULT_ACCEPTED

    def set_mode(self, main: int, sub: int) -> int:
        """Switch to PX4 mode (main, sub) if this vehicle flies it."""
        mode = Mode.from_custom_mode(main, sub)
        enter = self._mode_entries.get(mode)
        if enter is None:
            return self._refuse(f"Mode {mode.name if mode else f'{main}.{sub}'} not available on this vehicle")
        with self._lock:
            if mode == self._mode:
                return mavlink.MAV_RESULT_ACCEPTED
            if self._kept is not None and mode != Mode.LAND:
                return self._deny_kept(f"Mode {mode.name}")
            self._pending = None  # an operator's choice ends a failsafe's countdown
            return enter()

    def start_mission(self) -> int:
        """MAV_CMD_MISSION_START: AUTO.MISSION from the current item."""
        with self._lock:
            if self._kept is not None:
                return self._deny_kept("Mission")
            return self._enter_mission()

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
                return self._refuse(f"Speed change denied: unknown speed type {kind}")
        return mavlink.MAV_RESULT_ACCEPTED

    # --- flying (the dynamics' Pilot; called under the lock) --------------------------------

    def setpoint(self, dt: float, wall_now: float) -> Setpoint | None:
        airborne = self._dynamics.airborne
        charge = self._battery.drain(dt, self._armed, airborne, self._dynamics.state().vel)
        if self._estimator is not None:
            self._estimator.advance(dt)
        if not self._armed:
            return None
        if airborne:
            self._failsafes(charge, wall_now)
        elif not self._flew and self._preflight_timeout(wall_now):
            return None
        if not self._armed:
            return None
        p = self._params
        up, down = p.get("MPC_Z_VEL_MAX_UP"), p.get("MPC_Z_VEL_MAX_DN")
        speed = min(self._speed_xy, p.get("MPC_XY_VEL_MAX"))
        here = self._position()
        if airborne and self._payload is not None:
            self._payload.fly(here, self._dynamics.sim_time)
        self._landing = False
        self._velocity = None
        if self._mode == Mode.OFFBOARD:
            self._offboard_target(wall_now, dt, speed, up, down)
        elif self._mode == Mode.MISSION:
            speed = self._mission_target(here, airborne, speed)
        if self._mode == Mode.RTL:
            speed = self._rtl_target(here, speed)
        if self._mode == Mode.LAND or self._landing:
            self._landing = True
            self._target = (here[0], here[1], 0.0) if self._mode == Mode.LAND else self._target
            if self._dynamics.altitude <= LAND_SLOW_ALT_M:
                down = min(down, self._params.get("MPC_LAND_SPEED"))
            speed = 0.0 if self._mode == Mode.LAND else speed
        if self._mode == Mode.TAKEOFF:
            speed = 0.0  # a vertical climb, like PX4's takeoff
        target = (self._target[0], self._target[1], self._dynamics.clamp_down(self._target[2]))
        if self._estimator is not None:
            target = self._estimator.truth_of(target)
        return Setpoint(target, self._target_yaw, speed, up, down, velocity=self._velocity,
                        accel_xy=p.get("MPC_ACC_HOR"), accel_up=p.get("MPC_ACC_UP_MAX"),
                        accel_down=p.get("MPC_ACC_DOWN_MAX"), jerk=p.get("MPC_JERK_AUTO"))

    def on_moved(self, setpoint: Setpoint) -> None:
        alt = self._dynamics.altitude
        if self._mode == Mode.TAKEOFF and abs(alt + setpoint.target[2]) <= TAKEOFF_DONE_M:
            self._journal.event(f"takeoff complete at {alt:.1f} m")
            self._enter_hold()
            # hold at the takeoff altitude, not where the climb was called done (once 0.42 m for 0.5 m)
            self._target = (*self._target[:2], setpoint.target[2])

    def on_contact(self, contact: Contact | None) -> None:
        """Like PX4's commander: auto-disarm COM_DISARM_LAND simulated seconds after touchdown."""
        now = self._dynamics.sim_time
        if contact is Contact.LIFTOFF:
            self._touchdown_at = None
            self._flew = True
        elif contact is Contact.TOUCHDOWN:
            self._touchdown_at = now
        elif (self._armed and not self._dynamics.airborne and self._mode == Mode.LAND
              and self._touchdown_at is None):
            self._touchdown_at = now  # told to land while still on the ground
        if (self._armed and self._touchdown_at is not None and not self._dynamics.airborne
                and now - self._touchdown_at >= self._params.get("COM_DISARM_LAND")):
            self._disarm("disarmed after landing")

    # --- transitions (the caller holds the lock) ----------------------------------------------

    def _switch(self, mode: Mode, why: str | None = None) -> None:
        """Enter `mode`, telling the ground stations (PX4 says mode changes at INFO)."""
        if mode == self._mode:
            return
        self._journal.say(INFO, f"Mode {self._mode.name} -> {mode.name}" + (f" ({why})" if why else ""))
        self._mode = mode

    def _refuse(self, why: str) -> int:
        self._journal.say(CRITICAL, why)
        return mavlink.MAV_RESULT_DENIED

    def _deny_kept(self, what: str) -> int:
        mode, why = self._kept
        return self._refuse(f"{what} denied: failsafe {mode.name} ({why}) in progress")

    def _disarm(self, why: str) -> None:
        self._armed = False
        self._touchdown_at = None
        self._pending = None
        self._kept = None
        if self._mode in (Mode.LAND, Mode.TAKEOFF, Mode.RTL, Mode.MISSION):
            self._switch(Mode.HOLD, why)  # so that the next arm + takeoff starts clean
        self._journal.event(why)

    def _disarm_soon(self) -> None:
        """A finished mission on the ground disarms like a landing."""
        if self._touchdown_at is None:
            self._touchdown_at = self._dynamics.sim_time

    def _enter_hold(self, why: str | None = None) -> None:
        """Switch to HOLD, braking at the current position."""
        self._switch(Mode.HOLD, why)
        self._target = self._position()

    def _enter_hold_mode(self) -> int:
        self._enter_hold()
        return mavlink.MAV_RESULT_ACCEPTED

    def _enter_position(self) -> int:
        """POSCTL without sticks: centred sticks hold the position, which is all this vehicle can do."""
        self._switch(Mode.POSCTL)
        self._target = self._position()
        return mavlink.MAV_RESULT_ACCEPTED

    def _enter_mission(self) -> int:
        items = self._mission.items
        if not items:
            return self._refuse("Mission denied: no mission uploaded")
        if not self._gps:
            return self._refuse("Mission denied: no global position (no GPS)")
        here = self._position()
        outside = next((v for v in map(self._fence.violation, self._mission.points(here)) if v), None)
        if outside is not None:
            return self._refuse(f"Mission denied: an item is outside the geofence ({outside})")
        if self._mission.finished:
            self._mission.set_current(0)
        self._switch(Mode.MISSION)
        return mavlink.MAV_RESULT_ACCEPTED

    def _enter_offboard(self) -> int:
        if not self._offboard.streaming(time.monotonic()):
            return self._refuse("Offboard denied: no setpoint stream")  # PX4 switches only once setpoints stream
        self._switch(Mode.OFFBOARD)
        return mavlink.MAV_RESULT_ACCEPTED

    def _fence_ceiling(self) -> float:
        ver = self._params.get("GF_MAX_VER_DIST")
        return ver if ver > 0 else math.inf

    def _cap_cruise_speed(self, max_speed: float) -> None:
        self._speed_xy = min(self._speed_xy, max_speed)
