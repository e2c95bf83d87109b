"""The vehicle's MAVLink link: the connection, framing of what arrives, and sending."""
from __future__ import annotations

import select
import threading
import time
from typing import Callable

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import MissionError

from .config import VehicleConfig
from .journal import Journal

COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1


class Link:
    """One pymavlink connection. `encoder` builds messages, `send` frames and writes them;
    `run` receives until stopped and hands each valid message to a handler."""

    def __init__(self, config: VehicleConfig, lock: threading.RLock, journal: Journal):
        self._config = config
        self._lock = lock
        self._journal = journal
        self._send_lock = threading.Lock()
        self._conn = None
        self.encoder = mavlink.MAVLink(self, config.system_id, COMPONENT_ID)
        self._parser = mavlink.MAVLink(None, 0, 0)
        self._parser.robust_parsing = True
        self._bad_frames = 0

    def open(self) -> None:
        url = self._config.url
        try:
            self._conn = mavutil.mavlink_connection(url, source_system=self._config.system_id,
                                                    source_component=COMPONENT_ID)
        except Exception as exc:  # pymavlink raises anything from ValueError to OSError here
            raise MissionError(f"cannot open the vehicle's MAVLink link {url!r}: {exc}") from None

    def close(self) -> None:
        if self._conn is not None:
            try:
                self._conn.close()
            except OSError:
                pass
            self._conn = None

    @property
    def local_address(self) -> tuple[str, int] | None:
        conn = self._conn
        if conn is None or not isinstance(conn, mavutil.mavudp):
            return None
        try:
            return conn.port.getsockname()[:2]
        except OSError:
            return None

    @property
    def bad_frames(self) -> int:
        with self._lock:
            return self._bad_frames

    def bad(self, text: str) -> None:
        """Count a frame that was not valid MAVLink, or that broke a handler, and say why."""
        with self._lock:
            self._bad_frames += 1
        self._journal.warn(text)

    def send(self, msg) -> None:
        with self._send_lock:
            if self._conn is not None:
                self.encoder.send(msg)

    def write(self, buf: bytes) -> None:
        """Where `encoder` puts finished frames (pymavlink wants a file); callers use `send`."""
        conn = self._conn
        if conn is not None:
            conn.write(buf)

    # --- receive -----------------------------------------------------------------------

    def run(self, stop: threading.Event, handle: Callable[[object], None], greeting: Callable[[], object]) -> None:
        """Receive until `stop`; `handle` gets each valid message, a new peer gets `greeting()`."""
        conn = self._conn
        is_udp = isinstance(conn, mavutil.mavudp)
        while not stop.is_set():
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
                if stop.is_set():
                    return
                continue
            if not data:
                continue
            if isinstance(data, str):
                data = data.encode("latin-1")
            if self._deliver(data, is_udp, handle) and is_udp and conn.udp_server and addr is not None:
                self._learn_peer(conn, addr, greeting)

    def _deliver(self, data: bytes, is_udp: bool, handle: Callable[[object], None]) -> bool:
        """Parse one read's bytes and hand on its messages; whether any was valid MAVLink."""
        try:
            msgs = self._parser.parse_buffer(data) or []
        except Exception as exc:  # the parser should not raise, but a forged frame must never kill us
            msgs = []
            self.bad(f"unparseable bytes ({exc})")
        if is_udp and self._parser.buf_len() > 0:
            # MAVLink frames never span datagrams: a truncated frame left in the buffer
            # would swallow the start of the next datagram.
            self._parser.buf = bytearray()
            self._parser.buf_index = 0
            self._parser.expected_length = mavlink.HEADER_LEN_V1 + 2
            self.bad(f"truncated frame of {len(data)} bytes")
        valid = False
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                self.bad(f"bad MAVLink data: {getattr(msg, 'reason', '?')}")
                continue
            if msg.get_type().startswith("UNKNOWN_"):
                # pymavlink cannot check the CRC of an id it does not know: random bytes
                # pass as such frames now and then, so they are garbage to us
                self.bad(f"frame of unknown type {msg.get_type()}")
                continue
            if msg.get_srcSystem() == self._config.system_id and msg.get_srcComponent() == COMPONENT_ID:
                continue  # our own frames echoed back
            valid = True
            try:
                handle(msg)
            except Exception as exc:  # a well-formed frame with absurd content
                self.bad(f"cannot handle {msg.get_type()}: {type(exc).__name__}: {exc}")
        return valid

    def _learn_peer(self, conn, addr, greeting: Callable[[], object]) -> None:
        # Only a sender of valid MAVLink becomes a peer: garbage must not redirect telemetry.
        new_peer = addr not in conn.clients
        conn.clients.add(addr)
        conn.clients_last_alive[addr] = time.time()
        if new_peer:  # greet it now rather than at the next heartbeat, so it connects at once
            self._journal.event(f"ground station at {addr[0]}:{addr[1]}")
            self.send(greeting())
