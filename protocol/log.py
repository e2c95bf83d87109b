"""Warning lines that a flood of bad input cannot turn into a flood of output."""
from __future__ import annotations

import sys
import threading
import time


class Throttled:
    """At most one line per `interval_s` to stderr; the lines held back are counted and said in the next."""

    def __init__(self, prefix: str, interval_s: float = 1.0) -> None:
        self.prefix = prefix
        self.interval_s = interval_s
        self.count = 0            # every warning, shown or not
        self._held = 0
        self._last = -float("inf")
        self._lock = threading.Lock()

    def __call__(self, text: str) -> None:
        now = time.monotonic()
        with self._lock:
            self.count += 1
            if now - self._last < self.interval_s:
                self._held += 1
                return
            held, self._held, self._last = self._held, 0, now
        more = f" ({held} more held back)" if held else ""
        print(f"warning: {self.prefix}: {text}{more}", file=sys.stderr, flush=True)
