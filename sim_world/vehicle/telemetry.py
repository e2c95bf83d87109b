"""Telemetry: the messages the vehicle reports and the streams that carry them.

Streams run on wall time, not simulated time: the ground station's own timeouts (and
the rates it asks for with SET_MESSAGE_INTERVAL) are in wall seconds.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from protocol.geo import ned_to_geo

from .autopilot import Autopilot
from .config import VehicleConfig
from .dynamics import Dynamics
from .journal import Journal
from .link import Link
from .modes import AUTO_MODES, Mode

HEARTBEAT_PERIOD_S = 1.0
MAX_STREAM_HZ = 100.0
PX4_VERSION = (1 << 24) | (15 << 16) | (0 << 8) | 255  # 1.15.0 release, PX4's encoding


class Telemetry:
    """Builds every message the vehicle can report (for streams and REQUEST_MESSAGE) and
    sends the streams at their rates."""

    def __init__(self, config: VehicleConfig, lock: threading.RLock, journal: Journal, link: Link,
                 dynamics: Dynamics, autopilot: Autopilot):
        self._config = config
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

    def restart_clock(self) -> None:
        """Time since boot (in the messages that carry it) counts from now."""
        self._boot = time.monotonic()

    def message(self, msg_id: int):
        """A fresh message with id `msg_id`, or None if this vehicle does not report it."""
        builder = self._builders.get(msg_id)
        return builder() if builder is not None else None

    def set_interval(self, msg_id: float, interval_us: float) -> int:
        """SET_MESSAGE_INTERVAL: < 0 stops the stream, 0 restores its default rate."""
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

    def run(self, stop: threading.Event) -> None:
        """Send each stream when it is due until `stop`."""
        next_due: dict[int, float] = {}
        last_status = None
        while not stop.is_set():
            now = time.monotonic()
            with self._lock:
                streams = dict(self._streams)
                status = self._autopilot.status()
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
                    self._link.send(self._builders[mid]())
                except Exception as exc:
                    self._journal.warn(f"cannot send message {mid}: {type(exc).__name__}: {exc}")
            pending = [t for mid, t in next_due.items() if mid in streams]
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
        armed = self._autopilot.armed
        return self._encoder.sys_status_encode(sensors, sensors, sensors, 200, 16200, 500 if armed else 0,
                                               100, 0, 0, 0, 0, 0, 0)

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

    def _global_position_int(self):
        state = self._dynamics.state()
        lat, lon, alt, rel = self._geo_of(state.pos)
        cm = [max(-32768, min(32767, round(v * 100))) for v in state.vel]
        return self._encoder.global_position_int_encode(self._boot_ms(), lat, lon, alt, rel, *cm,
                                                        _centidegrees(state.yaw))

    def _local_position_ned(self):
        state = self._dynamics.state()
        return self._encoder.local_position_ned_encode(self._boot_ms(), *state.pos, *state.vel)

    def _attitude(self):
        s = self._dynamics.state()
        return self._encoder.attitude_encode(self._boot_ms(), s.roll, s.pitch, s.yaw, s.roll_rate, s.pitch_rate, 0.0)

    def _home_position(self):
        return self._encoder.home_position_encode(*self._home_geo(), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                                                  0.0, 0.0, 0.0, int(time.time() * 1e6))

    def _gps_global_origin(self):
        return self._encoder.gps_global_origin_encode(*self._home_geo(), int(time.time() * 1e6))

    def _gps_raw_int(self):
        state = self._dynamics.state()
        lat, lon, alt, _ = self._geo_of(state.pos)
        speed = math.hypot(state.vel[0], state.vel[1])
        return self._encoder.gps_raw_int_encode(int(time.time() * 1e6), mavlink.GPS_FIX_TYPE_3D_FIX, lat, lon, alt,
                                                80, 120, min(65534, round(speed * 100)), _centidegrees(state.yaw),
                                                12)

    def _vfr_hud(self):
        with self._lock:
            state, armed = self._dynamics.state(), self._autopilot.armed
        vn, ve, vd = state.vel
        return self._encoder.vfr_hud_encode(math.hypot(vn, ve), math.hypot(vn, ve),
                                            round(math.degrees(state.yaw)) % 360, 50 if armed else 0,
                                            self._config.home_alt_m - state.pos[2], -vd)

    def _autopilot_version(self):
        s = mavlink
        caps = (s.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT | s.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | s.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED | s.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | s.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE)
        uid = 0x5541_5652_0000_0000 | self._config.system_id  # "UAVR" + system id: stable per vehicle
        return self._encoder.autopilot_version_encode(caps, PX4_VERSION, PX4_VERSION, 0, 0, [0] * 8, [0] * 8,
                                                      [0] * 8, 0, 0, uid)


def _centidegrees(yaw: float) -> int:
    """A heading in radians as MAVLink's 0..35999 hundredths of a degree."""
    return round(math.degrees(yaw) * 100) % 36000
