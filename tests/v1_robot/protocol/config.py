"""The one place where Zenoh sessions are configured.

The hub (the UAV agent, or `uav-robots run`'s launcher) is a Zenoh router
listening on an explicit endpoint; the world and the robots are clients that
connect to it. Multicast scouting is always off so that unrelated processes on
the machine are never found (docs/protocol.md, *Sessions*). A user may pass a
JSON5 file instead (`--zenoh-config`), e.g. for TLS or a remote router.
"""
from __future__ import annotations

import argparse
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


def session_config(listen: list[str] | None = None, connect: list[str] | None = None,
                   config_file: str | Path | None = None) -> str:
    """What every process opens: a config file if given, else a router on `listen`, else a client of
    `connect` (default: the hub on this machine)."""
    if listen and connect:
        raise UavRobotsError("give --connect or --listen, not both")
    if config_file:
        return config_from_file(config_file)
    if listen:
        return hub_config(listen)
    return client_config(connect or [DEFAULT_ENDPOINT])


def describe_session(listen: list[str] | None = None, connect: list[str] | None = None,
                     config_file: str | Path | None = None) -> str:
    if config_file:
        return f"config {config_file}"
    if listen:
        return f"listening on {','.join(listen)}"
    return f"connected to {','.join(connect or [DEFAULT_ENDPOINT])}"


def add_session_arguments(p: argparse.ArgumentParser, hub: bool = False) -> None:
    """--connect / --listen / --zenoh-config, the same for every process (`hub`: it listens by default)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="join a Zenoh router at this endpoint" + ("" if hub else f" (default {DEFAULT_ENDPOINT})"))
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="be the Zenoh router, listening here" + (f" (default {DEFAULT_ENDPOINT})" if hub else ""))
    g.add_argument("--zenoh-config", default=None, metavar="FILE",
                   help="a Zenoh JSON5 config file instead (TLS, access control, a remote router)")
