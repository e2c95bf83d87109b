"""What the autopilot says, as `Flight` reads it from MAVSDK's telemetry: its position in the
mission's frame, attitude, battery, arming, mode and last warning. A part of `Flight`, on its link."""
from __future__ import annotations

import math
import time

from mavsdk.plugins.action import Action
from mavsdk.plugins.telemetry import LandedState, StatusTextType, Telemetry

from protocol.errors import MissionError
from protocol.geo import geo_to_ned

# The autopilot's words worth quoting: a warning or worse, said this recently (ArduPilot says a lot at INFO,
# "EKF3 IMU0 MAG0 in-flight yaw alignment complete", which would otherwise be quoted as an RTL's reason).
ALERT_S = 15.0


class Readings:
    """The autopilot's telemetry, read: mixed into `Flight`, whose link (`_action`, `_telemetry`,
    `_system`, `_home`, `_offboard`, `_alert`) it reads."""

    def home(self) -> tuple[float, float, float]:
        """(latitude, longitude, altitude AMSL m) of the frame's origin, as read at connect."""
        self._link()
        return self._home

    def position_ned(self) -> tuple[float, float, float]:
        """(north, east, down) metres from home."""
        _, telemetry = self._link()
        if self._offboard is not None:
            return self._local()
        pos = telemetry.position()
        home_lat, home_lon, home_alt = self._home
        north, east = geo_to_ned(pos.latitude_deg, pos.longitude_deg, home_lat, home_lon)
        return north, east, home_alt - pos.absolute_altitude_m

    def pose(self) -> tuple[float, float, float, float]:
        """(north, east, down, yaw_rad), the same tuple `sim_world.vehicle.Vehicle.pose` gives."""
        _, telemetry = self._link()
        yaw = math.radians(telemetry.attitude_euler().yaw_deg)
        return (*self.position_ned(), yaw if math.isfinite(yaw) else 0.0)

    def attitude_rad(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in radians; 0 for an angle the autopilot has not sent."""
        return self.attitude_sample()[:3]

    def attitude_sample(self) -> tuple[float, float, float, int]:
        """(roll, pitch, yaw) in radians and the autopilot's time of the sample (microseconds since
        its boot; 0 if it sends none): a new time is a sample sent after the one read before."""
        _, telemetry = self._link()
        e = telemetry.attitude_euler()
        angles = tuple(math.radians(v) if math.isfinite(v) else 0.0 for v in (e.roll_deg, e.pitch_deg, e.yaw_deg))
        return (*angles, int(e.timestamp_us))

    @property
    def battery_pct(self) -> float:
        """Remaining charge 0-100, or -1 when the autopilot has not said."""
        pct = self._link()[1].battery().remaining_percent
        return min(100.0, max(0.0, pct)) if math.isfinite(pct) else -1.0

    @property
    def battery_time_left_s(self) -> float | None:
        """The autopilot's own estimate of the flight time its pack has left at the current draw (its
        seconds: BATTERY_STATUS.time_remaining), or None when it gives none."""
        t = self._link()[1].battery().time_remaining_s
        return float(t) if t is not None and math.isfinite(t) and t > 0 else None

    @property
    def armed(self) -> bool:
        return self._link()[1].armed()

    @property
    def in_air(self) -> bool:
        return self._link()[1].in_air()

    @property
    def flight_mode(self) -> str:
        """The autopilot's mode as MAVSDK names it: HOLD, TAKEOFF, LAND, OFFBOARD, ..."""
        return self._link()[1].flight_mode().name

    @property
    def autopilot(self) -> str:
        """PX4, ARDUPILOT, GENERIC or UNKNOWN, from the autopilot's heartbeat: modes mean different
        things (MAVSDK names ArduCopter's GUIDED, the mode a companion flies it in, OFFBOARD)."""
        return self._system.autopilot_type().name if self._system is not None else "UNKNOWN"

    @property
    def status_text(self) -> str:
        """The autopilot's last warning or worse of the last ALERT_S ('' if none): a failsafe says why it
        took the vehicle, a refused arm why it refused."""
        when, text = self._alert
        return text if time.monotonic() - when <= ALERT_S else ""

    def _on_status_text(self, status, _user_data) -> None:   # MAVSDK's thread
        if status.type.value >= StatusTextType.WARNING.value and status.text:
            self._alert = (time.monotonic(), str(status.text))

    @property
    def landed(self) -> bool:
        """On the ground and disarmed, as the autopilot says."""
        _, telemetry = self._link()
        return telemetry.landed_state() == LandedState.ON_GROUND and not telemetry.armed()

    def _link(self) -> tuple[Action, Telemetry]:
        if self._action is None or self._telemetry is None:
            raise MissionError(f"not connected to an autopilot at {self.url} (call connect() first)")
        return self._action, self._telemetry

    def _altitude(self) -> float:
        if self._offboard is not None:
            return -self._local()[2]
        return self._telemetry.position().relative_altitude_m

    def _local(self) -> tuple[float, float, float]:
        p = self._telemetry.position_velocity_ned().position
        return p.north_m, p.east_m, p.down_m
