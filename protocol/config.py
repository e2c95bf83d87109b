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
from typing import Any

from .errors import UavRobotsError

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
CONNECT_TIMEOUT_MS = 20_000
# A killed process is noticed at once (its TCP link closes); the lease only bounds how long a frozen
# one keeps its session. Longer than a robot's tick deadline, so that a short freeze (a paused process,
# a busy machine) is a stall the UAV repairs, not a lost session the robot must rebuild.
LEASE_MS = 10_000


def hub_dict(listen: list[str]) -> dict[str, Any]:
    return {
        "mode": "router",
        "listen": {"endpoints": listen},
        "scouting": {"multicast": {"enabled": False}, "delay": 0},
    }


# Processes start together, each client before the router it connects to is up: Zenoh's own
# first retry after a second made them (and the launcher's recorder, which then missed the
# take-off) wait that long; from 50 ms, backing off to Zenoh's usual pace for a router that is down.
CONNECT_RETRY = {"period_init_ms": 50, "period_max_ms": 4000, "period_increase_factor": 2}


def client_dict(connect: list[str], timeout_ms: int = CONNECT_TIMEOUT_MS, lease_ms: int = LEASE_MS) -> dict[str, Any]:
    return {
        "mode": "client",
        "connect": {"endpoints": connect, "timeout_ms": timeout_ms, "retry": dict(CONNECT_RETRY)},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"link": {"tx": {"lease": lease_ms}}},
    }


def hub_config(listen: list[str]) -> str:
    return json.dumps(hub_dict(listen))


def client_config(connect: list[str], timeout_ms: int = CONNECT_TIMEOUT_MS, lease_ms: int = LEASE_MS) -> str:
    return json.dumps(client_dict(connect, timeout_ms, lease_ms))


def config_from_file(path: str | Path) -> str:
    try:
        return Path(path).read_text()
    except OSError as exc:
        raise UavRobotsError(f"cannot read zenoh config {path}: {exc.strerror}") from None


def add_session_arguments(p: argparse.ArgumentParser, hub: bool = False) -> None:
    """--connect / --listen / --zenoh-config, the same for every process (`hub`: it listens by default).
    With --zenoh-config, --connect or --listen replaces the file's endpoints: one file serves any address."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="join a Zenoh router at this endpoint" + ("" if hub else f" (default {DEFAULT_ENDPOINT})"))
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="be the Zenoh router, listening here" + (f" (default {DEFAULT_ENDPOINT})" if hub else ""))
    p.add_argument("--zenoh-config", default=None, metavar="FILE",
                   help="a Zenoh JSON5 config file (TLS, access control: see `uav-robots secure init`); "
                        "--connect/--listen then replace its endpoints")
