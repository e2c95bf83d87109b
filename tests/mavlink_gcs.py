"""A minimal ground station for tests: pymavlink's MAVLink 2 codec over a plain UDP socket,
optionally signing what it sends and sending heartbeats like a real ground station."""
from __future__ import annotations

import socket
import struct
import threading
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

GCS_SYSID, GCS_COMPID = 245, 190


class Client:
    """Talks to a vehicle at 127.0.0.1:`port` (or, with `port` None, listens on `listen` for a
    vehicle that sends to it, like QGroundControl on 14550)."""

    def __init__(self, port: int | None, system_id: int = GCS_SYSID, key: bytes | None = None,
                 heartbeat_hz: float = 0.0, listen: int = 0):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", listen))
        self.dest = ("127.0.0.1", port) if port is not None else None
        self.mav = mavlink.MAVLink(self, system_id, GCS_COMPID)
        self.parser = mavlink.MAVLink(None, 0, 0)
        self.parser.robust_parsing = True
        if key is not None:  # sign what it sends, and check what it receives
            for mav in (self.mav, self.parser):
                mav.signing.secret_key = key
                mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)
            self.mav.signing.sign_outgoing = True
        self.pending: list = []
        self.statustexts: list = []  # every STATUSTEXT received, whatever was being waited for
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._beat = None
        if port is not None:
            self.heartbeat()
        if heartbeat_hz > 0:
            self._beat = threading.Thread(target=self._beating, args=(1.0 / heartbeat_hz,), daemon=True)
            self._beat.start()

    def heartbeat(self) -> None:
        self.send(self.mav.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))

    def stop_heartbeats(self) -> None:
        self._stop.set()
        if self._beat is not None:
            self._beat.join(2.0)

    def _beating(self, period: float) -> None:
        while not self._stop.wait(period):
            if self.dest is not None:
                self.heartbeat()

    def write(self, buf: bytes) -> None:
        if self.dest is not None:
            self.sock.sendto(buf, self.dest)

    def send(self, msg) -> None:
        with self._lock:
            self.mav.send(msg)

    def recv(self, kind: str | tuple[str, ...], timeout: float = 3.0, cond=lambda m: True):
        """The next message of type `kind` satisfying `cond`; fails the test on timeout."""
        msg = self.poll(kind, timeout, cond)
        if msg is None:
            pytest.fail(f"no {kind} within {timeout} s")
        return msg

    def poll(self, kind: str | tuple[str, ...], timeout: float, cond=lambda m: True):
        """The next message of type `kind` (or one of the types) satisfying `cond`, or None after `timeout` s."""
        kinds = (kind,) if isinstance(kind, str) else kind
        deadline = time.monotonic() + timeout
        while True:
            while self.pending:
                msg = self.pending.pop(0)
                if msg.get_type() in kinds and cond(msg):
                    return msg
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            self.sock.settimeout(remaining)
            try:
                data, addr = self.sock.recvfrom(65535)
            except socket.timeout:
                continue
            if self.dest is None:
                self.dest = addr  # a listening ground station answers whoever called it
            msgs = self.parser.parse_buffer(data) or []
            self.statustexts += [msg for msg in msgs if msg.get_type() == "STATUSTEXT"]
            self.pending.extend(msgs)

    def said(self, words: str, timeout: float = 3.0):
        """The first STATUSTEXT received (now or within `timeout`) that contains `words`."""
        deadline = time.monotonic() + timeout
        while True:
            texts = self.texts()
            found = next((msg for msg, text in texts if words in text), None)
            if found is not None:
                return found
            if time.monotonic() > deadline:
                pytest.fail(f"no STATUSTEXT with {words!r} within {timeout} s: {[t for _, t in texts]}")
            self.poll("STATUSTEXT", 0.05)

    def texts(self) -> list:
        """(first chunk, whole text) of every STATUSTEXT received: a long text's 50-character chunks share
        a nonzero `id` (MAVLink 2), and are joined here as a ground station joins them."""
        whole: list = []
        open_ids: dict[int, int] = {}
        for msg in self.statustexts:
            ident = getattr(msg, "id", 0)
            if ident and ident in open_ids:
                i = open_ids[ident]
                whole[i] = (whole[i][0], whole[i][1] + msg.text)
                continue
            if ident:
                open_ids[ident] = len(whole)
            whole.append((msg, msg.text))
        return whole

    def command(self, command: int, *params: float, target_component: int = 1, timeout: float = 3.0) -> int:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(self.mav.command_long_encode(1, target_component, command, 0, *p))
        return self.recv("COMMAND_ACK", timeout, cond=lambda m: m.command == command).result

    def close(self) -> None:
        self.stop_heartbeats()
        self.sock.close()


def set_param(client: Client, name: str, value: float) -> float:
    """PARAM_SET (as a REAL32, a script's habit) and the vehicle's echo: the value it stored, read by
    the echo's own type (an INT32 travels bytewise, as PX4 sends it)."""
    client.send(client.mav.param_set_encode(1, 1, name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32))
    return param_value(client.recv("PARAM_VALUE", cond=lambda m: m.param_id == name))


def param_value(msg) -> float:
    """A PARAM_VALUE's value by its type: an INT32's four bytes are in the float field (PX4's bytewise encoding)."""
    if msg.param_type == mavlink.MAV_PARAM_TYPE_INT32:
        return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
    return msg.param_value


def set_mode(client: Client, main: int, sub: int = 0) -> int:
    """DO_SET_MODE to PX4 mode (main, sub)."""
    return client.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)


def px4_mode(heartbeat) -> tuple[int, int]:
    return (heartbeat.custom_mode >> 16) & 0xFF, (heartbeat.custom_mode >> 24) & 0xFF


def wait_for(predicate, timeout: float = 5.0, what: str = "condition") -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"{what} not met within {timeout} s")
        time.sleep(0.01)
