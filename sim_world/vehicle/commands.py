"""What the vehicle does with each message it receives, by table: one dict from message
type to handler, one from MAV_CMD to handler for COMMAND_LONG and COMMAND_INT.

Handlers here decode MAVLink's conventions (parameter slots, NaN or INT32_MAX for "keep",
degrees * 1e7, AMSL altitudes) and call the part that owns the state, which speaks local
NED and SI units. Adding a command or a message is one table entry and one method.
"""
from __future__ import annotations

import math
import time
from typing import Callable

from pymavlink.dialects.v20 import common as mavlink

from protocol.geo import geo_to_ned

from .autopilot import Autopilot
from .config import VehicleConfig
from .datalink import Datalink
from .journal import CRITICAL, INFO, Journal
from .link import COMPONENT_ID, Link
from .mission import Mission
from .mission_protocol import MissionService
from .offboard import Offboard
from .params import Params
from .telemetry import Telemetry

FORCE_MAGIC = 21196  # param2 of MAV_CMD_COMPONENT_ARM_DISARM that overrides safety checks
INT32_MAX = 2**31 - 1
GLOBAL_FRAMES = (mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                 mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
RELATIVE_FRAMES = (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)

COMMAND_NAMES = {v: k[len("MAV_CMD_"):] for k, v in vars(mavlink).items() if k.startswith("MAV_CMD_")
                 and isinstance(v, int)}
RESULT_NAMES = {v: k[len("MAV_RESULT_"):] for k, v in vars(mavlink).items() if k.startswith("MAV_RESULT_")
                and isinstance(v, int)}

Params7 = tuple[float, float, float, float, float, float, float]
# (MAV_RESULT, a message to send after the COMMAND_ACK or None)
Reply = tuple[int, object | None]
# A command's seven parameters and, for COMMAND_INT, its frame (None for COMMAND_LONG,
# whose x and y are degrees as floats rather than degrees * 1e7).
CommandHandler = Callable[[Params7, int | None], Reply]


def _given(value: float) -> float | None:
    """A float parameter, or None where MAVLink's NaN means "not given"."""
    return value if math.isfinite(value) else None


class Commands:
    """Routes each incoming message to its handler."""

    def __init__(self, config: VehicleConfig, link: Link, journal: Journal, autopilot: Autopilot,
                 telemetry: Telemetry, params: Params, offboard: Offboard, datalink: Datalink, mission: Mission,
                 mission_service: MissionService):
        self._config = config
        self._link = link
        self._journal = journal
        self._autopilot = autopilot
        self._telemetry = telemetry
        self._mission = mission
        m = mavlink
        self._commands: dict[int, CommandHandler] = {
            m.MAV_CMD_COMPONENT_ARM_DISARM: self._arm_disarm,
            m.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            m.MAV_CMD_NAV_LAND: lambda p, frame: (autopilot.land(), None),
            m.MAV_CMD_NAV_RETURN_TO_LAUNCH: lambda p, frame: (autopilot.rtl(), None),
            m.MAV_CMD_MISSION_START: lambda p, frame: (autopilot.start_mission(), None),
            m.MAV_CMD_DO_SET_MISSION_CURRENT: self._set_mission_current,
            m.MAV_CMD_DO_REPOSITION: self._reposition,
            m.MAV_CMD_DO_SET_MODE: self._do_set_mode,
            m.MAV_CMD_NAV_LOITER_UNLIM: lambda p, frame: (autopilot.loiter(), None),
            m.MAV_CMD_DO_CHANGE_SPEED: lambda p, frame: (autopilot.change_speed(int(p[0]), p[1]), None),
            m.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            m.MAV_CMD_GET_HOME_POSITION:  # deprecated for REQUEST_MESSAGE, still sent by MAVProxy
                lambda p, frame: (m.MAV_RESULT_ACCEPTED, telemetry.message(m.MAVLINK_MSG_ID_HOME_POSITION)),
            m.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
                lambda p, frame: (m.MAV_RESULT_ACCEPTED, telemetry.message(m.MAVLINK_MSG_ID_AUTOPILOT_VERSION)),
            m.MAV_CMD_SET_MESSAGE_INTERVAL: lambda p, frame: (telemetry.set_interval(p[0], p[1]), None),
            m.MAV_CMD_GET_MESSAGE_INTERVAL: self._get_message_interval,
        }
        # Everything else from a ground station needs no answer.
        self._messages: dict[str, Callable[[object], None]] = {
            "HEARTBEAT": datalink.on_heartbeat,
            **{name: self._to_component(h) for name, h in mission_service.handlers.items()},
            "COMMAND_LONG": self._to_component(self._command_long),
            "COMMAND_INT": self._to_component(self._command_int),
            "PARAM_REQUEST_READ": self._to_component(params.on_request_read),
            "PARAM_REQUEST_LIST": self._to_component(params.on_request_list),
            "PARAM_SET": self._to_component(params.on_set),
            "SET_POSITION_TARGET_LOCAL_NED": self._to_component(offboard.on_setpoint),
            "SET_POSITION_TARGET_GLOBAL_INT": self._to_component(offboard.on_global_setpoint),
            "SET_MODE": self._to_system(self._set_mode),
            "TIMESYNC": self._timesync,
            "PING": self._ping,
        }

    def handle(self, msg) -> None:
        handler = self._messages.get(msg.get_type())
        if handler is not None:
            handler(msg)

    # --- addressing ----------------------------------------------------------------------

    def _to_system(self, handler: Callable[[object], None]) -> Callable[[object], None]:
        """`handler`, for messages addressed to this system or broadcast."""
        def addressed(msg) -> None:
            if msg.target_system in (0, self._config.system_id):
                handler(msg)
        return addressed

    def _to_component(self, handler: Callable[[object], None]) -> Callable[[object], None]:
        """`handler`, for messages addressed to this autopilot or broadcast; another
        component's command is not ours to answer."""
        def addressed(msg) -> None:
            if msg.target_component in (0, COMPONENT_ID):
                handler(msg)
        return self._to_system(addressed)

    # --- messages ------------------------------------------------------------------------

    def _command_long(self, msg) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        self._command(msg, params, None)

    def _command_int(self, msg) -> None:
        params = (msg.param1, msg.param2, msg.param3, msg.param4, msg.x, msg.y, msg.z)
        self._command(msg, params, msg.frame)

    def _command(self, msg, params: Params7, frame: int | None) -> None:
        command = msg.command
        handler = self._commands.get(command)
        said = len(self._journal.said)
        try:
            result, follow_up = handler(params, frame) if handler else (mavlink.MAV_RESULT_UNSUPPORTED, None)
        except (ValueError, OverflowError, TypeError) as exc:  # e.g. NaN where an integer belongs
            self._link.bad(f"command {command} with unusable parameters: {exc}")
            result, follow_up = mavlink.MAV_RESULT_FAILED, None
        if result != mavlink.MAV_RESULT_ACCEPTED and len(self._journal.said) == said:
            # every refusal is said, with its reason where the handler gave one
            self._journal.say(CRITICAL, f"Command {COMMAND_NAMES.get(command, command)} refused: "
                                        f"{RESULT_NAMES.get(result, result)}")
        self._link.reply(self._link.encoder.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(),
                                                               msg.get_srcComponent()))
        if follow_up is not None:
            self._link.reply(follow_up)

    def _set_mode(self, msg) -> None:
        if msg.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            self._autopilot.set_mode((msg.custom_mode >> 16) & 0xFF, (msg.custom_mode >> 24) & 0xFF)

    def _timesync(self, msg) -> None:
        if msg.tc1 == 0:  # a request; answering lets a client estimate our clock offset
            self._link.reply(self._link.encoder.timesync_encode(time.monotonic_ns(), msg.ts1))

    def _ping(self, msg) -> None:
        if msg.target_system == 0 and msg.target_component == 0:  # a request, not someone's reply
            self._link.reply(self._link.encoder.ping_encode(msg.time_usec, msg.seq, msg.get_srcSystem(),
                                                           msg.get_srcComponent()))

    # --- commands ------------------------------------------------------------------------

    def _arm_disarm(self, p: Params7, frame: int | None) -> Reply:
        if p[0] not in (0.0, 1.0):
            return mavlink.MAV_RESULT_DENIED, None
        force = math.isfinite(p[1]) and int(p[1]) == FORCE_MAGIC
        return self._autopilot.arm(p[0] == 1.0, force), None

    def _takeoff(self, p: Params7, frame: int | None) -> Reply:
        return self._autopilot.takeoff(self._takeoff_altitude(_given(p[6])), _given(p[3])), None

    def _takeoff_altitude(self, param7: float | None) -> float | None:
        """PX4 reads param7 as AMSL. MAVProxy's `takeoff 10` (ArduPilot's convention) sends 10 m
        above home, which as AMSL lies far below home: PX4 would then climb only to
        MIS_TAKEOFF_ALT. A value below home cannot be meant as AMSL, so it is taken as relative."""
        if param7 is None:
            return None
        home = self._config.home_alt_m
        if param7 >= home:
            return param7 - home
        self._journal.say(INFO, f"Takeoff altitude {param7:g} m is below home ({home:g} m AMSL): "
                                f"taken as {param7:g} m above home")
        return param7

    def _set_mission_current(self, p: Params7, frame: int | None) -> Reply:
        if not (math.isfinite(p[0]) and self._mission.set_current(int(p[0]))):
            self._journal.say(CRITICAL, f"Mission item {p[0]:g} does not exist: current item unchanged")
            return mavlink.MAV_RESULT_DENIED, None
        return mavlink.MAV_RESULT_ACCEPTED, None

    def _do_set_mode(self, p: Params7, frame: int | None) -> Reply:
        if not int(p[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_DENIED, None
        return self._autopilot.set_mode(int(p[1]), int(p[2])), None

    def _request_message(self, p: Params7, frame: int | None) -> Reply:
        msg = self._telemetry.message(int(p[0])) if math.isfinite(p[0]) else None
        if msg is None:
            return mavlink.MAV_RESULT_UNSUPPORTED, None
        return mavlink.MAV_RESULT_ACCEPTED, msg

    def _get_message_interval(self, p: Params7, frame: int | None) -> Reply:
        msg = self._telemetry.interval(p[0])
        if msg is None:
            return mavlink.MAV_RESULT_DENIED, None
        return mavlink.MAV_RESULT_ACCEPTED, msg

    def _reposition(self, p: Params7, frame: int | None) -> Reply:
        if not self._autopilot.armed:
            # refused before the target is looked at, as PX4 does; the autopilot checks again
            # with the move itself
            return mavlink.MAV_RESULT_DENIED, None
        cfg = self._config
        if frame is None:  # COMMAND_LONG: degrees as floats, NaN = keep
            lat, lon, alt = p[4], p[5], p[6]
            has_xy = math.isfinite(lat) and math.isfinite(lon)
            relative = False
        else:  # COMMAND_INT: degrees * 1e7, INT32_MAX = keep
            if frame not in GLOBAL_FRAMES:
                return mavlink.MAV_RESULT_UNSUPPORTED, None
            has_xy = p[4] != INT32_MAX and p[5] != INT32_MAX
            lat, lon, alt = p[4] / 1e7, p[5] / 1e7, p[6]
            relative = frame in RELATIVE_FRAMES
        north = east = down = None
        if has_xy:
            if not cfg.gps:
                self._journal.say(CRITICAL, "Reposition denied: no global position (no GPS)")
                return mavlink.MAV_RESULT_DENIED, None
            if not (abs(lat) <= 90 and abs(lon) <= 180):
                return mavlink.MAV_RESULT_DENIED, None
            north, east = geo_to_ned(lat, lon, cfg.home_lat, cfg.home_lon)
        if math.isfinite(alt):
            down = -(alt if relative else alt - cfg.home_alt_m)
        speed = p[0] if math.isfinite(p[0]) and p[0] > 0 else None
        return self._autopilot.reposition(north, east, down, _given(p[3]), speed), None
