"""The robot's puts as the router got them, congestion control included."""
from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from .waiter import Waiter

if TYPE_CHECKING:
    from .hub import Hub


class Wire(Waiter):
    """Every put of the robot(s) under test as the router got it: (key, payload, congestion control), in order.

    Read from the router's own session, below `protocol.transport`: the congestion control a put was
    sent with travels with it (docs/protocol.md, QoS) and only a Zenoh sample shows it.
    """
    SUFFIXES = ("/ack", "/state", "/done", "/states")

    def __init__(self, hub: "Hub") -> None:
        super().__init__()
        self.puts: list[tuple[str, bytes, str]] = []
        self._ahead = f"{hub.keys.prefix}/world/ahead/"
        self._sub = hub.transport.session.declare_subscriber(f"{hub.keys.prefix}/**", self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        key = str(sample.key_expr)
        if key.endswith(self.SUFFIXES) or key.startswith(self._ahead):
            with self.cv:
                self.puts.append((key, sample.payload.to_bytes(), str(sample.congestion_control).rsplit(".", 1)[-1]))
                self.cv.notify_all()

    def order(self) -> list[tuple[str, int]]:
        """(key, tick or -1) of each put, in the order the router got them."""
        out = []
        with self.cv:
            for key, payload, _cc in self.puts:
                try:
                    tick = json.loads(payload).get("tick", -1)
                except (ValueError, AttributeError):
                    tick = -1
                out.append((key, tick if isinstance(tick, int) else -1))
        return out

    def count(self, key: str, tick: int = -1) -> int:
        """How many puts on `key` (naming `tick`, -1 for any) the router got."""
        return sum(1 for item in self.order() if item[0] == key and (tick == -1 or item[1] == tick))

    def close(self) -> None:
        self._sub.undeclare()
