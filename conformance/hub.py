"""The conformance hub: a Zenoh router session of its own, on a free loopback port, for one fleet."""
from __future__ import annotations

import socket

from protocol.config import hub_config
from protocol.errors import MissionError
from protocol.keys import Keys, new_fleet_name
from protocol.transport import Transport, ZenohTransport


def free_endpoint() -> str:
    """A loopback TCP endpoint on a port the kernel just had free (bind port 0, then release)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


class Hub:
    """A Zenoh router session on a free loopback port (or on `endpoint`), for one fleet."""

    def __init__(self, fleet: str | None = None, attempts: int = 5, endpoint: str | None = None) -> None:
        self.fleet = fleet or new_fleet_name()
        self.keys = Keys(self.fleet)
        last: Exception | None = None
        for _ in range(1 if endpoint else attempts):
            self.endpoint = endpoint or free_endpoint()
            try:
                self.transport: Transport = ZenohTransport(hub_config([self.endpoint]), "conformance hub")
                return
            except MissionError as exc:  # the port was taken between probe and bind: try another
                last = exc
        raise MissionError(f"no free port for a Zenoh router after {attempts} attempts: {last}")

    def close(self) -> None:
        self.transport.close()

    def __enter__(self) -> "Hub":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
