"""An autopilot's pose as its telemetry tells it, in the floor's frame: pure parts of the pose
follower (sim_world/pose_follower.py), no I/O.

- `BootClock`: the local instant of each reading of the autopilot's own clock (time_boot_ms);
- `FloorFrame`: where the autopilot's local NED frame lies on the floor, pinned once;
- `Track`: a short time-stamped history, and the pose at any recent instant (interpolated);
- `Truth`: what the autopilot showed of itself (armed, landed state, altitude, a crash, its texts),
  the record a world with a vehicle of its own keeps (`Record.truth["vehicle"]`).
"""
from __future__ import annotations

import bisect
import math
from collections import deque
from typing import NamedTuple

from protocol.geo import geo_to_ned

Vec3 = tuple[float, float, float]

# A sample's local instant is its autopilot clock reading plus the smallest (arrival - reading) of
# this window: the link's delay floor, so a sample read late by a busy process keeps its instant.
CLOCK_WINDOW_S = 0.5
KEEP_S = 10.0               # history kept: an image's shutter is never older than this
MAX_EXTRAPOLATION_S = 0.5   # past the last sample, the position goes on at its velocity this long at most
# A touchdown faster than this is a crash, as the simulated vehicle's own land detector says
# (sim_world/vehicle/dynamics.py: HARD_TOUCHDOWN_M_S).
HARD_TOUCHDOWN_M_S = 3.0
NEAR_GROUND_M = 0.5


class Pose(NamedTuple):
    """The vehicle's pose and velocity in the floor's NED frame (metres, radians, m/s)."""
    north_m: float
    east_m: float
    down_m: float
    yaw_rad: float = 0.0
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    vel_north: float = 0.0
    vel_east: float = 0.0
    vel_down: float = 0.0


class BootClock:
    """Maps the autopilot's clock (seconds since its boot) to this machine's monotonic clock.

    An autopilot clock that runs faster than ours (a SITL sped up) makes the newest arrival the
    floor every time: the instants become arrival times, no worse than stamping on arrival."""

    def __init__(self, window_s: float = CLOCK_WINDOW_S) -> None:
        self.window_s = window_s
        self._seen: deque[tuple[float, float]] = deque()   # (arrival, arrival - boot)
        self._last_boot = -math.inf

    def local(self, boot_s: float, arrival: float) -> float:
        if boot_s < self._last_boot - 1.0:   # the autopilot rebooted: its clock starts again
            self._seen.clear()
        self._last_boot = boot_s
        self._seen.append((arrival, arrival - boot_s))
        while self._seen[0][0] < arrival - self.window_s:
            self._seen.popleft()
        return boot_s + min(d for _, d in self._seen)

    def boot_at(self, local: float) -> float | None:
        """The autopilot's clock at the local instant `local`, once it was read."""
        if not self._seen:
            return None
        return local - min(d for _, d in self._seen)


class FloorFrame:
    """The floor's NED frame (origin at the grid's top-left corner, on the floor) against the
    autopilot's local NED frame.

    `origin` given: the autopilot's local origin lies there on the floor (an indoor autopilot
    without GPS or home). Otherwise the autopilot's first home is the floor's corner, as the UAV
    agent takes it (its mission frame is the home it first reads): pinned then, so a home moved
    later (ArduPilot's where it arms) does not move the floor. HOME_POSITION gives home both in
    the local frame (x, y, z) and on the globe, hence the local frame's own place."""

    def __init__(self, origin: Vec3 | None = None) -> None:
        self.offset: Vec3 | None = origin            # floor = local + offset
        self.home: tuple[float, float, float, float, float, float] | None = None   # the latest home

    @property
    def known(self) -> bool:
        return self.offset is not None

    def on_home(self, lat: float, lon: float, alt_m: float, x: float, y: float, z: float) -> bool:
        """A HOME_POSITION; True when it pinned the frame."""
        values = (lat, lon, alt_m, x, y, z)
        if not all(map(math.isfinite, values)) or abs(lat) > 89.0:
            return False
        self.home = values
        if self.offset is None:
            self.offset = (-x, -y, -z)
            return True
        return False

    def from_local(self, pos: Vec3) -> Vec3 | None:
        if self.offset is None:
            return None
        return pos[0] + self.offset[0], pos[1] + self.offset[1], pos[2] + self.offset[2]

    def from_global(self, lat: float, lon: float, alt_m: float) -> Vec3 | None:
        """A geodetic position (GLOBAL_POSITION_INT's, AMSL) on the floor: by the latest home, whose
        local and global positions are one point."""
        if self.home is None or self.offset is None:
            return None
        h_lat, h_lon, h_alt, x, y, z = self.home
        n, e = geo_to_ned(lat, lon, h_lat, h_lon)
        return self.from_local((x + n, y + e, z - (alt_m - h_alt)))


def _lerp(a: float, b: float, f: float) -> float:
    return a + (b - a) * f


def _lerp_angle(a: float, b: float, f: float) -> float:
    d = (b - a + math.pi) % (2 * math.pi) - math.pi
    return (a + d * f + math.pi) % (2 * math.pi) - math.pi


class Track:
    """Position (with velocity) and attitude samples, each at its local instant; `at(t)` is the
    pose then: interpolated between the samples around t, the position carried on at its velocity
    (at most MAX_EXTRAPOLATION_S) past the last, the attitude held."""

    def __init__(self, keep_s: float = KEEP_S) -> None:
        self.keep_s = keep_s
        self._pt: list[float] = []
        self._pv: list[tuple[float, ...]] = []    # north, east, down, vn, ve, vd
        self._at: list[float] = []
        self._av: list[tuple[float, float, float]] = []   # roll, pitch, yaw

    def add_position(self, t: float, pos: Vec3, vel: Vec3) -> None:
        self._add(self._pt, self._pv, t, (*pos, *vel))

    def add_attitude(self, t: float, roll: float, pitch: float, yaw: float) -> None:
        self._add(self._at, self._av, t, (roll, pitch, yaw))

    def _add(self, times: list[float], values: list, t: float, value: tuple) -> None:
        if times and t < times[-1]:      # out of order (a reboot, a reordering link): history restarts
            times.clear()
            values.clear()
        times.append(t)
        values.append(value)
        if times[0] < t - 2 * self.keep_s:   # trimmed in bulk, not at every sample
            cut = bisect.bisect_left(times, t - self.keep_s)
            del times[:cut], values[:cut]

    @property
    def last_position_t(self) -> float | None:
        return self._pt[-1] if self._pt else None

    @property
    def last_attitude_t(self) -> float | None:
        return self._at[-1] if self._at else None

    def at(self, t: float) -> Pose | None:
        if not self._pt:
            return None
        n, e, d, vn, ve, vd = self._position(t)
        roll, pitch, yaw = self._attitude(t) if self._at else (0.0, 0.0, 0.0)
        return Pose(n, e, d, yaw, roll, pitch, vn, ve, vd)

    def _position(self, t: float) -> tuple[float, ...]:
        times, values = self._pt, self._pv
        i = bisect.bisect_right(times, t)
        if i == 0:
            return values[0]
        if i == len(times):
            n, e, d, vn, ve, vd = values[-1]
            dt = min(t - times[-1], MAX_EXTRAPOLATION_S)
            return n + vn * dt, e + ve * dt, d + vd * dt, vn, ve, vd
        t0, t1 = times[i - 1], times[i]
        f = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        return tuple(_lerp(a, b, f) for a, b in zip(values[i - 1], values[i]))

    def _attitude(self, t: float) -> tuple[float, float, float]:
        times, values = self._at, self._av
        i = bisect.bisect_right(times, t)
        if i == 0:
            return values[0]
        if i == len(times):
            return values[-1]
        t0, t1 = times[i - 1], times[i]
        f = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        (r0, p0, y0), (r1, p1, y1) = values[i - 1], values[i]
        return _lerp(r0, r1, f), _lerp(p0, p1, f), _lerp_angle(y0, y1, f)


def euler_of_quaternion(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) of ATTITUDE_QUATERNION's body-to-NED quaternion (ZYX order, as ATTITUDE)."""
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


LANDED_STATES = {0: "UNDEFINED", 1: "ON_GROUND", 2: "IN_AIR", 3: "TAKING_OFF", 4: "LANDING"}


class Truth:
    """What the autopilot showed of itself: armed, landed state, the highest altitude, a touchdown
    too fast to be a landing, its own texts. Event times are the autopilot's clock (s since boot)."""

    def __init__(self) -> None:
        self.armed = False
        self.landed_state: str | None = None
        self.max_altitude_m = 0.0
        self.events: list[tuple[float, str]] = []
        self._fall: tuple[float, float] | None = None   # (altitude, down speed) of the last sample
        self._text: dict[int, list[str]] = {}

    def on_armed(self, armed: bool, t: float) -> None:
        if armed != self.armed:
            self.armed = armed
            self.events.append((t, "armed" if armed else "disarmed"))

    def on_landed_state(self, state: int, t: float) -> None:
        name = LANDED_STATES.get(state, "UNDEFINED")
        if name != self.landed_state:
            if self.landed_state is not None:
                self.events.append((t, f"landed state {name}"))
            self.landed_state = name

    def on_position(self, altitude_m: float, down_speed: float, t: float) -> None:
        self.max_altitude_m = max(self.max_altitude_m, altitude_m)
        fall = self._fall
        if (fall is not None and fall[1] > HARD_TOUCHDOWN_M_S and altitude_m < NEAR_GROUND_M
                and down_speed < fall[1] / 2):
            # The telemetry's last speed before the stop: the impact's, or less.
            self.events.append((t, f"hit the ground at {fall[1]:.1f} m/s (a crash: over {HARD_TOUCHDOWN_M_S:g} m/s)"))
        self._fall = (altitude_m, down_speed)

    def on_text(self, severity: int, text: str, ident: int, chunk: int, t: float) -> None:
        """A STATUSTEXT; a long one comes in 50-byte chunks of one id, the last one shorter."""
        if not ident:
            self.events.append((t, text))
            return
        parts = self._text.setdefault(ident, [])
        if chunk == len(parts):
            parts.append(text)
        if len(text.encode()) < 50 or len(parts) > 20:
            self.events.append((t, "".join(self._text.pop(ident))))

    def landed_name(self) -> str:
        """The landed state it reported; without EXTENDED_SYS_STATE, what its arming and altitude say."""
        if self.landed_state is not None:
            return self.landed_state
        if self._fall is None:
            return "UNDEFINED"
        return "ON_GROUND" if not self.armed and self._fall[0] < NEAR_GROUND_M else "IN_AIR"
