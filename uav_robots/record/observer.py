"""An observer of a fleet: one more Zenoh client that records everything published under the fleet's prefix.

It needs no hook inside the processes it watches. The subscriber's callback only appends (receive time,
key, payload) to a list, so a slow consumer never holds back a publisher; decoding happens afterwards.
"""
from __future__ import annotations

import secrets
import sys
import threading
import time
from dataclasses import dataclass

from protocol.keys import Keys
from protocol.transport import Transport, open_session


@dataclass(frozen=True)
class Sample:
    time_ns: int        # wall clock at reception (the log time of a recording)
    key: str
    payload: bytes


class Observer:
    def __init__(self, endpoint: str, fleet: str, wait_s: float = 20.0, config_file: str | None = None) -> None:
        self.keys = Keys(fleet)
        self._lock = threading.Lock()
        self.samples: list[Sample] = []
        self._flying = threading.Event()
        self._transport: Transport | None = open_session("observer", connect=[endpoint], config_file=config_file,
                                                         wait_s=wait_s)
        self._transport.subscribe(f"{self.keys.prefix}/**", self._on_sample)
        # Listening from here on: a UAV started with --observers waits for this before its first status.
        self._transport.announce(self.keys.alive_observer(secrets.token_hex(4)))

    def _on_sample(self, key: str, payload: bytes) -> None:
        with self._lock:
            self.samples.append(Sample(time.time_ns(), key, payload))
        if key == self.keys.uav_pose:
            self._flying.set()

    def flying(self) -> bool:
        """True once the UAV has published a pose: it does so from its take-off on."""
        return self._flying.is_set()

    def since(self, i: int) -> list[Sample]:
        """Samples received after the first `i` (a reader keeps its own position)."""
        with self._lock:
            return self.samples[i:]

    def close(self) -> list[Sample]:
        """Stop listening; every sample received, in arrival order. Must be called: an open session's
        thread keeps the process from exiting."""
        transport, self._transport = self._transport, None
        if transport is not None:
            try:
                transport.close()
            except Exception as exc:  # noqa: BLE001 - what it recorded is kept all the same
                print(f"uav-robots: the observer's session did not close cleanly: {exc}", file=sys.stderr, flush=True)
        with self._lock:
            return list(self.samples)
