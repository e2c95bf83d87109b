"""The vehicle's parameters and MAVLink's parameter protocol (read, list, set).

Each parameter has PX4's type, INT32 or REAL32. PARAM_VALUE carries the parameter's own type,
its value encoded bytewise as PX4 does (an INT32's four bytes in the float field, which
AUTOPILOT_VERSION announces with MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE, and which
MAVSDK and QGroundControl expect of PX4). A PARAM_SET must name the same type, as PX4 wants;
one concession to hand-written scripts: a REAL32 whole number for an INT32 parameter is taken
as that integer. Anything else of another type is refused, said as STATUSTEXT, and answered
with the value kept.
"""
from __future__ import annotations

import math
import struct
import threading
from dataclasses import dataclass
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from .config import VehicleConfig
from .journal import CRITICAL, Journal
from .link import Link

INT32, REAL32 = mavlink.MAV_PARAM_TYPE_INT32, mavlink.MAV_PARAM_TYPE_REAL32
TYPE_NAMES = {v: k[len("MAV_PARAM_TYPE_"):] for k, v in vars(mavlink).items()
              if k.startswith("MAV_PARAM_TYPE_") and isinstance(v, int)}


def encode_value(value: float, kind: int) -> float:
    """What PARAM_VALUE's float field carries for `value` of type `kind` (bytewise for INT32)."""
    if kind == INT32:
        return struct.unpack("<f", struct.pack("<i", int(value)))[0]
    return float(value)


def decode_value(field: float, kind: int) -> float:
    """The value a PARAM_SET / PARAM_VALUE float field of type `kind` carries (bytewise for INT32)."""
    if kind == INT32:
        return float(struct.unpack("<i", struct.pack("<f", field))[0])
    return field


@dataclass
class _Param:
    value: float
    low: float
    high: float
    kind: int = REAL32  # MAV_PARAM_TYPE: INT32 or REAL32, as PX4 declares the parameter


class Params:
    """PX4-named parameters, typed as in PX4, in a fixed order (their protocol index)."""

    def __init__(self, config: VehicleConfig, lock: threading.RLock, journal: Journal, link: Link):
        self._lock = lock
        self._journal = journal
        self._link = link
        cfg = config
        self._params: dict[str, _Param] = {
            "MIS_TAKEOFF_ALT": _Param(cfg.takeoff_alt_m, 0.5, cfg.max_alt_m),
            "MPC_XY_VEL_MAX": _Param(cfg.max_speed_m_s, 0.1, 100.0),
            "MPC_Z_VEL_MAX_UP": _Param(cfg.max_climb_m_s, 0.1, 50.0),
            "MPC_Z_VEL_MAX_DN": _Param(cfg.max_climb_m_s, 0.1, 50.0),
            "MPC_LAND_SPEED": _Param(cfg.land_speed_m_s, 0.1, 50.0),
            "COM_DISARM_LAND": _Param(cfg.disarm_after_land_s, 0.0, 60.0),
            "LNDMC_ALT_MAX": _Param(cfg.max_alt_m, 1.0, 10000.0),
            # return and missions
            "RTL_RETURN_ALT": _Param(min(30.0, cfg.max_alt_m), 0.0, 10000.0),
            "NAV_ACC_RAD": _Param(2.0, 0.05, 200.0),
            "NAV_MC_ALT_RAD": _Param(0.8, 0.05, 200.0),
            # geofence: 0 disables a limit; GF_ACTION 0 none, 1 warn, 2 hold, 3 return, 5 land
            "GF_MAX_HOR_DIST": _Param(1000.0, 0.0, 1e7),
            "GF_MAX_VER_DIST": _Param(cfg.max_alt_m, 0.0, 1e5),
            "GF_ACTION": _Param(2.0, 0.0, 5.0, INT32),
            # datalink loss: NAV_DLL_ACT 0 off, 1 hold, 2 return, 3 land, after COM_DL_LOSS_T s
            # without a ground station's heartbeat and COM_FAIL_ACT_T s of hold
            "NAV_DLL_ACT": _Param(2.0, 0.0, 3.0, INT32),
            # INT32 in PX4; a float here, so that a test can lose its link within a second
            "COM_DL_LOSS_T": _Param(10.0, 0.5, 300.0),
            "COM_FAIL_ACT_T": _Param(5.0, 0.0, 25.0),
            # battery; COM_LOW_BAT_ACT 0 warn, 2 land at critical, 3 return at critical and land at emergency
            # A 6S 16 Ah pack: about an hour of hover at 15 A, so a long mission at --time-scale 10
            # (100 s of wall time is 1000 simulated seconds) does not end in a battery failsafe.
            "BAT1_CAPACITY": _Param(16000.0, 1.0, 1e6),
            "BAT1_N_CELLS": _Param(6.0, 1.0, 14.0, INT32),
            "SIM_BAT_HOVER_A": _Param(15.0, 0.0, 1000.0),
            # 1: a reposition's yaw is flown, as PX4 does; 0: kept as it was, as ArduCopter's guided goto does
            "SIM_GOTO_YAW": _Param(1.0, 0.0, 1.0, INT32),
            "BAT_LOW_THR": _Param(0.15, 0.12, 0.5),
            "BAT_CRIT_THR": _Param(0.07, 0.05, 0.5),
            "BAT_EMERGEN_THR": _Param(0.05, 0.03, 0.5),
            "COM_LOW_BAT_ACT": _Param(3.0, 0.0, 3.0, INT32),
            # preflight: arming is refused at or below BAT_LOW_THR, and below COM_ARM_BAT_MIN (0: off)
            "COM_ARM_BAT_MIN": _Param(0.0, 0.0, 0.9),
            # armed on the ground without taking off: disarm after this many seconds (0: never)
            "COM_DISARM_PRFLT": _Param(10.0, 0.0, 60.0),
            # the trajectory's limits: speed changes ramp, so a 0 to 12 m/s start takes seconds
            "MPC_ACC_HOR": _Param(cfg.max_accel_m_s2, 2.0, 15.0),
            "MPC_ACC_UP_MAX": _Param(cfg.max_accel_up_m_s2, 2.0, 15.0),
            "MPC_ACC_DOWN_MAX": _Param(cfg.max_accel_down_m_s2, 2.0, 15.0),
            "MPC_JERK_AUTO": _Param(cfg.jerk_m_s3, 1.0, 80.0),
        }
        self._watchers: dict[str, list[Callable[[float], None]]] = {}

    def get(self, name: str) -> float:
        with self._lock:
            return self._params[name].value

    def kind(self, name: str) -> int:
        """The parameter's MAV_PARAM_TYPE (INT32 or REAL32)."""
        return self._params[name].kind

    def set(self, name: str, value: float, *, clamp_low: bool = True) -> None:
        """Store `value` within the parameter's range (capped only from above unless
        `clamp_low`; an INT32 rounded), then tell its watchers, all under the lock."""
        param = self._params[name]
        with self._lock:
            value = min(param.high, max(param.low, value) if clamp_low else value)
            param.value = float(round(value)) if param.kind == INT32 else value
            for watcher in self._watchers.get(name, ()):
                watcher(param.value)

    def watch(self, name: str, callback: Callable[[float], None]) -> None:
        """Call `callback(new value)` under the lock whenever `name` is set."""
        self._watchers.setdefault(name, []).append(callback)

    # --- the protocol ------------------------------------------------------------------

    def on_request_read(self, msg) -> None:
        self._read(_text(msg.param_id), msg.param_index)

    def on_request_list(self, msg) -> None:
        for index in range(len(self._params)):
            self._read("", index)

    def on_set(self, msg) -> None:
        name = _text(msg.param_id)
        if name not in self._params:
            self._journal.warn(f"unknown parameter {name!r} set")
            return
        value = self._value_of(name, msg.param_value, msg.param_type)
        if value is not None:
            self.set(name, value)
        self._send(name)  # the echo tells the client what was actually stored

    def _value_of(self, name: str, field: float, kind: int) -> float | None:
        """The value a PARAM_SET of type `kind` asks `name` to take, None (said) if refused."""
        mine = self._params[name].kind
        value = decode_value(field, kind) if kind in (INT32, REAL32) else math.nan
        if kind == REAL32 and mine == INT32 and math.isfinite(value) and value == round(value):
            return value  # a script's float for an integer parameter: the same number
        if kind != mine:
            # short enough for one STATUSTEXT, as PX4's "[pm] param types mismatch"
            self._journal.say(CRITICAL, f"Param {name}: {TYPE_NAMES.get(mine)}, not {TYPE_NAMES.get(kind, kind)}: refused")
            return None
        if not math.isfinite(value):
            self._journal.warn(f"non-finite value for parameter {name!r} ignored")
            return None
        return value

    def _read(self, name: str, index: int) -> None:
        names = list(self._params)
        if index >= 0:
            if index >= len(names):
                return
            name = names[index]
        elif name not in self._params:
            self._journal.warn(f"unknown parameter {name!r} requested")
            return  # like PX4: no answer for a parameter it does not have
        self._send(name)

    def _send(self, name: str) -> None:
        names = list(self._params)
        kind = self._params[name].kind
        self._link.send(self._link.encoder.param_value_encode(name.encode(), encode_value(self.get(name), kind), kind,
                                                              len(names), names.index(name)))


def _text(value) -> str:
    """A MAVLink char[] field as str, without NUL padding."""
    if isinstance(value, (bytes, bytearray)):
        value = value.decode("ascii", "replace")
    return value.split("\0", 1)[0]
