"""The vehicle's MAVLink links: the flight link and an optional ground-station link, framing of
what arrives, signing, and sending.

Every socket is bound to `config.bind_host` (loopback unless the operator opens it on
purpose): a `udpout` socket left unbound would take 0.0.0.0 at its first send and accept
commands from any host that finds its port.

The flight link (channel "vehicle") answers its companion only, as a serial link to a
companion computer would: the system `config.companion_system_id`, or the first system whose
valid MAVLink arrives (for `udpout`, from the address the link sends to), bound to the address it
sent from. Another process's frames there, however well formed (an unsigned force-disarm), are
refused and counted (`refused_strangers`), and each new stranger is said as STATUSTEXT. The
ground-station link stays open to several ground stations; signing guards it.
"""
from __future__ import annotations

import select
import socket
import threading
import time
from dataclasses import dataclass, field
from typing import Callable

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import MissionError

from .config import VehicleConfig
from .journal import CRITICAL, Journal
from .link_loss import LinkLoss

COMPONENT_ID = mavlink.MAV_COMP_ID_AUTOPILOT1
SIGNING_EPOCH = 1420070400  # MAVLink 2 signing timestamps count 10 us units from 2015-01-01
STRANGERS_SAID = 16  # strangers named in a STATUSTEXT each; the rest are counted and warned about


def signing_timestamp() -> int:
    """Now, as a MAVLink 2 signing timestamp."""
    return int((max(time.time(), SIGNING_EPOCH) - SIGNING_EPOCH) * 100_000)


@dataclass
class Channel:
    """One pymavlink connection with its own framing (sequence numbers, signing) and parser."""

    name: str
    url: str
    key: bytes | None
    conn: object = None
    packer: object = None
    parser: object = None
    refused_unsigned: int = 0
    lock: threading.Lock = field(default_factory=threading.Lock)

    def write(self, buf: bytes) -> None:
        """Where `packer` puts finished frames (pymavlink wants a file)."""
        conn = self.conn
        if conn is not None:
            conn.write(buf)


class Link:
    """The vehicle's connections. `encoder` builds messages; `send` frames them for every
    channel (telemetry, STATUSTEXT), `reply` only for the channel whose message is being
    handled; `run` receives until stopped and hands each valid message to a handler."""

    def __init__(self, config: VehicleConfig, lock: threading.RLock, journal: Journal):
        self._config = config
        self._lock = lock
        self._journal = journal
        self.encoder = mavlink.MAVLink(None, config.system_id, COMPONENT_ID)  # a message factory only
        self.channels = [Channel("vehicle", config.url, None)]
        if config.gcs_url:
            self.channels.append(Channel("gcs", config.gcs_url, config.signing_key))
        if config.pose_url:
            self.channels.append(Channel("pose", config.pose_url, None))
        self._handling = threading.local()
        self._bad_frames = 0
        self._companion: tuple[int, object] | None = None  # (system id, address) the flight link answers
        self._strangers: set[tuple[int, object]] = set()
        self._refused_strangers = 0
        self.loss: LinkLoss | None = None   # the fault mavlink-loss: the flight link's window of silence

    def open(self) -> None:
        try:
            for ch in self.channels:
                self._open(ch)
        except MissionError:
            self.close()
            raise

    def _open(self, ch: Channel) -> None:
        cfg = self._config
        try:
            ch.conn = mavutil.mavlink_connection(ch.url, source_system=cfg.system_id, source_component=COMPONENT_ID)
            if isinstance(ch.conn, mavutil.mavudp) and not ch.conn.udp_server:
                ch.conn.port.bind((cfg.bind_host, 0))
        except Exception as exc:  # pymavlink raises anything from ValueError to OSError here
            raise MissionError(f"cannot open the vehicle's MAVLink link {ch.url!r}: {exc}") from None
        ch.packer = mavlink.MAVLink(ch, cfg.system_id, COMPONENT_ID)
        ch.parser = mavlink.MAVLink(None, 0, 0)
        ch.parser.robust_parsing = True
        if ch.key is not None:
            for mav in (ch.packer, ch.parser):
                mav.signing.secret_key = ch.key
                mav.signing.timestamp = signing_timestamp()
            ch.packer.signing.sign_outgoing = True
            ch.parser.signing.allow_unsigned_callback = lambda mav, msg_id, ch=ch: self._refuse_unsigned(ch, msg_id)

    def close(self) -> None:
        for ch in self.channels:
            if ch.conn is not None:
                try:
                    ch.conn.close()
                except OSError:
                    pass
                ch.conn = None

    def address(self, name: str = "vehicle") -> tuple[str, int] | None:
        """The (host, port) channel `name`'s UDP socket is bound to, once open."""
        conn = next((ch.conn for ch in self.channels if ch.name == name), None)
        if conn is None or not isinstance(conn, mavutil.mavudp):
            return None
        try:
            return conn.port.getsockname()[:2]
        except OSError:
            return None

    @property
    def local_address(self) -> tuple[str, int] | None:
        return self.address("vehicle")

    @property
    def bad_frames(self) -> int:
        with self._lock:
            return self._bad_frames

    @property
    def refused_strangers(self) -> int:
        """Valid frames the flight link refused because they came from another system or address than its companion."""
        with self._lock:
            return self._refused_strangers

    @property
    def companion(self) -> tuple[int, object] | None:
        """(system id, address) of the flight link's companion, once it has spoken."""
        with self._lock:
            return self._companion

    @property
    def refused_unsigned(self) -> int:
        """Frames refused on a signed channel because they were unsigned or wrongly signed."""
        with self._lock:
            return sum(ch.refused_unsigned for ch in self.channels)

    def bad(self, text: str) -> None:
        """Count a frame that was not valid MAVLink, or that broke a handler, and say why."""
        with self._lock:
            self._bad_frames += 1
        self._journal.warn(text)

    def _refuse_unsigned(self, ch: Channel, msg_id: int) -> bool:
        with self._lock:
            ch.refused_unsigned += 1
        self._journal.warn(f"{ch.name} link: refused an unsigned or wrongly signed frame (message id {msg_id})")
        return False

    # --- send --------------------------------------------------------------------------

    def send(self, msg, channel: Channel | None = None) -> None:
        """Frame and send `msg` on `channel`, or on every channel."""
        for ch in (channel,) if channel is not None else self.channels:
            if self._lost(ch):
                continue
            with ch.lock:
                if ch.conn is not None:
                    ch.packer.send(msg)

    def _lost(self, ch: Channel) -> bool:
        """Whether what goes over `ch` now is lost (the flight link, in an injected loss's window)."""
        return ch.name == "vehicle" and self.loss is not None and self.loss.down()

    def reply(self, msg) -> None:
        """Send `msg` on the channel whose message is being handled (all of them outside a handler)."""
        self.send(msg, self.current)

    @property
    def current(self) -> Channel | None:
        """The channel whose message this thread is handling, None outside a handler."""
        return getattr(self._handling, "channel", None)

    def say(self, severity: int, text: str) -> None:
        """STATUSTEXT on every channel; texts longer than the field go in numbered chunks."""
        data = text.encode("utf-8", "replace")
        chunks = [data[i:i + 50] for i in range(0, len(data), 50)] or [b""]
        ident = (hash(text) & 0xFFFF or 1) if len(chunks) > 1 else 0
        for seq, chunk in enumerate(chunks):
            self.send(self.encoder.statustext_encode(severity, chunk, ident, seq))

    # --- receive -----------------------------------------------------------------------

    def run(self, stop: threading.Event, handle: Callable[[object], None], greeting: Callable[[], object]) -> None:
        """Receive until `stop`; `handle` gets each valid message, a new peer gets `greeting()`."""
        by_fd = {ch.conn.fd: ch for ch in self.channels if ch.conn is not None}
        while not stop.is_set():
            try:
                readable, _, _ = select.select(list(by_fd), [], [], 0.1)
            except (OSError, ValueError):
                return  # closed under us
            for fd in readable:
                if not self._receive(by_fd[fd], handle, greeting) and stop.is_set():
                    return

    def _receive(self, ch: Channel, handle: Callable[[object], None], greeting: Callable[[], object]) -> bool:
        """Read one datagram (or stream chunk) of `ch`; False if its socket failed."""
        conn = ch.conn
        if conn is None:
            return False
        is_udp = isinstance(conn, mavutil.mavudp)
        try:
            if is_udp:
                data, addr = conn.port.recvfrom(65535)
            else:
                data, addr = conn.recv(4096), None
        except (BlockingIOError, ConnectionRefusedError, InterruptedError):
            return True  # ICMP port unreachable from a udpout peer that is not up yet
        except OSError:
            return False
        if not data or self._lost(ch):   # read, then lost: the sender's socket sees nothing wrong
            return True
        if isinstance(data, str):
            data = data.encode("latin-1")
        self._handling.channel = ch
        try:
            valid = self._deliver(ch, data, is_udp, handle, addr)
        finally:
            self._handling.channel = None
        if valid and is_udp and conn.udp_server and addr is not None:
            self._learn_peer(ch, addr, greeting)
        return True

    def _deliver(self, ch: Channel, data: bytes, is_udp: bool, handle: Callable[[object], None], addr=None) -> bool:
        """Parse one read's bytes and hand on its messages; whether any was valid MAVLink from a
        sender this channel answers."""
        parser = ch.parser
        try:
            msgs = parser.parse_buffer(data) or []
        except Exception as exc:  # the parser should not raise, but a forged frame must never kill us
            msgs = []
            self.bad(f"unparseable bytes ({exc})")
        if is_udp and parser.buf_len() > 0:
            # MAVLink frames never span datagrams: a truncated frame left in the buffer
            # would swallow the start of the next datagram.
            parser.buf = bytearray()
            parser.buf_index = 0
            parser.expected_length = mavlink.HEADER_LEN_V1 + 2
            self.bad(f"truncated frame of {len(data)} bytes")
        valid = False
        for msg in msgs:
            if msg.get_type() == "BAD_DATA":
                if "signature" not in str(getattr(msg, "reason", "")):  # those are counted as refused
                    self.bad(f"bad MAVLink data: {getattr(msg, 'reason', '?')}")
                continue
            if msg.get_type().startswith("UNKNOWN_"):
                # pymavlink cannot check the CRC of an id it does not know: random bytes
                # pass as such frames now and then, so they are garbage to us
                self.bad(f"frame of unknown type {msg.get_type()}")
                continue
            if msg.get_srcSystem() == self._config.system_id and msg.get_srcComponent() == COMPONENT_ID:
                continue  # our own frames echoed back
            if ch.name == "vehicle" and not self._admit(ch, msg.get_srcSystem(), addr):
                continue
            if ch.name == "pose" and not self._from_peer(ch, addr):
                # the pose reader's link answers the reader it sends to, not any process that finds its port
                self._refuse_stranger(msg.get_srcSystem(), addr, "pose link", "not its reader")
                continue
            valid = True
            try:
                handle(msg)
            except Exception as exc:  # a well-formed frame with absurd content
                self.bad(f"cannot handle {msg.get_type()}: {type(exc).__name__}: {exc}")
        return valid

    def _admit(self, ch: Channel, system: int, addr) -> bool:
        """Whether the flight link answers `system` at `addr`: its companion, or the first to speak
        (the configured system id; for `udpout`, from the address the link sends to)."""
        with self._lock:
            companion = self._companion
            if companion is None:
                wanted = self._config.companion_system_id
                if (wanted is None or system == wanted) and self._from_peer(ch, addr):
                    self._companion = (system, addr)
                    where = f" at {addr[0]}:{addr[1]}" if addr else ""
                    self._journal.event(f"companion: system {system}{where} on the flight link")
                    return True
            elif companion == (system, addr):
                return True
        self._refuse_stranger(system, addr, "flight link", "not the companion")
        return False

    def _refuse_stranger(self, system: int, addr, link: str, why: str) -> None:
        with self._lock:
            self._refused_strangers += 1
            stranger = (system, addr)
            new = stranger not in self._strangers and len(self._strangers) < STRANGERS_SAID
            if new:
                self._strangers.add(stranger)
        where = f" at {addr[0]}:{addr[1]}" if addr else ""
        if new:
            self._journal.say(CRITICAL, f"{link.capitalize()}: refused system {system}{where}, {why}")
        else:
            self._journal.warn(f"{link}: refused a frame from system {system}{where} ({why})")

    @staticmethod
    def _from_peer(ch: Channel, addr) -> bool:
        """For a `udpout` link, whether `addr` is the address it sends to; any address otherwise."""
        conn = ch.conn
        if addr is None or not isinstance(conn, mavutil.mavudp) or conn.udp_server:
            return True
        host, port = conn.destination_addr
        try:
            host = socket.gethostbyname(host)
        except OSError:
            return False
        return (host, port) == tuple(addr[:2])

    def _learn_peer(self, ch: Channel, addr, greeting: Callable[[], object]) -> None:
        # Only a sender of valid MAVLink becomes a peer: garbage must not redirect telemetry.
        conn = ch.conn
        new_peer = addr not in conn.clients
        conn.clients.add(addr)
        conn.clients_last_alive[addr] = time.time()
        if new_peer:  # greet it now rather than at the next heartbeat, so it connects at once
            self._journal.event(f"ground station at {addr[0]}:{addr[1]} on the {ch.name} link")
            self.send(greeting(), ch)
