"""Telemetry: the messages the vehicle reports and the streams that carry them.

Streams run on wall time, not simulated time: the ground station's own timeouts (and
the rates it asks for with SET_MESSAGE_INTERVAL) are in wall seconds. Each link has its own
streams, as PX4's MAVLink instances do: SET_MESSAGE_INTERVAL changes the rate on the link it
came from only (a ground station silencing a stream does not silence the companion's), and
MAV_CMD_GET_MESSAGE_INTERVAL answers that link's rate.

Position and attitude are the estimator's (see `estimator.py`); an indoor vehicle (no GPS) has
no global position, GPS or home to report: LOCAL_POSITION_NED is its frame.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from protocol.geo import ned_to_geo

from .autopilot import Autopilot
from .battery import Battery
from .config import VehicleConfig
from .dynamics import Dynamics, State
from .estimator import Estimator
from .journal import Journal
from .link import Link
from .mission import Mission
from .modes import AUTO_MODES, Mode

HEARTBEAT_PERIOD_S = 1.0
MAX_STREAM_HZ = 100.0
PX4_VERSION = (1 << 24) | (15 << 16) | (0 << 8) | 255  # 1.15.0 release, PX4's encoding
m = mavlink
GLOBAL_ONLY = (m.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, m.MAVLINK_MSG_ID_GPS_RAW_INT, m.MAVLINK_MSG_ID_HOME_POSITION,
               m.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN)  # what a vehicle without GPS has not


class Telemetry:
    """Builds every message the vehicle can report (for streams and REQUEST_MESSAGE) and
    sends the streams at their rates."""

    def __init__(self, config: VehicleConfig, lock: threading.RLock, journal: Journal, link: Link,
                 dynamics: Dynamics, autopilot: Autopilot, battery: Battery, mission: Mission,
                 estimator: Estimator | None = None):
        self._config = config
        self._estimator = estimator or Estimator(config, lock)
        self._battery = battery
        self._mission = mission
        self._lock = lock
        self._journal = journal
        self._link = link
        self._encoder = link.encoder
        self._dynamics = dynamics
        self._autopilot = autopilot
        self._boot = time.monotonic()
        self._builders: dict[int, Callable[[], object]] = {
            mavlink.MAVLINK_MSG_ID_HEARTBEAT: self.heartbeat,
            mavlink.MAVLINK_MSG_ID_SYS_STATUS: self._sys_status,
            mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self._extended_sys_state,
            mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self._global_position_int,
            mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self._local_position_ned,
            mavlink.MAVLINK_MSG_ID_ATTITUDE: self._attitude,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._home_position,
            mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: self._gps_raw_int,
            mavlink.MAVLINK_MSG_ID_VFR_HUD: self._vfr_hud,
            mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: self._gps_global_origin,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._autopilot_version,
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: self._battery_status,
            mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: self.mission_current,
            mavlink.MAVLINK_MSG_ID_ALTITUDE: self._altitude,
            mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self._attitude_quaternion,
            mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: self._estimator_status,
        }
        if not config.gps:
            for mid in GLOBAL_ONLY:
                del self._builders[mid]
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
            mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
            mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
            mavlink.MAVLINK_MSG_ID_ALTITUDE: 5.0,
            mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
            mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 1.0,
        }
        self._default_rates_hz = {mid: hz for mid, hz in self._default_rates_hz.items() if mid in self._builders}
        # link name -> message id -> period in wall seconds; SET_MESSAGE_INTERVAL changes its own link's
        quiet = {mavlink.MAVLINK_MSG_ID_HEARTBEAT} if config.streams_until_asked else self._default_rates_hz
        self._streams: dict[str, dict[int, float]] = {
            ch.name: {mid: 1.0 / hz for mid, hz in self._default_rates_hz.items() if mid in quiet}
            for ch in link.channels}

    def restart_clock(self) -> None:
        """Time since boot (in the messages that carry it) counts from now."""
        self._boot = time.monotonic()

    def message(self, msg_id: int):
        """A fresh message with id `msg_id`, or None if this vehicle does not report it."""
        builder = self._builders.get(msg_id)
        return builder() if builder is not None else None

    def _streams_of(self, link: str | None) -> dict[int, float]:
        """The streams of link `link` (the one whose message is being handled when None)."""
        if link is None:
            current = self._link.current
            link = current.name if current is not None else self._link.channels[0].name
        return self._streams.setdefault(link, {})

    def set_interval(self, msg_id: float, interval_us: float, link: str | None = None) -> int:
        """SET_MESSAGE_INTERVAL on one link (the asker's): < 0 stops the stream, 0 restores its default rate."""
        if not (math.isfinite(msg_id) and math.isfinite(interval_us)):
            return mavlink.MAV_RESULT_DENIED
        mid = int(msg_id)
        if mid not in self._builders:
            return mavlink.MAV_RESULT_UNSUPPORTED
        with self._lock:
            streams = self._streams_of(link)
            if interval_us < 0:
                streams.pop(mid, None)
            elif interval_us == 0:
                if mid in self._default_rates_hz:
                    streams[mid] = 1.0 / self._default_rates_hz[mid]
                else:
                    streams.pop(mid, None)
            else:
                streams[mid] = max(interval_us / 1e6, 1.0 / MAX_STREAM_HZ)
        return mavlink.MAV_RESULT_ACCEPTED

    def interval(self, msg_id: float, link: str | None = None):
        """MESSAGE_INTERVAL for MAV_CMD_GET_MESSAGE_INTERVAL on one link (the asker's): the period in
        microseconds, -1 if the stream is off, 0 if this vehicle has no such message; None for a bad id."""
        if not (math.isfinite(msg_id) and 0 <= msg_id < 2**24):
            return None
        mid = int(msg_id)
        with self._lock:
            period = self._streams_of(link).get(mid)
        interval_us = 0 if mid not in self._builders else -1 if period is None else round(period * 1e6)
        return self._encoder.message_interval_encode(mid, interval_us)

    def run(self, stop: threading.Event) -> None:
        """Send each link's streams when they are due until `stop`; a message due on several links
        is built once."""
        next_due: dict[tuple[str, int], float] = {}
        last_status = None
        channels = {ch.name: ch for ch in self._link.channels}
        while not stop.is_set():
            now = time.monotonic()
            with self._lock:
                streams = {name: dict(self._streams_of(name)) for name in channels}
                status = self._autopilot.status()
            due: dict[int, list[str]] = {}
            for name, mine in streams.items():
                for mid, period in mine.items():
                    key = (name, mid)
                    if now >= next_due.get(key, 0.0):
                        due.setdefault(mid, []).append(name)
                        next_due[key] = max(next_due.get(key, now) + period, now)  # no bursts to catch up
            if status != last_status:
                # Ground stations learn arming and mode only from heartbeats: tell them now,
                # not up to a heartbeat period later (on every link).
                for mid in (mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE):
                    due[mid] = list(channels)
                last_status = status
            for mid, names in due.items():
                try:
                    msg = self._builders[mid]()
                    for name in dict.fromkeys(names):
                        self._link.send(msg, channels[name])
                except Exception as exc:
                    self._journal.warn(f"cannot send message {mid}: {type(exc).__name__}: {exc}")
            pending = [t for (name, mid), t in next_due.items() if mid in streams.get(name, {})]
            wait = min(pending, default=now + 0.05) - time.monotonic()
            stop.wait(min(0.02, max(0.001, wait)))

    # --- the messages --------------------------------------------------------------------

    def heartbeat(self):
        armed, mode, _ = self._autopilot.status()
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if mode in AUTO_MODES:
            base |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        elif mode == Mode.OFFBOARD:
            base |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        status = mavlink.MAV_STATE_ACTIVE if armed else mavlink.MAV_STATE_STANDBY
        return self._encoder.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base,
                                              mode.custom_mode, status)

    def _sys_status(self):
        s = mavlink
        sensors = (s.MAV_SYS_STATUS_SENSOR_3D_GYRO | s.MAV_SYS_STATUS_SENSOR_3D_ACCEL | s.MAV_SYS_STATUS_SENSOR_3D_MAG
                   | s.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | s.MAV_SYS_STATUS_SENSOR_GPS
                   | s.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL | s.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
                   | s.MAV_SYS_STATUS_SENSOR_YAW_POSITION | s.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
                   | s.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL | s.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
                   | s.MAV_SYS_STATUS_AHRS | s.MAV_SYS_STATUS_SENSOR_BATTERY | s.MAV_SYS_STATUS_PREARM_CHECK)
        if not self._config.gps:
            sensors &= ~s.MAV_SYS_STATUS_SENSOR_GPS
        fence = s.MAV_SYS_STATUS_GEOFENCE
        enabled = sensors | (fence if self._autopilot.fence_enabled else 0)
        healthy = enabled & ~(fence if self._autopilot.fence_breached else 0)  # ground stations show a breach
        volts, amps, _, remaining = self._battery.reading()
        return self._encoder.sys_status_encode(enabled, enabled, healthy, 200, round(volts * 1000), round(amps * 100),
                                               round(remaining * 100), 0, 0, 0, 0, 0, 0)

    def _battery_status(self):
        volts, amps, used_mah, remaining = self._battery.reading()
        cells = self._battery.cells
        cell_mv = min(65534, round(volts * 1000 / cells))
        voltages = [cell_mv] * min(cells, 10) + [65535] * (10 - min(cells, 10))  # UINT16_MAX: no cell
        hover = max(amps, 0.1)
        seconds_left = round(self._battery.capacity_mah * remaining / 1000 / hover * 3600)
        return self._encoder.battery_status_encode(0, mavlink.MAV_BATTERY_FUNCTION_ALL, mavlink.MAV_BATTERY_TYPE_LIPO,
                                                   32767, voltages, round(amps * 100), round(used_mah),
                                                   round(volts * used_mah * 3.6 / 100), round(remaining * 100),
                                                   seconds_left, int(self._battery.charge))

    def mission_current(self):
        items = self._mission.items
        seq = self._mission.current
        if not items:
            state = mavlink.MISSION_STATE_NO_MISSION
        elif self._mission.finished:
            state = mavlink.MISSION_STATE_COMPLETE
        elif self._autopilot.mode == Mode.MISSION:
            state = mavlink.MISSION_STATE_ACTIVE
        else:
            state = mavlink.MISSION_STATE_NOT_STARTED if seq == 0 else mavlink.MISSION_STATE_PAUSED
        return self._encoder.mission_current_encode(min(seq, max(0, len(items) - 1)), len(items), state)

    def _extended_sys_state(self):
        return self._encoder.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED,
                                                       int(self._autopilot.landed_state))

    def _boot_ms(self) -> int:
        return int((time.monotonic() - self._boot) * 1000) & 0xFFFFFFFF

    def _geo_of(self, pos) -> tuple[int, int, int, int]:
        """(lat 1e7, lon 1e7, alt AMSL mm, relative alt mm) of a local NED position."""
        cfg = self._config
        n, e, d = pos
        lat, lon = ned_to_geo(n, e, cfg.home_lat, cfg.home_lon)
        return round(lat * 1e7), round(lon * 1e7), round((cfg.home_alt_m - d) * 1000), round(-d * 1000)

    def _home_geo(self) -> tuple[int, int, int]:
        """Home as (lat 1e7, lon 1e7, alt AMSL mm)."""
        cfg = self._config
        return round(cfg.home_lat * 1e7), round(cfg.home_lon * 1e7), round(cfg.home_alt_m * 1000)

    def _estimate(self) -> tuple[State, tuple[float, float, float], tuple[float, float, float]]:
        """(true state, estimated position, estimated roll/pitch/yaw): one sample of the estimator."""
        state = self._dynamics.state()
        est = self._estimator
        return state, est.position(state.pos), est.attitude(state.roll, state.pitch, state.yaw)

    def _global_position_int(self):
        state, pos, (_, _, yaw) = self._estimate()
        lat, lon, alt, rel = self._geo_of(pos)
        cm = [max(-32768, min(32767, round(v * 100))) for v in state.vel]
        return self._encoder.global_position_int_encode(self._boot_ms(), lat, lon, alt, rel, *cm, _centidegrees(yaw))

    def _local_position_ned(self):
        state, pos, _ = self._estimate()
        return self._encoder.local_position_ned_encode(self._boot_ms(), *pos, *state.vel)

    def _attitude(self):
        s, _, (roll, pitch, yaw) = self._estimate()
        return self._encoder.attitude_encode(self._boot_ms(), roll, pitch, yaw, s.roll_rate, s.pitch_rate, 0.0)

    def _attitude_quaternion(self):
        s, _, (roll, pitch, yaw) = self._estimate()
        return self._encoder.attitude_quaternion_encode(self._boot_ms(), *quaternion(roll, pitch, yaw), s.roll_rate,
                                                        s.pitch_rate, 0.0, [0.0, 0.0, 0.0, 0.0])

    def _altitude(self):
        """ALTITUDE: the estimate's altitude above home (local and relative) and AMSL; the floor is flat, so
        the terrain is home's altitude and the bottom clearance the height."""
        _, (_, _, d), _ = self._estimate()
        amsl = self._config.home_alt_m - d
        return self._encoder.altitude_encode(int((time.monotonic() - self._boot) * 1e6), amsl, amsl, -d, -d,
                                             self._config.home_alt_m, -d)

    def _estimator_status(self):
        s = mavlink
        flags = (s.ESTIMATOR_ATTITUDE | s.ESTIMATOR_VELOCITY_HORIZ | s.ESTIMATOR_VELOCITY_VERT
                 | s.ESTIMATOR_POS_HORIZ_REL | s.ESTIMATOR_POS_VERT_ABS | s.ESTIMATOR_PRED_POS_HORIZ_REL)
        if self._config.gps:
            flags |= s.ESTIMATOR_POS_HORIZ_ABS | s.ESTIMATOR_PRED_POS_HORIZ_ABS
        horizontal, vertical = self._estimator.accuracy()
        return self._encoder.estimator_status_encode(int((time.monotonic() - self._boot) * 1e6), flags, 0.1, 0.1,
                                                     0.1, 0.0, 0.0, 0.0, horizontal, vertical)

    def _home_position(self):
        return self._encoder.home_position_encode(*self._home_geo(), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                                  0.0, 0.0, 0.0, int(time.time() * 1e6))

    def _gps_global_origin(self):
        return self._encoder.gps_global_origin_encode(*self._home_geo(), int(time.time() * 1e6))

    def _gps_raw_int(self):
        state, pos, _ = self._estimate()
        lat, lon, alt, _ = self._geo_of(pos)
        speed = math.hypot(state.vel[0], state.vel[1])
        return self._encoder.gps_raw_int_encode(int(time.time() * 1e6), mavlink.GPS_FIX_TYPE_3D_FIX, lat, lon, alt,
                                                80, 120, min(65534, round(speed * 100)), _centidegrees(state.yaw),
                                                12)

    def _vfr_hud(self):
        with self._lock:
            (state, pos, (_, _, yaw)), armed = self._estimate(), self._autopilot.armed
        vn, ve, vd = state.vel
        return self._encoder.vfr_hud_encode(math.hypot(vn, ve), math.hypot(vn, ve), round(math.degrees(yaw)) % 360,
                                            50 if armed else 0, self._config.home_alt_m - pos[2], -vd)

    def _autopilot_version(self):
        s = mavlink
        # as PX4 announces them, less what this vehicle lacks (FTP, fence and rally plans, attitude targets)
        caps = (s.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | s.MAV_PROTOCOL_CAPABILITY_MISSION_INT
                | s.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | s.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | s.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | s.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT | s.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | s.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
        uid = 0x5541_5652_0000_0000 | self._config.system_id  # "UAVR" + system id: stable per vehicle
        return self._encoder.autopilot_version_encode(caps, PX4_VERSION, PX4_VERSION, 0, 0, [0] * 8, [0] * 8,
                                                      [0] * 8, 0, 0, uid)


def quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of the body's attitude (ZYX Euler angles, radians), as ATTITUDE_QUATERNION carries it."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def _centidegrees(yaw: float) -> int:
    """A heading in radians as MAVLink's 0..35999 hundredths of a degree."""
    return round(math.degrees(yaw) * 100) % 36000
