"""Warning lines that a flood of bad input cannot turn into a flood of output."""
from __future__ import annotations

import atexit
import sys
import threading
import time

MAX_LINE_CHARS = 300


def printable(text: str) -> str:
    """One line a terminal shows as it is: what a stranger sent (a key, a status text) may hold
    control characters, escape sequences or line breaks; those are written as escapes."""
    if text.isprintable() and len(text) <= MAX_LINE_CHARS:
        return text
    out = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return out if len(out) <= MAX_LINE_CHARS else out[:MAX_LINE_CHARS] + "..."


class Throttled:
    """At most one line per `interval_s` to stderr; the lines held back are counted and said in the
    next, or at the process's exit."""

    def __init__(self, prefix: str, interval_s: float = 1.0) -> None:
        self.prefix = prefix
        self.interval_s = interval_s
        self.count = 0            # every warning, shown or not
        self._held = 0
        self._last = -float("inf")
        self._lock = threading.Lock()
        self._flush_at_exit = False

    def __call__(self, text: str) -> None:
        now = time.monotonic()
        with self._lock:
            self.count += 1
            if now - self._last < self.interval_s:
                self._held += 1
                if not self._flush_at_exit:
                    self._flush_at_exit = True
                    atexit.register(self.flush)
                return
            held, self._held, self._last = self._held, 0, now
        more = f" ({held} more held back)" if held else ""
        print(f"warning: {self.prefix}: {printable(text)}{more}", file=sys.stderr, flush=True)

    def flush(self) -> None:
        """Say how many lines were held back since the last one shown (nothing if none)."""
        with self._lock:
            held, self._held = self._held, 0
        if held:
            print(f"warning: {self.prefix}: {held} more held back ({self.count} in all)", file=sys.stderr, flush=True)
