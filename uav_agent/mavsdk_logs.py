"""MAVSDK's own log lines, routed: its warnings and errors become the UAV's throttled warning
lines, its debug and info lines are dropped (MAVSDK prints them to stdout by default)."""
from __future__ import annotations

import threading

from mavsdk.logging import LogLevel, log_subscribe

from protocol.log import Throttled

_log_installed = threading.Lock()
_log_routed = False


def route_mavsdk_logs() -> None:
    """MAVSDK's own warnings and errors as the UAV's throttled warning lines, once; its debug and
    info lines not at all (it prints them to stdout by default). What it logs can quote anything
    a stranger sends to the MAVLink port (500 PARAM_SETs were 500 lines, with the sender's bytes)."""
    global _log_routed
    with _log_installed:
        if _log_routed:
            return
        warn = Throttled("uav: MAVSDK")

        def forward(level, message, file, line):
            if level in (LogLevel.WARN, LogLevel.ERROR):
                warn(message)
            return True  # suppress MAVSDK's default printing

        log_subscribe(forward)
        _log_routed = True
