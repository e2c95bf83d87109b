"""The UAV's MAVLink link to its autopilot, through MAVSDK 4.x (the native binding).

`Flight` is synchronous on purpose: the mission is a sequence of blocking steps
(connect, arm, take off, go to a pose, land), each with a timeout that ends in a
one-line `MissionError`. MAVSDK 4.x offers blocking calls on its own threads, so
no asyncio loop is needed: telemetry getters return the latest received values,
actions wait for the vehicle's COMMAND_ACK (MAVSDK retries, then gives up after a
couple of seconds).

Frame: local NED with its origin at the vehicle's home position as read once at
connect (for the simulated vehicle, the warehouse grid's top-left corner), converted
with protocol/geo.py exactly as the vehicle does. The origin is not updated if the
autopilot later moves its home (PX4 does on arming): the mission's frame must stay put.
An autopilot without a global position (indoor: no GPS, no home) is flown in its own
local frame instead (LOCAL_POSITION_NED, offboard position setpoints): its origin, where
its estimator started, is then the floor's corner.
"""
from __future__ import annotations

import json
import logging
import math
import time
from typing import Callable

from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.plugins.action import Action, ActionError, ActionResult
from mavsdk.plugins.mavlink_direct import MavlinkDirect, MavlinkMessage
from mavsdk.plugins.offboard import Offboard, OffboardError, PositionNedYaw
from mavsdk.plugins.telemetry import FixType, Telemetry

from protocol.errors import MissionError
from protocol.geo import check_home, ned_to_geo

from .flight_readings import Readings
from .mavsdk_logs import route_mavsdk_logs

DEFAULT_URL = "udpin://0.0.0.0:14540"
POLL_S = 0.02
SETTLED_M_S = 0.5  # a goto has arrived once the vehicle is this slow near its target
# An autopilot that has a local position but has sent no home this long after it is indoor (PX4 on
# vision or optical flow: no GPS, no home): the mission flies its local frame, in offboard.
NO_HOME_S = 3.0
OFFBOARD_START_S = 3.0   # how long the switch to offboard may take once setpoints stream
ARM_RETRY_S = 1.0        # a refused arm is asked again this often while the autopilot gets ready
# A refused command waits this long for the guard to name the autopilot's own decision behind it: more than a
# heartbeat's period (1 s, the mode's only carrier), so a failsafe that took the vehicle just before the
# command is what the mission reports, not the refusal it caused.
REFUSAL_GRACE_S = 1.5
MAV_CMD_DO_SET_MODE, CUSTOM_MODE_ENABLED, COPTER_GUIDED = 176, 1, 4
# A link that falls silent (a radio out of range: MAVSDK calls it disconnected after 3 s) is waited for this
# long, and a command it swallowed sent again meanwhile: longer than the autopilot's own datalink-loss
# timeout and its action's delay (PX4: COM_DL_LOSS_T 10 s, then COM_FAIL_ACT_T 5 s), so a link that comes
# back within it shows what the autopilot decided (its failsafe's mode, which the guard then names).
LINK_LOSS_S = 30.0
LINK_RETRY_S = 0.2
# After a silent link, its telemetry is trusted again this long after it came back: every stream the waits
# read (position, in-air state, mode) has then been sent afresh.
FRESH_S = 1.5
MAVSDK_SILENT_S = 3.0   # MAVSDK calls a system disconnected after this long without its heartbeat
LINK_LOST = (ActionResult.TIMEOUT, ActionResult.NO_SYSTEM, ActionResult.CONNECTION_ERROR)

_log = logging.getLogger("uav_agent.flight")


class Flight(Readings):
    """Fly one autopilot over MAVLink: `connect`, `arm`, `takeoff`, `goto`, `land`.

    Usable as a context manager; `close()` releases MAVSDK (its sockets and threads).
    """

    def __init__(self, url: str = DEFAULT_URL):
        self.url = url
        self._config: Configuration | None = None
        self._mavsdk: Mavsdk | None = None
        self._system = None
        self._action: Action | None = None
        self._telemetry: Telemetry | None = None
        self._home: tuple[float, float, float] | None = None
        self._offboard: Offboard | None = None   # the local frame's setpoints (no home)
        self._direct: MavlinkDirect | None = None   # raw commands MAVSDK's plugins lack (ArduPilot's GUIDED)
        self._alert: tuple[float, str] = (-math.inf, "")   # (when, text) of the last warning or worse
        # Why the vehicle is no longer the mission's (a failsafe's RTL or LAND, a pilot's mode, a
        # disarm), or None: checked before every command and in every wait, so the agent never
        # commands over the autopilot's own decision and notices it within a poll in any phase.
        self.guard: Callable[[], str | None] = lambda: None
        self._silent_since: float | None = None   # when the link was first seen lost, None while it is up
        # (seconds, time.monotonic() when it came back) of the link's last loss: the guard's reason says it
        self.last_gap: tuple[float, float] | None = None

    # --- lifecycle ---------------------------------------------------------------------

    def open(self) -> "Flight":
        """Open the link and return at once: MAVSDK listens from now on. An autopilot beats once
        a second, and its beats before this are lost (UDP): open early, `connect` later."""
        if self._mavsdk is not None:
            return self
        route_mavsdk_logs()
        self._config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        self._mavsdk = Mavsdk(self._config)
        try:
            result = self._mavsdk.add_any_connection(self.url)
        except Exception as exc:  # ctypes refuses e.g. a URL that is not text
            self.close()
            raise MissionError(f"cannot open MAVLink connection {self.url!r}: {exc}") from None
        if result != ConnectionResult.SUCCESS:
            self.close()
            raise MissionError(f"cannot open MAVLink connection {self.url!r}: {result.name}")
        return self

    def connect(self, timeout_s: float = 10.0) -> "Flight":
        """Open the link (unless `open` did), wait for an autopilot, its home and its position."""
        if self._system is not None:
            return self
        _check_timeout(timeout_s)
        deadline = time.monotonic() + timeout_s
        self.open()
        system = self._mavsdk.first_autopilot(max(0.0, deadline - time.monotonic()))
        if system is None:
            self.close()
            raise MissionError(f"no autopilot at {self.url} within {timeout_s:g} s")
        self._system = system
        self._action = Action(system)
        self._telemetry = Telemetry(system)
        self._telemetry.subscribe_status_text(self._on_status_text)
        self._wake_streams()

        def home_and_position():
            home, pos = self._telemetry.home(), self._telemetry.position()
            return _finite(home.latitude_deg, home.longitude_deg, home.absolute_altitude_m,
                           pos.latitude_deg, pos.longitude_deg, pos.absolute_altitude_m)

        local_since: list[float] = []

        def indoor():
            """A local position, no GPS at all (an outdoor drone still waiting for its fix says NO_FIX) and no
            home for NO_HOME_S: nothing global will come."""
            if not _finite(*self._local()) or self._telemetry.gps_info().fix_type != FixType.NO_GPS:
                return False
            local_since[:1] = local_since[:1] or [time.monotonic()]
            return time.monotonic() - local_since[0] >= NO_HOME_S

        try:
            self._wait(lambda: home_and_position() or indoor(), deadline,
                       lambda: f"autopilot at {self.url} sent no home position and position (nor a local position) "
                               f"within {timeout_s:g} s")
            if not home_and_position():
                self._offboard = Offboard(system)
                _log.info("connected to autopilot %d at %s, no home: flying its local frame (offboard)",
                          system.get_system_id(), self.url)
                return self
            home = self._telemetry.home()
            check_home(home.latitude_deg, home.longitude_deg)
        except MissionError:
            self.close()
            raise
        self._home = (home.latitude_deg, home.longitude_deg, home.absolute_altitude_m)
        _log.info("connected to autopilot %d at %s, home %.7f %.7f %.1f m", system.get_system_id(), self.url,
                  *self._home)
        return self

    def _wake_streams(self) -> None:
        """Ask for what `connect` and the watch read, at once: ArduPilot streams nothing until asked (its SRn_
        rates at 0) and MAVSDK does not ask, so its home and position would never come. A stream the autopilot
        refuses is no error (PX4 streams them anyway; an indoor one has no global position to send)."""
        t = self._telemetry
        for call, hz in ((t.set_rate_home, 1.0), (t.set_rate_position, 10.0), (t.set_rate_position_velocity_ned, 10.0),
                         (t.set_rate_attitude_euler, 10.0), (t.set_rate_in_air, 5.0), (t.set_rate_landed_state, 5.0),
                         (t.set_rate_battery, 1.0), (t.set_rate_gps_info, 1.0)):
            try:
                call(hz)
            except Exception:  # noqa: BLE001 - MAVSDK's TelemetryError: a rate is a wish here
                pass

    @property
    def local_frame(self) -> bool:
        """Flying the autopilot's local frame (no home: indoor), in offboard."""
        return self._offboard is not None

    @property
    def own_modes(self) -> set[str]:
        """The modes the mission itself puts the vehicle in beyond HOLD, TAKEOFF and LAND."""
        return {"OFFBOARD"} if self.local_frame else set()

    def stream(self, hz: float) -> list[str]:
        """Ask the autopilot for attitude, position and velocity `hz` times a second (MAVSDK's
        set_rate_*, MAV_CMD_SET_MESSAGE_INTERVAL): the shutter waits for an attitude sample sent
        after the vehicle was seen to arrive, so each stream's period is part of every stop.
        Returns the streams the autopilot refused (it keeps its own rate for those)."""
        _, telemetry = self._link()
        refused = []
        for name, call in (("attitude", telemetry.set_rate_attitude_euler), ("position", telemetry.set_rate_position),
                           ("velocity", telemetry.set_rate_velocity_ned)):
            try:
                call(float(hz))
            except Exception as exc:  # noqa: BLE001 - MAVSDK's TelemetryError: a rate is a wish, not a need
                refused.append(f"{name}: {exc}")
        return refused

    def close(self) -> None:
        """Release MAVSDK (sockets, threads). Idempotent; `connect()` again to reuse the Flight."""
        mavsdk, self._mavsdk = self._mavsdk, None
        self._action = self._telemetry = self._system = self._offboard = self._direct = None
        if mavsdk is not None:
            mavsdk.destroy()
        config, self._config = self._config, None
        if config is not None:
            config.destroy()

    def __enter__(self) -> "Flight":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- commands ----------------------------------------------------------------------

    def arm(self, timeout_s: float = 10.0, on_wait: Callable[[str], None] | None = None) -> None:
        """Arm and wait until the heartbeat says armed. A refusal is asked again every ARM_RETRY_S until
        `timeout_s` (an autopilot whose estimator is still settling: ArduPilot SITL for about 38 s after it
        starts); `on_wait` hears the first refusal and the autopilot's words for it."""
        _check_timeout(timeout_s)
        deadline = time.monotonic() + timeout_s
        action, telemetry = self._link()
        if telemetry.armed():
            return
        told: list[str] = []

        def retry(exc: MissionError) -> None:
            why = f"{exc}" + (f" ({self.status_text})" if self.status_text else "")
            # Waiting cures an estimator that settles, never a battery (nor ArduPilot's battery settings)
            if "refused" not in str(exc) or "battery" in why.lower() or time.monotonic() + ARM_RETRY_S >= deadline:
                raise MissionError(why) from None
            if on_wait is not None and not told:
                on_wait(why)
                told.append(why)
            time.sleep(ARM_RETRY_S)

        while self.autopilot == "ARDUPILOT" and self.flight_mode != "OFFBOARD":
            try:
                self._guided()
            except MissionError as exc:
                retry(exc)
        while True:
            try:
                self._act("arm", action.arm)
                break
            except MissionError as exc:
                retry(exc)
        self._wait(telemetry.armed, deadline, lambda: f"vehicle did not report armed within {timeout_s:g} s")

    def _guided(self) -> None:
        """ArduCopter is flown in GUIDED, and armed in it: armed in the mode it sits in after a landing
        (LAND), MAVSDK would first ask for its HOLD, which is Copter's BRAKE and cannot arm; armed in
        STABILIZE, it would disarm again before the take-off. GUIDED needs a position: Copter refuses it
        until its estimator uses the GPS (SITL: about 38 s after it starts), so the caller asks again.
        MAVSDK names GUIDED OFFBOARD."""
        self._check_guard()
        fields = {"target_system": self._system.get_system_id(), "target_component": 1,
                  "command": MAV_CMD_DO_SET_MODE, "confirmation": 0, "param1": CUSTOM_MODE_ENABLED,
                  "param2": COPTER_GUIDED, "param3": 0, "param4": 0, "param5": 0, "param6": 0, "param7": 0}
        message = MavlinkMessage("COMMAND_LONG", 0, 0, fields["target_system"], 1, json.dumps(fields))
        try:
            self._direct = self._direct or MavlinkDirect(self._system)
            self._direct.send_message(message)
        except Exception as exc:  # noqa: BLE001 - MavlinkDirectError: the link is gone
            raise MissionError(f"could not ask the vehicle for GUIDED: {exc}") from None
        self._wait(lambda: self.flight_mode == "OFFBOARD", time.monotonic() + ARM_RETRY_S,
                   lambda: "vehicle refused GUIDED")

    def takeoff(self, alt_m: float, timeout_s: float = 60.0) -> None:
        """Arm if needed, take off to `alt_m` above home, wait until in the air near it."""
        _check_timeout(timeout_s)
        if not (math.isfinite(alt_m) and alt_m > 0):
            raise MissionError(f"takeoff altitude must be a positive number of metres, got {alt_m}")
        deadline = time.monotonic() + timeout_s
        action, telemetry = self._link()
        self._act(f"set takeoff altitude {alt_m:g} m", lambda: action.set_takeoff_altitude(float(alt_m)))
        if not telemetry.armed():
            self.arm(max(0.1, deadline - time.monotonic()))
        self._act("take off", action.takeoff)
        tolerance = max(0.3, 0.03 * alt_m)

        def up():
            return telemetry.in_air() and abs(self._altitude() - alt_m) <= tolerance

        self._wait(up, deadline,
                   lambda: f"vehicle did not reach {alt_m:g} m within {timeout_s:g} s (at {self._altitude():.1f} m)")

    def set_speed(self, m_s: float) -> None:
        """Ask for a horizontal speed for the gotos that follow (MAV_CMD_DO_CHANGE_SPEED); the
        autopilot caps it at its MPC_XY_VEL_MAX."""
        if not (math.isfinite(m_s) and m_s > 0):
            raise MissionError(f"speed must be a positive number of m/s, got {m_s}")
        action, _ = self._link()
        self._act(f"set speed {m_s:g} m/s", lambda: action.set_current_speed(float(m_s)))

    def goto(self, north_m: float, east_m: float, alt_m: float, yaw_rad: float | None = 0.0,
             timeout_s: float = 120.0, tolerance_m: float = 0.5) -> tuple[float, float, float]:
        """Fly to (north, east) at `alt_m` above home, facing `yaw_rad` (None keeps the heading);
        wait until within `tolerance_m` horizontally and vertically and nearly stopped.
        Returns the reached (north, east, down)."""
        _check_timeout(timeout_s)
        deadline = time.monotonic() + timeout_s
        self.go(north_m, east_m, alt_m, yaw_rad, tolerance_m)

        def error() -> tuple[float, float]:
            n, e, d = self.position_ned()
            return math.hypot(n - north_m, e - east_m), abs(-d - alt_m)

        self._wait(lambda: self.settled_at(north_m, east_m, alt_m, tolerance_m), deadline, lambda: (
            f"vehicle did not reach N {north_m:.1f} E {east_m:.1f} at {alt_m:.1f} m within {timeout_s:g} s"
            f" (still {error()[0]:.1f} m away horizontally, {error()[1]:.1f} m vertically)"))
        return self.position_ned()

    def go(self, north_m: float, east_m: float, alt_m: float, yaw_rad: float | None = 0.0,
           tolerance_m: float = 0.5) -> None:
        """Send the vehicle towards (north, east) at `alt_m` above home and return at once
        (`settled_at` tells when it is there): for flying while something else goes on."""
        yaw_deg = math.nan if yaw_rad is None else math.degrees(yaw_rad)  # NaN: MAVLink's "keep current"
        if not all(math.isfinite(v) for v in (north_m, east_m, alt_m, tolerance_m)) or tolerance_m <= 0 or (
                yaw_rad is not None and not math.isfinite(yaw_rad)):
            raise MissionError(f"goto target ({north_m}, {east_m}, {alt_m} m, yaw {yaw_rad}, tolerance {tolerance_m})"
                               " must be finite numbers with a positive tolerance")
        action, _ = self._link()
        what = f"go to N {north_m:.1f} E {east_m:.1f} at {alt_m:.1f} m"
        if self._offboard is not None:
            self._go_local(what, north_m, east_m, alt_m, yaw_deg)
            return
        home_lat, home_lon, home_alt = self._home
        lat, lon = ned_to_geo(north_m, east_m, home_lat, home_lon)
        self._act(what, lambda: action.goto_location(lat, lon, home_alt + alt_m, yaw_deg))

    def _go_local(self, what: str, north_m: float, east_m: float, alt_m: float, yaw_deg: float) -> None:
        """A position setpoint in the local frame; offboard is entered with the first (PX4 wants a setpoint
        stream before it switches; MAVSDK keeps sending the last one at 20 Hz)."""
        offboard = self._offboard
        if not math.isfinite(yaw_deg):
            yaw_deg = math.degrees(self.pose()[3])
        self._check_guard()
        try:
            offboard.set_position_ned(PositionNedYaw(float(north_m), float(east_m), float(-alt_m), float(yaw_deg)))
        except OffboardError as exc:
            raise MissionError(f"vehicle refused to {what} in offboard: {exc.args[0].name}") from None
        # The mode the autopilot reports, not MAVSDK's own flag (it says active after a refused start): after a
        # take-off or a hold the vehicle is out of offboard again. PX4 switches only once the setpoints stream.
        deadline = time.monotonic() + OFFBOARD_START_S
        while self.flight_mode != "OFFBOARD":
            self._check_guard()
            try:
                offboard.start()
            except OffboardError as exc:
                if time.monotonic() >= deadline:
                    raise MissionError(f"vehicle refused to {what} in offboard: {exc.args[0].name}") from None
                time.sleep(0.1)
                continue
            self._wait(lambda: self.flight_mode == "OFFBOARD", deadline,
                       lambda: f"vehicle did not enter offboard to {what} within {OFFBOARD_START_S:g} s")

    def settled_at(self, north_m: float, east_m: float, alt_m: float, tolerance_m: float = 0.5) -> bool:
        """Within `tolerance_m` of the point horizontally and vertically, and stopped, not just
        passing through: the camera should see a still pose."""
        n, e, d = self.position_ned()
        if math.hypot(n - north_m, e - east_m) > tolerance_m or abs(-d - alt_m) > tolerance_m:
            return False
        # Indoors the velocity is LOCAL_POSITION_NED's (MAVSDK's velocity_ned is GLOBAL_POSITION_INT's).
        v = self._telemetry.position_velocity_ned().velocity if self.local_frame else self._telemetry.velocity_ned()
        return math.hypot(v.north_m_s, v.east_m_s, v.down_m_s) <= SETTLED_M_S

    def land(self, timeout_s: float = 120.0) -> None:
        """Land where it is; wait until on the ground and disarmed."""
        _check_timeout(timeout_s)
        deadline = time.monotonic() + timeout_s
        action, telemetry = self._link()
        self._act("land", action.land)

        self._wait(lambda: self.landed, deadline, lambda: (f"vehicle did not land and disarm within {timeout_s:g} s"
                                            f" (at {self._altitude():.1f} m, {telemetry.landed_state().name})"))

    # --- helpers -----------------------------------------------------------------------

    def _act(self, what: str, call: Callable[[], object]) -> None:
        """Send a command; one the link swallowed is sent again for up to LINK_LOSS_S (a link lost for
        longer before it, at once: the mission has given up on it)."""
        first = None
        while True:
            self._check_guard()
            try:
                call()
                return
            except ActionError as exc:
                if exc.result not in LINK_LOST:
                    self._refused(what, exc.result.name)
                now = time.monotonic()
                first = now if first is None else first
                if now - first >= LINK_LOSS_S or self._silent_s() >= LINK_LOSS_S:
                    raise MissionError(f"vehicle did not answer the request to {what} ({exc.result.name})") from None
            time.sleep(LINK_RETRY_S)

    def link_lost_for(self, recent_s: float) -> float:
        """Seconds the link is lost now, or was lost last if it came back within `recent_s`; else 0.
        Kept up to date by whoever asks (the watch, every wait)."""
        now = self._silent_s()
        if now > 0:
            return now + MAVSDK_SILENT_S
        gap = self.last_gap
        return gap[0] if gap is not None and time.monotonic() - gap[1] < recent_s else 0.0

    def _stale(self) -> bool:
        """True while the link is silent, and for FRESH_S after it came back: what MAVSDK holds then is
        from before the loss (an altitude the vehicle has left while its failsafe took it home)."""
        gap = self.last_gap
        return self._silent_s() > 0 or (gap is not None and time.monotonic() - gap[1] < FRESH_S)

    def _silent_s(self) -> float:
        now = time.monotonic()
        if self._system is None or self._system.is_connected():
            since, self._silent_since = self._silent_since, None
            if since is not None:
                self.last_gap = (now - since + MAVSDK_SILENT_S, now)
            return 0.0
        if self._silent_since is None:
            self._silent_since = now
        return now - self._silent_since

    def _refused(self, what: str, result: str) -> None:
        """A refusal is often the autopilot's own decision taken a moment before (a failsafe's RTL denies the
        next goto): the guard's reason, if it names one within REFUSAL_GRACE_S, is the mission's; else the refusal."""
        deadline = time.monotonic() + REFUSAL_GRACE_S
        while time.monotonic() < deadline:
            why = self.guard()
            if why:
                raise MissionError(f"vehicle: {why}")
            time.sleep(POLL_S)
        raise MissionError(f"vehicle refused to {what}: {result}")

    def _check_guard(self) -> None:
        why = self.guard()
        if why:
            raise MissionError(f"vehicle: {why}")

    def _wait(self, done: Callable[[], bool], deadline: float, failure: Callable[[], str]) -> None:
        """Poll `done` until true; MissionError(failure()) at the deadline, on link loss, or as soon as
        the guard says the vehicle is not the mission's any more."""
        while True:
            self._check_guard()
            if not self._stale() and done():
                return
            if self._silent_s() >= LINK_LOSS_S:   # a shorter silence is waited out (the deadline still holds)
                raise MissionError(f"lost the autopilot link at {self.url}: nothing from it for {LINK_LOSS_S:g} s "
                                   "(its own datalink-loss failsafe has the vehicle)")
            if time.monotonic() >= deadline:
                raise MissionError(failure())
            time.sleep(POLL_S)


def _check_timeout(timeout_s: float) -> None:
    if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and timeout_s > 0):
        raise MissionError(f"timeout must be a positive number of seconds, got {timeout_s!r}")


def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)
