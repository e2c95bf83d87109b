"""A PX4-SITL-like multicopter autopilot, speaking MAVLink 2 through pymavlink.

No real PX4 or ArduPilot SITL can be installed here, so this is the vehicle MAVSDK,
MAVProxy and pymavlink clients fly. It implements what a ground station needs from
a PX4 autopilot (see /work/shared/NOTES-transports.md): heartbeats with PX4 custom
modes, the parameter protocol, REQUEST_MESSAGE / SET_MESSAGE_INTERVAL, telemetry
streams, COMMAND_ACK for every command, arm / takeoff / land / DO_REPOSITION /
DO_SET_MODE and offboard position or velocity setpoints.

The physics is kinematic: the vehicle moves straight toward its target with its
horizontal speed and climb limits; there is no attitude dynamics (the camera is
treated as gimballed, so roll and pitch are reported as zero). `time_scale`
simulated seconds pass per wall second, so a demo need not wait for real flight;
the link (heartbeats, telemetry rates, the offboard setpoint timeout) runs on wall
time, since that is what the ground station's own timeouts use.

Frames: local NED with the origin at home (the warehouse grid's top-left corner, at
ground level; see protocol/geo.py). Altitude is positive up from home; `down` is
its negative.
"""
from __future__ import annotations

import enum
import math
import select
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import MissionError
from protocol.geo import check_home, geo_to_ned, ned_to_geo

MAV_COMP_ID_AUTOPILOT1 = 1
FORCE_MAGIC = 21196  # param2 of MAV_CMD_COMPONENT_ARM_DISARM that overrides safety checks
INT32_MAX = 2**31 - 1
GROUND_EPS_M = 0.01  # at or below this altitude the vehicle touches the ground
LIFTOFF_ALT_M = 0.1  # above this altitude the land detector calls it airborne
TAKEOFF_DONE_M = 0.1  # takeoff ends within this distance of the takeoff altitude
LAND_SLOW_ALT_M = 2.0  # below this altitude a landing descends at the land speed
YAW_RATE_RAD_S = math.radians(90.0)
GRAVITY_M_S2 = 9.81
TERMINAL_SPEED_M_S = 20.0
OFFBOARD_LOSS_S = 1.0  # PX4's COM_OF_LOSS_T: no setpoint for this long -> hold
OFFBOARD_MIN_RATE_WINDOW_S = 1.0  # two setpoints within this window = a >= 2 Hz stream
HEARTBEAT_PERIOD_S = 1.0
MAX_STREAM_HZ = 100.0


class Mode(enum.Enum):
    """PX4 flight modes as (main mode, sub mode) of the heartbeat's custom_mode."""

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    READY = (4, 1)
    TAKEOFF = (4, 2)
    HOLD = (4, 3)  # AUTO.LOITER
    MISSION = (4, 4)
    RTL = (4, 5)
    LAND = (4, 6)
    ACRO = (5, 0)
    OFFBOARD = (6, 0)
    STABILIZED = (7, 0)

    @property
    def custom_mode(self) -> int:
        main, sub = self.value
        return (main << 16) | (sub << 24)

    @classmethod
    def from_custom_mode(cls, main: int, sub: int) -> "Mode | None":
        for mode in cls:
            if mode.value == (main, sub):
                return mode
        return None


# Modes this vehicle flies; the others need an RC or a mission, which it lacks.
FLYABLE_MODES = (Mode.HOLD, Mode.TAKEOFF, Mode.LAND, Mode.OFFBOARD)
AUTO_MODES = (Mode.READY, Mode.TAKEOFF, Mode.HOLD, Mode.MISSION, Mode.RTL, Mode.LAND)


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE values, as sent in EXTENDED_SYS_STATE."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKING_OFF = 3
    LANDING = 4


@dataclass(frozen=True)
class VehicleConfig:
    """How the simulated vehicle is reached and how it flies.

    `url` is a pymavlink connection string: `udpout:host:port` sends to a ground
    station listening there (like PX4 SITL's offboard link on 14540),
    `udpin:host:port` listens and answers whoever sends valid MAVLink to it
    (port 0 picks a free port; see `Vehicle.local_address`).
    """

    url: str = "udpout:127.0.0.1:14540"
    system_id: int = 1
    home_lat: float = 47.397742  # PX4 SITL's default home (Zurich)
    home_lon: float = 8.545594
    home_alt_m: float = 488.0  # AMSL
    max_speed_m_s: float = 12.0
    max_climb_m_s: float = 3.0
    time_scale: float = 1.0
    takeoff_alt_m: float = 10.0  # MIS_TAKEOFF_ALT
    max_alt_m: float = 120.0
    land_speed_m_s: float = 0.7  # MPC_LAND_SPEED, used for the last metres of a landing
    disarm_after_land_s: float = 2.0  # COM_DISARM_LAND, simulated seconds

    def __post_init__(self) -> None:
        check_home(self.home_lat, self.home_lon)
        if not 1 <= self.system_id <= 255:
            raise MissionError(f"vehicle system id {self.system_id} is outside 1..255")
        for name in ("max_speed_m_s", "max_climb_m_s", "time_scale", "takeoff_alt_m", "max_alt_m",
                     "land_speed_m_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise MissionError(f"vehicle {name} must be a positive number, got {value}")
        if not (math.isfinite(self.home_alt_m) and math.isfinite(self.disarm_after_land_s)
                and self.disarm_after_land_s >= 0):
            raise MissionError("vehicle home_alt_m and disarm_after_land_s must be finite (the latter >= 0)")
        if self.takeoff_alt_m > self.max_alt_m:
            raise MissionError(f"vehicle takeoff_alt_m {self.takeoff_alt_m} is above max_alt_m {self.max_alt_m}")


@dataclass
class _Param:
    value: float
    low: float
    high: float


# --- kinematics (pure) ---------------------------------------------------------------

def step_toward(pos: tuple[float, float, float], target: tuple[float, float, float], speed_xy: float,
                speed_up: float, speed_down: float, dt: float) -> tuple[float, float, float]:
    """Move `pos` toward `target` (NED) for `dt` s, capping horizontal and vertical speed
    separately, without overshooting. Returns the new position."""
    dn, de, dd = target[0] - pos[0], target[1] - pos[1], target[2] - pos[2]
    dist_xy = math.hypot(dn, de)
    reach = speed_xy * dt
    if dist_xy > reach > 0:
        dn, de = dn * reach / dist_xy, de * reach / dist_xy
    elif reach <= 0:
        dn = de = 0.0
    # down is positive: dd < 0 climbs
    dd = max(-speed_up * dt, min(speed_down * dt, dd))
    return pos[0] + dn, pos[1] + de, pos[2] + dd


def step_yaw(yaw: float, target: float, rate: float, dt: float) -> float:
    """Turn from `yaw` toward `target` (radians) at most `rate * dt`, the short way round."""
    diff = (target - yaw + math.pi) % (2 * math.pi) - math.pi
    diff = max(-rate * dt, min(rate * dt, diff))
    return (yaw + diff + math.pi) % (2 * math.pi) - math.pi


# --- the vehicle ---------------------------------------------------------------------

class Vehicle:
    """The simulated autopilot. `start()` opens the link and runs its threads; `stop()`
    ends them. All public accessors are thread-safe."""

    def __init__(self, config: VehicleConfig | None = None):
        self.config = config or VehicleConfig()
        cfg = self.config
        self._lock = threading.RLock()
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._conn = None
        self._sender = mavlink.MAVLink(_Writer(self), cfg.system_id, MAV_COMP_ID_AUTOPILOT1)
        self._parser = mavlink.MAVLink(None, 0, 0)
        self._parser.robust_parsing = True
        self._boot = time.monotonic()

        # physical state (NED, metres, m/s, radians)
        self._pos = (0.0, 0.0, 0.0)
        self._vel = (0.0, 0.0, 0.0)
        self._yaw = 0.0
        self._sim_time = 0.0
        self._airborne = False
        self._touchdown_at: float | None = None
        self._max_alt = 0.0

        # autopilot state
        self._armed = False
        self._mode = Mode.HOLD
        self._target = self._pos
        self._target_yaw = 0.0
        self._speed_xy = cfg.max_speed_m_s  # current cruise speed, DO_CHANGE_SPEED sets it
        self._offboard_times: deque[float] = deque(maxlen=2)  # wall times of the last setpoints
        self._offboard_pos: tuple[float, float, float] | None = None
        self._offboard_vel: tuple[float, float, float] | None = None
        self._offboard_yaw: float | None = None

        self._params: dict[str, _Param] = {
            "MIS_TAKEOFF_ALT": _Param(cfg.takeoff_alt_m, 0.5, cfg.max_alt_m),
            "MPC_XY_VEL_MAX": _Param(cfg.max_speed_m_s, 0.1, 100.0),
            "MPC_Z_VEL_MAX_UP": _Param(cfg.max_climb_m_s, 0.1, 50.0),
            "MPC_Z_VEL_MAX_DN": _Param(cfg.max_climb_m_s, 0.1, 50.0),
            "MPC_LAND_SPEED": _Param(cfg.land_speed_m_s, 0.1, 50.0),
            "COM_DISARM_LAND": _Param(cfg.disarm_after_land_s, 0.0, 60.0),
            "LNDMC_ALT_MAX": _Param(cfg.max_alt_m, 1.0, 10000.0),
        }

        # link bookkeeping
        self._bad_frames = 0
        self._last_warn = 0.0
        self._suppressed_warnings = 0
        self._events: list[tuple[float, str]] = []
        self._builders: dict[int, Callable[[], object]] = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self._msg_heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._msg_sys_status,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._msg_extended_sys_state,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._msg_global_position_int,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._msg_local_position_ned,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self._msg_attitude,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._msg_home_position,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self._msg_gps_raw_int,
            mavlink.MAVLINK_MSG_ID_VFR_HUD: self._msg_vfr_hud,
            mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: self._msg_gps_global_origin,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._msg_autopilot_version,
        }
        self._default_rates_hz = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0 / HEARTBEAT_PERIOD_S,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: 2.0,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 25.0,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 25.0,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: 25.0,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0,
            mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,
        }
        # message id -> period in wall seconds; SET_MESSAGE_INTERVAL changes it
        self._streams: dict[int, float] = {mid: 1.0 / hz for mid, hz in self._default_rates_hz.items()}

    # --- lifecycle -------------------------------------------------------------------

    def start(self) -> "Vehicle":
        """Open the MAVLink link and start the receive, physics and telemetry threads."""
        if self._threads:
            raise MissionError("vehicle already started")
        try:
            self._conn = mavutil.mavlink_connection(self.config.url, source_system=self.config.system_id,
                                                    source_component=MAV_COMP_ID_AUTOPILOT1)
        except Exception as exc:  # pymavlink raises anything from ValueError to OSError here
            raise MissionError(f"cannot open the vehicle's MAVLink link {self.config.url!r}: {exc}") from None
        self._stop.clear()
        self._boot = time.monotonic()
        self._event("booted")
        for name, target in (("recv", self._recv_loop), ("physics", self._physics_loop),
                             ("telemetry", self._telemetry_loop)):
            thread = threading.Thread(target=target, name=f"vehicle-{name}", daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def stop(self) -> None:
        """Stop the threads (joined within 2 s) and close the link. Idempotent."""
        self._stop.set()
        deadline = time.monotonic() + 2.0
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        self._threads = []
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:
                pass
            self._conn = None

    def __enter__(self) -> "Vehicle":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- public state ----------------------------------------------------------------

    def pose(self) -> tuple[float, float, float, float]:
        """(north, east, down, yaw_rad) in the local NED frame."""
        with self._lock:
            return (*self._pos, self._yaw)

    @property
    def armed(self) -> bool:
        with self._lock:
            return self._armed

    @property
    def landed_state(self) -> LandedState:
        with self._lock:
            return self._landed_state()

    @property
    def in_air(self) -> bool:
        return self.landed_state != LandedState.ON_GROUND

    @property
    def mode(self) -> Mode:
        with self._lock:
            return self._mode

    @property
    def bad_frames(self) -> int:
        """Datagrams or frames received that were not valid MAVLink, or that broke a handler."""
        with self._lock:
            return self._bad_frames

    @property
    def max_altitude_m(self) -> float:
        with self._lock:
            return self._max_alt

    @property
    def sim_time_s(self) -> float:
        with self._lock:
            return self._sim_time

    @property
    def events(self) -> list[tuple[float, str]]:
        """(simulated time in s, text) of notable events: armed, takeoff, landed, ..."""
        with self._lock:
            return list(self._events)

    @property
    def local_address(self) -> tuple[str, int] | None:
        """The (host, port) the vehicle's UDP socket is bound to, once started."""
        conn = self._conn
        if conn is None or not isinstance(conn, mavutil.mavudp):
            return None
        try:
            return conn.port.getsockname()[:2]
        except OSError:
            return None

    # --- small helpers ---------------------------------------------------------------

    def _event(self, text: str) -> None:
        with self._lock:
            self._events.append((round(self._sim_time, 3), text))

    def _warn(self, text: str) -> None:
        """One line to stderr, at most once per second; the rest are counted."""
        now = time.monotonic()
        with self._lock:
            if now - self._last_warn < 1.0:
                self._suppressed_warnings += 1
                return
            suppressed, self._suppressed_warnings = self._suppressed_warnings, 0
            self._last_warn = now
        more = f" ({suppressed} more suppressed)" if suppressed else ""
        print(f"vehicle: {text}{more}", file=sys.stderr, flush=True)

    def _bad(self, text: str) -> None:
        with self._lock:
            self._bad_frames += 1
        self._warn(text)

    def _boot_ms(self) -> int:
        return int((time.monotonic() - self._boot) * 1000) & 0xFFFFFFFF

    def _alt(self) -> float:
        return -self._pos[2]

    def _max_alt_m(self) -> float:
        return self._params["LNDMC_ALT_MAX"].value

    def _send(self, msg) -> None:
        with self._send_lock:
            if self._conn is not None:
                self._sender.send(msg)

    # --- receive ---------------------------------------------------------------------

    def _recv_loop(self) -> None:
        conn = self._conn
        is_udp = isinstance(conn, mavutil.mavudp)
        while not self._stop.is_set():
            try:
                readable, _, _ = select.select([conn.fd], [], [], 0.1)
            except (OSError, ValueError):
                return  # closed under us
            if not readable:
                continue
            try:
                if is_udp:
                    data, addr = conn.port.recvfrom(65535)
                else:
                    data, addr = conn.recv(4096), None
            except (BlockingIOError, ConnectionRefusedError, InterruptedError):
                continue  # ICMP port unreachable from a udpout peer that is not up yet
            except OSError:
                if self._stop.is_set():
                    return
                continue
            if not data:
                continue
            if isinstance(data, str):
                data = data.encode("latin-1")
            self._on_bytes(data, addr, conn, is_udp)

    def _on_bytes(self, data: bytes, addr, conn, is_udp: bool) -> None:
        try:
            msgs = self._parser.parse_buffer(data) or []
        except Exception as exc:  # the parser should not raise, but a forged frame must never kill us
            msgs = []
            self._bad(f"unparseable bytes ({exc})")
        if is_udp and self._parser.buf_len() > 0:
            # MAVLink frames never span datagrams: a truncated frame left in the buffer
            # would swallow the start of the next datagram.
            self._parser.buf = bytearray()
            self._parser.buf_index = 0
            self._parser.expected_length = mavlink.HEADER_LEN_V1 + 2
            self._bad(f"truncated frame of {len(data)} bytes")
        valid = False
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self._bad(f"bad MAVLink data: {getattr(msg, 'reason', '?')}")
                continue
            if msg.get_type().startswith("UNKNOWN_"):
                # pymavlink cannot check the CRC of an id it does not know: random bytes
                # pass as such frames now and then, so they are garbage to us
                self._bad(f"frame of unknown type {msg.get_type()}")
                continue
            if msg.get_srcSystem() == self.config.system_id and msg.get_srcComponent() == MAV_COMP_ID_AUTOPILOT1:
                continue  # our own frames echoed back
            valid = True
            try:
                self._handle(msg)
            except Exception as exc:  # a well-formed frame with absurd content
                self._bad(f"cannot handle {msg.get_type()}: {type(exc).__name__}: {exc}")
        if valid and is_udp and conn.udp_server and addr is not None:
            # Only a sender of valid MAVLink becomes a peer: garbage must not redirect telemetry.
            new_peer = addr not in conn.clients
            conn.clients.add(addr)
            conn.clients_last_alive[addr] = time.time()
            if new_peer:  # greet it now rather than at the next heartbeat, so it connects at once
                self._event(f"ground station at {addr[0]}:{addr[1]}")
                self._send(self._msg_heartbeat())

    def _for_us(self, target_system: int, target_component: int | None = None) -> bool:
        if target_system not in (0, self.config.system_id):
            return False
        return target_component is None or target_component in (0, MAV_COMP_ID_AUTOPILOT1)

    def _handle(self, msg) -> None:
        kind = msg.get_type()
        if kind == "COMMAND_LONG":
            if self._for_us(msg.target_system, msg.target_component):
                params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
                self._command(msg, msg.command, params, frame=None)
        elif kind == "COMMAND_INT":
            if self._for_us(msg.target_system, msg.target_component):
                params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z)
                self._command(msg, msg.command, params, frame=msg.frame)
        elif kind == "PARAM_REQUEST_READ":
            if self._for_us(msg.target_system, msg.target_component):
                self._param_read(_text(msg.param_id), msg.param_index)
        elif kind == "PARAM_REQUEST_LIST":
            if self._for_us(msg.target_system, msg.target_component):
                for index in range(len(self._params)):
                    self._param_read("", index)
        elif kind == "PARAM_SET":
            if self._for_us(msg.target_system, msg.target_component):
                self._param_set(_text(msg.param_id), msg.param_value)
        elif kind == "SET_POSITION_TARGET_LOCAL_NED":
            if self._for_us(msg.target_system, msg.target_component):
                self._offboard_setpoint(msg)
        elif kind == "SET_MODE":
            if self._for_us(msg.target_system):
                if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                    self._set_mode((msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF)
        elif kind == "TIMESYNC":
            if msg.tc1 == 0:  # a request; answering lets a client estimate our clock offset
                self._send(self._sender.timesync_encode(time.monotonic_ns(), msg.ts1))
        elif kind == "PING":
            if msg.target_system == 0 and msg.target_component == 0:  # a request, not someone's reply
                self._send(self._sender.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(),
                                                    msg.get_srcComponent()))
        # HEARTBEAT and everything else from a ground station needs no answer

    # --- commands ----------------------------------------------------------------------

    def _command(self, msg, command: int, params: tuple, frame: int | None) -> None:
        try:
            result, follow_up = self._run_command(command, params, frame)
        except (ValueError, OverflowError, TypeError) as exc:  # e.g. NaN where an integer belongs
            self._bad(f"command {command} with unusable parameters: {exc}")
            result, follow_up = mavlink.MAV_RESULT_FAILED, None
        self._send(self._sender.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(),
                                                   msg.get_srcComponent()))
        if follow_up is not None:
            self._send(follow_up)

    def _run_command(self, command: int, p: tuple, frame: int | None) -> tuple[int, object | None]:
        """Execute one command; returns (MAV_RESULT, message to send after the ACK or None)."""
        m = mavlink
        if command == m.MAV_CMD_COMPONENT_ARM_DISARM:
            if p[0] not in (0.0, 1.0):
                return m.MAV_RESULT_DENIED, None
            return self._arm(p[0] == 1.0, math.isfinite(p[1]) and int(p[1]) == FORCE_MAGIC), None
        if command == m.MAV_CMD_NAV_TAKEOFF:
            return self._takeoff(p[6], p[3]), None
        if command == m.MAV_CMD_NAV_LAND:
            return self._land(), None
        if command == m.MAV_CMD_DO_REPOSITION:
            return self._reposition(p, frame), None
        if command == m.MAV_CMD_DO_SET_MODE:
            if not int(p[0]) & m.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                return m.MAV_RESULT_DENIED, None
            return self._set_mode(int(p[1]), int(p[2])), None
        if command == m.MAV_CMD_NAV_LOITER_UNLIM:
            with self._lock:
                if not self._armed:
                    return m.MAV_RESULT_DENIED, None
                self._enter_hold()
            return m.MAV_RESULT_ACCEPTED, None
        if command == m.MAV_CMD_DO_CHANGE_SPEED:
            return self._change_speed(int(p[0]), p[1]), None
        if command == m.MAV_CMD_REQUEST_MESSAGE:
            builder = self._builders.get(int(p[0])) if math.isfinite(p[0]) else None
            if builder is None:
                return m.MAV_RESULT_UNSUPPORTED, None
            return m.MAV_RESULT_ACCEPTED, builder()
        if command == m.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return m.MAV_RESULT_ACCEPTED, self._msg_autopilot_version()
        if command == m.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_interval(p[0], p[1]), None
        return m.MAV_RESULT_UNSUPPORTED, None

    def _arm(self, arm: bool, force: bool) -> int:
        with self._lock:
            if arm:
                if self._armed:
                    return mavlink.MAV_RESULT_ACCEPTED
                if self._airborne and not force:
                    return mavlink.MAV_RESULT_DENIED
                self._armed = True
                self._touchdown_at = None
                if self._mode == Mode.HOLD:
                    self._target = self._pos
                self._event("armed")
                return mavlink.MAV_RESULT_ACCEPTED
            if not self._armed:
                return mavlink.MAV_RESULT_ACCEPTED
            if self._airborne and not force:
                return mavlink.MAV_RESULT_DENIED
            self._disarm("disarmed" + (" in the air (forced)" if self._airborne else ""))
            return mavlink.MAV_RESULT_ACCEPTED

    def _disarm(self, why: str) -> None:
        self._armed = False
        self._touchdown_at = None
        if self._mode in (Mode.LAND, Mode.TAKEOFF):
            self._mode = Mode.HOLD  # so that the next arm + takeoff starts clean
        self._event(why)

    def _takeoff(self, alt_amsl: float, yaw: float) -> int:
        with self._lock:
            if not self._armed:
                return mavlink.MAV_RESULT_DENIED
            if math.isfinite(alt_amsl):  # PX4 reads param7 as AMSL
                alt = alt_amsl - self.config.home_alt_m
            else:
                alt = self._params["MIS_TAKEOFF_ALT"].value
            alt = min(max(alt, 0.5), self._max_alt_m())
            self._mode = Mode.TAKEOFF
            self._target = (self._pos[0], self._pos[1], -alt)
            if math.isfinite(yaw):
                self._target_yaw = yaw
            self._event(f"takeoff to {alt:.1f} m")
            return mavlink.MAV_RESULT_ACCEPTED

    def _land(self) -> int:
        with self._lock:
            if self._mode != Mode.LAND:
                self._mode = Mode.LAND
                self._event("landing")
            self._target = (self._pos[0], self._pos[1], 0.0)
            return mavlink.MAV_RESULT_ACCEPTED

    def _reposition(self, p: tuple, frame: int | None) -> int:
        cfg = self.config
        with self._lock:
            if not self._armed:
                return mavlink.MAV_RESULT_DENIED
            north, east, down = self._pos
            if frame is None:  # COMMAND_LONG: degrees as floats, NaN = keep
                lat, lon, alt = p[4], p[5], p[6]
                has_xy = math.isfinite(lat) and math.isfinite(lon)
                relative = False
            else:  # COMMAND_INT: degrees * 1e7, INT32_MAX = keep
                has_xy = p[4] != INT32_MAX and p[5] != INT32_MAX
                lat, lon, alt = p[4] / 1e7, p[5] / 1e7, p[6]
                relative = frame in (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
                if frame not in (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT,
                                 mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
                    return mavlink.MAV_RESULT_UNSUPPORTED
            if has_xy:
                if not (abs(lat) <= 90 and abs(lon) <= 180):
                    return mavlink.MAV_RESULT_DENIED
                north, east = geo_to_ned(lat, lon, cfg.home_lat, cfg.home_lon)
            if math.isfinite(alt):
                down = -(alt if relative else alt - cfg.home_alt_m)
            down = min(0.0, max(-self._max_alt_m(), down))
            if self._mode != Mode.HOLD:
                self._event(f"mode {self._mode.name} -> HOLD (reposition)")
            self._mode = Mode.HOLD
            self._target = (north, east, down)
            if math.isfinite(p[3]):
                self._target_yaw = p[3]
            if math.isfinite(p[0]) and p[0] > 0:
                self._speed_xy = min(p[0], self._params["MPC_XY_VEL_MAX"].value)
            return mavlink.MAV_RESULT_ACCEPTED

    def _set_mode(self, main: int, sub: int) -> int:
        mode = Mode.from_custom_mode(main, sub)
        if mode is None or mode not in FLYABLE_MODES:
            self._warn(f"refused mode main={main} sub={sub} ({mode.name if mode else 'unknown'})")
            return mavlink.MAV_RESULT_DENIED
        with self._lock:
            if mode == self._mode:
                return mavlink.MAV_RESULT_ACCEPTED
            if mode == Mode.HOLD:
                self._enter_hold()
                return mavlink.MAV_RESULT_ACCEPTED
        if mode == Mode.TAKEOFF:
            return self._takeoff(math.nan, math.nan)
        if mode == Mode.LAND:
            return self._land()
        with self._lock:  # OFFBOARD: PX4 only switches once setpoints are streaming
            if not self._offboard_streaming(time.monotonic()):
                return mavlink.MAV_RESULT_DENIED
            self._mode = Mode.OFFBOARD
            self._event("mode OFFBOARD")
            return mavlink.MAV_RESULT_ACCEPTED

    def _enter_hold(self) -> None:
        """Switch to HOLD, braking at the current position. Caller holds the lock."""
        if self._mode != Mode.HOLD:
            self._event(f"mode {self._mode.name} -> HOLD")
        self._mode = Mode.HOLD
        self._target = self._pos

    def _change_speed(self, kind: int, speed: float) -> int:
        if not (math.isfinite(speed) and speed > 0):
            return mavlink.MAV_RESULT_ACCEPTED  # -1 means "no change"
        with self._lock:
            if kind in (0, 1):
                self._speed_xy = min(speed, self._params["MPC_XY_VEL_MAX"].value)
            elif kind == 2:
                self._params["MPC_Z_VEL_MAX_UP"].value = min(speed, self._params["MPC_Z_VEL_MAX_UP"].high)
            elif kind == 3:
                self._params["MPC_Z_VEL_MAX_DN"].value = min(speed, self._params["MPC_Z_VEL_MAX_DN"].high)
            else:
                return mavlink.MAV_RESULT_DENIED
        return mavlink.MAV_RESULT_ACCEPTED

    def _set_interval(self, msg_id: float, interval_us: float) -> int:
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)):
            return mavlink.MAV_RESULT_DENIED
        mid = int(msg_id)
        if mid not in self._builders:
            return mavlink.MAV_RESULT_UNSUPPORTED
        with self._lock:
            if interval_us < 0:
                self._streams.pop(mid, None)
            elif interval_us == 0:
                if mid in self._default_rates_hz:
                    self._streams[mid] = 1.0 / self._default_rates_hz[mid]
                else:
                    self._streams.pop(mid, None)
            else:
                self._streams[mid] = max(interval_us / 1e6, 1.0 / MAX_STREAM_HZ)
        return mavlink.MAV_RESULT_ACCEPTED

    # --- parameters --------------------------------------------------------------------

    def _param_read(self, name: str, index: int) -> None:
        names = list(self._params)
        if index >= 0:
            if index >= len(names):
                return
            name = names[index]
        elif name not in self._params:
            self._warn(f"unknown parameter {name!r} requested")
            return  # like PX4: no answer for a parameter it does not have
        self._send_param(name)

    def _param_set(self, name: str, value: float) -> None:
        param = self._params.get(name)
        if param is None:
            self._warn(f"unknown parameter {name!r} set")
            return
        if not math.isfinite(value):
            self._warn(f"non-finite value for parameter {name!r} ignored")
        else:
            with self._lock:
                param.value = min(param.high, max(param.low, float(value)))
                if name == "MPC_XY_VEL_MAX":
                    self._speed_xy = min(self._speed_xy, param.value)
        self._send_param(name)  # the echo tells the client what was actually stored

    def _send_param(self, name: str) -> None:
        names = list(self._params)
        with self._lock:
            value = self._params[name].value
        self._send(self._sender.param_value_encode(name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32,
                                                   len(names), names.index(name)))

    # --- offboard ----------------------------------------------------------------------

    def _offboard_streaming(self, now: float) -> bool:
        """At least two setpoints within the last second, the newest within the loss timeout."""
        times = self._offboard_times
        return (len(times) == 2 and now - times[0] <= OFFBOARD_MIN_RATE_WINDOW_S
                and now - times[1] <= OFFBOARD_LOSS_S)

    def _offboard_setpoint(self, msg) -> None:
        mask = msg.type_mask
        frame = msg.coordinate_frame
        if frame not in (mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_NED):
            self._warn(f"offboard setpoint in unsupported frame {frame} ignored")
            return
        pos = None if mask & 0b111 else (msg.x, msg.y, msg.z)
        vel = None if mask & 0b111000 else (msg.vx, msg.vy, msg.vz)
        yaw = None if mask & mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE else msg.yaw
        values = [v for v in (*(pos or ()), *(vel or ()), yaw if yaw is not None else 0.0)]
        if not all(math.isfinite(v) for v in values):
            self._bad("offboard setpoint with non-finite values ignored")
            return
        with self._lock:
            if frame == mavlink.MAV_FRAME_BODY_NED and vel is not None:
                c, s = math.cos(self._yaw), math.sin(self._yaw)
                vel = (c * vel[0] - s * vel[1], s * vel[0] + c * vel[1], vel[2])
            if frame == mavlink.MAV_FRAME_BODY_NED and pos is not None:
                pos = None  # body-frame positions are offsets PX4 does not take either
            self._offboard_times.append(time.monotonic())
            self._offboard_pos, self._offboard_vel, self._offboard_yaw = pos, vel, yaw

    # --- physics -----------------------------------------------------------------------

    def _physics_loop(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(0.02):
            now = time.monotonic()
            try:
                self._physics_step((now - last) * self.config.time_scale, now)
            except Exception as exc:  # never let the sky fall because of a bug in one step
                self._warn(f"physics step failed: {type(exc).__name__}: {exc}")
            last = now

    def _landed_state(self) -> LandedState:
        if self._armed and self._mode == Mode.TAKEOFF and self._alt() < -self._target[2] - TAKEOFF_DONE_M:
            return LandedState.TAKING_OFF
        if not self._airborne:
            return LandedState.ON_GROUND
        if self._mode == Mode.LAND:
            return LandedState.LANDING
        return LandedState.IN_AIR

    def _physics_step(self, dt: float, wall_now: float) -> None:
        with self._lock:
            prev = self._pos
            self._sim_time += dt
            if not self._armed:
                self._fall(dt)
            else:
                self._fly(dt, wall_now)
            n, e, d = self._pos
            d = min(0.0, max(-self._max_alt_m(), d))
            self._pos = (n, e, d)
            self._vel = tuple((a - b) / dt for a, b in zip(self._pos, prev)) if dt > 0 else (0.0, 0.0, 0.0)
            self._update_land_detector()
            self._max_alt = max(self._max_alt, self._alt())

    def _fall(self, dt: float) -> None:
        if self._alt() <= GROUND_EPS_M:
            self._pos = (self._pos[0], self._pos[1], 0.0)
            return
        vz = min(TERMINAL_SPEED_M_S, self._vel[2] + GRAVITY_M_S2 * dt)
        self._pos = (self._pos[0], self._pos[1], min(0.0, self._pos[2] + vz * dt))
        if self._pos[2] >= 0.0:
            self._event(f"hit the ground at {vz:.1f} m/s")

    def _fly(self, dt: float, wall_now: float) -> None:
        p = self._params
        up, down = p["MPC_Z_VEL_MAX_UP"].value, p["MPC_Z_VEL_MAX_DN"].value
        speed = min(self._speed_xy, p["MPC_XY_VEL_MAX"].value)
        if self._mode == Mode.OFFBOARD:
            if wall_now - (self._offboard_times[-1] if self._offboard_times else -math.inf) > OFFBOARD_LOSS_S:
                self._event("offboard setpoints lost")
                self._enter_hold()
            elif self._offboard_pos is not None:
                self._target = self._offboard_pos
            elif self._offboard_vel is not None:
                vn, ve, vd = self._offboard_vel
                scale = min(1.0, speed / math.hypot(vn, ve)) if math.hypot(vn, ve) > 0 else 1.0
                vd = max(-up, min(down, vd))
                n, e, d = self._pos
                self._target = (n + vn * scale * dt, e + ve * scale * dt, d + vd * dt)
            if self._offboard_yaw is not None:
                self._target_yaw = self._offboard_yaw
        if self._mode == Mode.LAND:
            self._target = (self._pos[0], self._pos[1], 0.0)
            if self._alt() <= LAND_SLOW_ALT_M:
                down = min(down, p["MPC_LAND_SPEED"].value)
            speed = 0.0
        target = (self._target[0], self._target[1], min(0.0, max(-self._max_alt_m(), self._target[2])))
        if self._mode == Mode.TAKEOFF:
            speed = 0.0  # a vertical climb, like PX4's takeoff
        self._pos = step_toward(self._pos, target, speed, up, down, dt)
        self._yaw = step_yaw(self._yaw, self._target_yaw, YAW_RATE_RAD_S, dt)
        if self._mode == Mode.TAKEOFF and abs(self._alt() + target[2]) <= TAKEOFF_DONE_M:
            self._event(f"takeoff complete at {self._alt():.1f} m")
            self._enter_hold()

    def _update_land_detector(self) -> None:
        """PX4-like land detector: airborne above LIFTOFF_ALT_M, landed on touching the
        ground, auto-disarm COM_DISARM_LAND simulated seconds after touchdown."""
        alt = self._alt()
        if not self._airborne and alt > LIFTOFF_ALT_M:
            self._airborne = True
            self._touchdown_at = None
            self._event("liftoff")
        elif self._airborne and alt <= GROUND_EPS_M:
            self._airborne = False
            self._touchdown_at = self._sim_time
            self._event("landed")
        elif self._armed and not self._airborne and self._mode == Mode.LAND and self._touchdown_at is None:
            self._touchdown_at = self._sim_time  # told to land while still on the ground
        if (self._armed and self._touchdown_at is not None and not self._airborne
                and self._sim_time - self._touchdown_at >= self._params["COM_DISARM_LAND"].value):
            self._disarm("disarmed after landing")

    # --- telemetry ---------------------------------------------------------------------

    def _telemetry_loop(self) -> None:
        next_due: dict[int, float] = {}
        last_status = None
        while not self._stop.is_set():
            now = time.monotonic()
            with self._lock:
                streams = dict(self._streams)
                status = (self._armed, self._mode, self._landed_state())
            due = []
            for mid, period in streams.items():
                if now >= next_due.get(mid, 0.0):
                    due.append(mid)
                    next_due[mid] = max(next_due.get(mid, now) + period, now)  # no bursts to catch up
            if status != last_status:
                # Ground stations learn arming and mode only from heartbeats: tell them now,
                # not up to a heartbeat period later.
                due += [mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE]
                last_status = status
            for mid in dict.fromkeys(due):
                try:
                    self._send(self._builders[mid]())
                except Exception as exc:
                    self._warn(f"cannot send message {mid}: {type(exc).__name__}: {exc}")
            pending = [t for mid, t in next_due.items() if mid in streams]
            wait = min(pending, default=now + 0.05) - time.monotonic()
            self._stop.wait(min(0.02, max(0.001, wait)))

    def _msg_heartbeat(self):
        with self._lock:
            armed, mode = self._armed, self._mode
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if mode in AUTO_MODES:
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        elif mode == Mode.OFFBOARD:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        status = mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY
        return self._sender.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base,
                                             mode.custom_mode, status)

    def _msg_sys_status(self):
        s = mavlink
        sensors = (s.MAV_SYS_STATUS_SENSOR_3D_GYRO | s.MAV_SYS_STATUS_SENSOR_3D_ACCEL | s.MAV_SYS_STATUS_SENSOR_3D_MAG
                   | s.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | s.MAV_SYS_STATUS_SENSOR_GPS
                   | s.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL | s.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
                   | s.MAV_SYS_STATUS_SENSOR_YAW_POSITION | s.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
                   | s.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL | s.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
                   | s.MAV_SYS_STATUS_AHRS | s.MAV_SYS_STATUS_SENSOR_BATTERY | s.MAV_SYS_STATUS_PREARM_CHECK)
        return self._sender.sys_status_encode(sensors, sensors, sensors, 200, 16200, 500 if self.armed else 0,
                                              100, 0, 0, 0, 0, 0, 0)

    def _msg_extended_sys_state(self):
        return self._sender.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, int(self.landed_state))

    def _geo(self) -> tuple[int, int, int, int]:
        """(lat 1e7, lon 1e7, alt AMSL mm, relative alt mm) of the current position."""
        cfg = self.config
        with self._lock:
            n, e, d = self._pos
        lat, lon = ned_to_geo(n, e, cfg.home_lat, cfg.home_lon)
        return round(lat * 1e7), round(lon * 1e7), round((cfg.home_alt_m - d) * 1000), round(-d * 1000)

    def _msg_global_position_int(self):
        lat, lon, alt, rel = self._geo()
        with self._lock:
            vn, ve, vd = self._vel
            yaw = self._yaw
        cm = [max(-32768, min(32767, round(v * 100))) for v in (vn, ve, vd)]
        return self._sender.global_position_int_encode(self._boot_ms(), lat, lon, alt, rel, *cm,
                                                       round(math.degrees(yaw) * 100) % 36000)

    def _msg_local_position_ned(self):
        with self._lock:
            pos, vel = self._pos, self._vel
        return self._sender.local_position_ned_encode(self._boot_ms(), *pos, *vel)

    def _msg_attitude(self):
        with self._lock:
            yaw = self._yaw
        return self._sender.attitude_encode(self._boot_ms(), 0.0, 0.0, yaw, 0.0, 0.0, 0.0)

    def _msg_home_position(self):
        cfg = self.config
        return self._sender.home_position_encode(round(cfg.home_lat * 1e7), round(cfg.home_lon * 1e7),
                                                 round(cfg.home_alt_m * 1000), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                                 0.0, 0.0, 0.0, int(time.time() * 1e6))

    def _msg_gps_global_origin(self):
        cfg = self.config
        return self._sender.gps_global_origin_encode(round(cfg.home_lat * 1e7), round(cfg.home_lon * 1e7),
                                                     round(cfg.home_alt_m * 1000), int(time.time() * 1e6))

    def _msg_gps_raw_int(self):
        lat, lon, alt, _ = self._geo()
        with self._lock:
            speed = math.hypot(self._vel[0], self._vel[1])
            yaw = self._yaw
        return self._sender.gps_raw_int_encode(int(time.time() * 1e6), mavlink.GPS_FIX_TYPE_3D_FIX, lat, lon, alt,
                                               80, 120, min(65534, round(speed * 100)),
                                               round(math.degrees(yaw) * 100) % 36000, 12)

    def _msg_vfr_hud(self):
        with self._lock:
            vn, ve, vd = self._vel
            yaw, alt, armed = self._yaw, self._alt(), self._armed
        return self._sender.vfr_hud_encode(math.hypot(vn, ve), math.hypot(vn, ve), round(math.degrees(yaw)) % 360,
                                           50 if armed else 0, self.config.home_alt_m + alt, -vd)

    def _msg_autopilot_version(self):
        s = mavlink
        caps = (s.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | s.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | s.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED | s.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | s.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
        version = (1 << 24) | (15 << 16) | (0 << 8) | 255  # 1.15.0 release, PX4's encoding
        uid = 0x5541_5652_0000_0000 | self.config.system_id  # "UAVR" + system id: stable per vehicle
        return self._sender.autopilot_version_encode(caps, version, version, 0, 0, [0] * 8, [0] * 8, [0] * 8,
                                                     0, 0, uid)


class _Writer:
    """The file pymavlink's sender writes frames to: the vehicle's current link."""

    def __init__(self, vehicle: Vehicle):
        self._vehicle = vehicle

    def write(self, buf: bytes) -> None:
        conn = self._vehicle._conn
        if conn is not None:
            conn.write(buf)


def _text(value) -> str:
    """A MAVLink char[] field as str, without NUL padding."""
    if isinstance(value, (bytes, bytearray)):
        value = value.decode("ascii", "replace")
    return value.split("\0", 1)[0]
