"""The one place where Zenoh sessions are configured.

The hub (the UAV agent, or `uav-robots run`'s launcher) is a Zenoh router
listening on an explicit endpoint; the world and the robots are clients that
connect to it. Multicast scouting is always off so that unrelated processes on
the machine are never found (NOTES-transports.md, pitfall 4). A user may pass a
JSON5 file instead (`--zenoh-config`), e.g. for TLS or a remote router.
"""
from __future__ import annotations

import json
from pathlib import Path

from .errors import UavRobotsError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
CONNECT_TIMEOUT_MS = 20_000


def hub_config(listen: list[str]) -> str:
    return json.dumps({
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}, "delay": 0},
    })


def client_config(connect: list[str], timeout_ms: int = CONNECT_TIMEOUT_MS, lease_ms: int = 3000) -> str:
    return json.dumps({
        "mode": "client",
        "connect": {"endpoints": connect, "timeout_ms": timeout_ms},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tx": {"lease": lease_ms}}},
    })


def config_from_file(path: str | Path) -> str:
    try:
        return Path(path).read_text()
    except OSError as exc:
        raise UavRobotsError(f"cannot read zenoh config {path}: {exc.strerror}") from None
