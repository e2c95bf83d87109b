"""Live progress for a person: a rich status line on a terminal, plain lines in logs and CI."""
from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, enabled: bool = True, stream=None) -> None:
        self.stream = stream or sys.stdout
        self.enabled = enabled
        self.live = enabled and self.stream.isatty()
        self._t0 = time.perf_counter()
        self._last_pct = -1
        self._console = None
        self._status = None
        if self.live:
            from rich.console import Console

            self._console = Console(file=self.stream)
            self._status = self._console.status("starting")
            self._status.start()

    def _line(self, text: str) -> None:
        if not self.enabled:
            return
        stamp = f"[{time.perf_counter() - self._t0:6.2f}s]"
        try:
            if self._console is not None:
                self._console.print(f"{stamp} {text}", highlight=False)
            else:
                print(f"{stamp} {text}", file=self.stream, flush=True)
        except OSError:   # the launcher that read this pipe is gone: the mission goes on without lines
            self.enabled = False

    def phase(self, name: str, detail: str = "") -> None:
        text = f"{name}" + (f": {detail}" if detail else "")
        if self._status is not None:
            self._status.update(text)
        self._line(text)

    def ticks(self, k: int, n: int, done: int, robots: int) -> None:
        text = f"tick {k}/{n}, robots done {done}/{robots}"
        if self._status is not None:
            self._status.update(text)
            if k == n:
                self._line(text)
            return
        pct = 100 * k // max(n, 1)
        if pct // 10 != self._last_pct // 10 or k == n:
            self._last_pct = pct
            self._line(text)

    def close(self) -> None:
        if self._status is not None:
            self._status.stop()
            self._status = None
