"""How a simulated vehicle is reached and how it flies."""
from __future__ import annotations

import ipaddress
import math
from dataclasses import dataclass

from protocol.errors import MissionError
from protocol.geo import check_home


# A run's hover wobble when it names none: the realistic camera's drone rolls gently in a hover (a
# camera fixed to its body sees it), the ideal one holds still.
WOBBLE_OF_CAMERA_PRESET = {"ideal": 0.0, "realistic": 0.3}

@dataclass(frozen=True)
class VehicleConfig:
    """How the simulated vehicle is reached and how it flies.

    `url` is a pymavlink connection string: `udpout:host:port` sends to a ground
    station listening there (like PX4 SITL's offboard link on 14540),
    `udpin:host:port` listens and answers whoever sends valid MAVLink to it
    (port 0 picks a free port; see `Vehicle.local_address`).

    `gcs_url` opens a second link for a ground station (QGroundControl, MAVProxy), signed
    with MAVLink 2 `signing_key` (32 bytes) if given: unsigned frames are refused there.
    Every socket is bound to `bind_host`, loopback unless the operator opens it on purpose.

    The flight link (`url`) answers its companion only: the system `companion_system_id`, or
    (None) the first system that sends valid MAVLink there, at the address it sent from; a
    stranger's frames are refused and counted (see `link.py`).

    `gps` False is an indoor vehicle: a local frame only (no global position, no home from
    GPS). `position_noise_m`, `position_bias_m` and `attitude_noise_deg` make the telemetry an
    estimate (see `estimator.py`); 0, the default, reports the truth.
    """

    url: str = "udpout:127.0.0.1:14540"
    system_id: int = 1
    home_lat: float = 47.397742  # PX4 SITL's default home (Zurich)
    home_lon: float = 8.545594
    home_alt_m: float = 488.0  # AMSL
    # A survey airframe: PX4's MPC_XY_VEL_MAX at its upper bound; it flies at the cruise speed
    # until DO_CHANGE_SPEED (MAVSDK's set_current_speed) asks for more.
    max_speed_m_s: float = 20.0
    cruise_speed_m_s: float = 12.0
    max_climb_m_s: float = 3.0
    time_scale: float = 1.0
    takeoff_alt_m: float = 2.5  # MIS_TAKEOFF_ALT: PX4's default, the lowest takeoff altitude
    max_alt_m: float = 120.0
    land_speed_m_s: float = 0.7  # MPC_LAND_SPEED, used for the last metres of a landing
    disarm_after_land_s: float = 2.0  # COM_DISARM_LAND, simulated seconds
    gcs_url: str | None = None
    signing_key: bytes | None = None
    # A third link for a reader of the pose (the world's camera follows the vehicle there), like PX4
    # SITL's onboard link: unsigned, and the ground station's link stays the operator's.
    pose_url: str | None = None
    bind_host: str = "127.0.0.1"
    hover_wobble_deg: float = 0.0  # amplitude of the roll/pitch wobble in the air (see dynamics.Wobble)
    heading_deg: float = 0.0       # where the vehicle faces when it boots (a drone set down any way round)
    # Streams nothing but its heartbeat until asked (SET_MESSAGE_INTERVAL), as ArduPilot with its SRn_ rates at 0
    streams_until_asked: bool = False
    # Arming is refused this many simulated seconds after boot (an estimator settling; ArduPilot SITL takes ~38 s)
    ready_after_s: float = 0.0
    seed: int = 0                  # of the wobble and the estimator's noise
    # MPC_ACC_HOR / MPC_ACC_UP_MAX / MPC_ACC_DOWN_MAX / MPC_JERK_AUTO (see motion.step_limited)
    max_accel_m_s2: float = 5.0
    max_accel_up_m_s2: float = 4.0
    max_accel_down_m_s2: float = 3.0
    jerk_m_s3: float = 8.0
    companion_system_id: int | None = None
    gps: bool = True
    position_noise_m: float = 0.0     # white noise (1 sigma) on the reported position
    position_bias_m: float = 0.0      # the reported position's slowly wandering error (1 sigma)
    attitude_noise_deg: float = 0.0   # white noise (1 sigma) on the reported roll, pitch and yaw
    # The fault `battery:PCT@SECONDS` (protocol/faults.py): (fraction left, simulated seconds in the air).
    battery_drop: tuple[float, float] | None = None
    # The fault `mavlink-loss:SECONDS+DURATION`: (simulated seconds after liftoff, simulated seconds down).
    link_loss: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        check_home(self.home_lat, self.home_lon)
        if not 1 <= self.system_id <= 255:
            raise MissionError(f"vehicle system id {self.system_id} is outside 1..255")
        for name in ("max_speed_m_s", "cruise_speed_m_s", "max_climb_m_s", "time_scale", "takeoff_alt_m", "max_alt_m",
                     "land_speed_m_s", "max_accel_m_s2", "max_accel_up_m_s2", "max_accel_down_m_s2", "jerk_m_s3"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise MissionError(f"vehicle {name} must be a positive number, got {value}")
        if not (math.isfinite(self.home_alt_m) and math.isfinite(self.disarm_after_land_s)
                and self.disarm_after_land_s >= 0):
            raise MissionError("vehicle home_alt_m and disarm_after_land_s must be finite (the latter >= 0)")
        if not (math.isfinite(self.ready_after_s) and 0 <= self.ready_after_s <= 3600):
            raise MissionError(f"vehicle ready_after_s must be in [0, 3600], got {self.ready_after_s}")
        if self.battery_drop is not None and not (0 <= self.battery_drop[0] <= 1 and self.battery_drop[1] >= 0):
            raise MissionError(f"vehicle battery_drop must be (a fraction in [0, 1], seconds >= 0), got "
                               f"{self.battery_drop}")
        if self.link_loss is not None and not (self.link_loss[0] >= 0 and self.link_loss[1] > 0):
            raise MissionError(f"vehicle link_loss must be (seconds >= 0, a duration > 0), got {self.link_loss}")
        if not (math.isfinite(self.heading_deg) and -360 <= self.heading_deg <= 360):
            raise MissionError(f"vehicle heading_deg must be in [-360, 360], got {self.heading_deg}")
        if not (math.isfinite(self.hover_wobble_deg) and 0 <= self.hover_wobble_deg <= 30):
            raise MissionError(f"vehicle hover_wobble_deg must be in [0, 30], got {self.hover_wobble_deg}")
        for name, top in (("position_noise_m", 100.0), ("position_bias_m", 100.0), ("attitude_noise_deg", 30.0)):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0 <= value <= top):
                raise MissionError(f"vehicle {name} must be in [0, {top:g}], got {value}")
        if self.companion_system_id is not None and not 1 <= self.companion_system_id <= 255:
            raise MissionError(f"vehicle companion system id {self.companion_system_id} is outside 1..255")
        if self.takeoff_alt_m > self.max_alt_m:
            raise MissionError(f"vehicle takeoff_alt_m {self.takeoff_alt_m} is above max_alt_m {self.max_alt_m}")
        if self.signing_key is not None and (self.gcs_url is None or len(self.signing_key) != 32):
            raise MissionError("a MAVLink signing key must be 32 bytes and needs a ground-station link (gcs_url)")
        for url in filter(None, (self.url, self.gcs_url, self.pose_url)):
            check_exposure(url, self.bind_host)


# Named sets of the options above; a preset's values are defaults that explicit options override.
PRESETS: dict[str, dict] = {
    "outdoor": {},  # PX4 SITL as it comes: GPS, telemetry as the truth
    "indoor": {"gps": False},  # no GPS: a local frame only, as PX4 with vision or optical flow
}


def preset(name: str, **options) -> VehicleConfig:
    """A configuration from preset `name` (see PRESETS), `options` overriding it."""
    if name not in PRESETS:
        raise MissionError(f"unknown vehicle preset {name!r}; known: {', '.join(PRESETS)}")
    return VehicleConfig(**{**PRESETS[name], **options})


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_exposure(url: str, bind_host: str) -> None:
    """Refuse a link that would take commands from other hosts (or reach them) while the
    vehicle is bound to loopback: opening it must be said with `bind_host`."""
    kind, _, rest = url.partition(":")
    host = rest.rpartition(":")[0]
    if kind not in ("udpin", "udp", "udpout", "tcpin", "tcp") or not host:
        return  # pymavlink names the problem when the link is opened
    if _is_loopback(bind_host) and not _is_loopback(host):
        listening = kind in ("udpin", "udp", "tcpin")
        what = "would accept commands from any host that reaches it" if listening else "is not on this machine"
        raise MissionError(f"MAVLink link {url!r} {what}, but the vehicle is bound to loopback "
                           f"({bind_host}); open it deliberately with --mavlink-bind {host if listening else '0.0.0.0'}")


def read_signing_key(path: str) -> bytes:
    """A MAVLink 2 signing key from `path`: 32 raw bytes, or 64 hex digits (as `openssl rand -hex 32` writes)."""
    try:
        with open(path, "rb") as f:
            data = f.read(4096)
    except OSError as exc:
        raise MissionError(f"--mavlink-key {path}: {exc.strerror or exc}") from None
    if len(data) == 32:
        return data
    try:
        key = bytes.fromhex(data.decode("ascii").strip())
    except (UnicodeDecodeError, ValueError):
        key = b""
    if len(key) != 32:
        raise MissionError(f"--mavlink-key {path}: not a 32-byte key (32 raw bytes or 64 hex digits), "
                           f"got {len(data)} bytes")
    return key
