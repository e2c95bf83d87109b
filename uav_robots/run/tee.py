"""A child's output on our terminal and in its log at once, byte for byte as it comes.

The UAV's progress lines are for the person at the terminal, and they are the record of the mission
when it fails: both get every byte the moment the child writes it (no line buffering in between).
"""
from __future__ import annotations

import os
import selectors
import threading
from pathlib import Path
from typing import IO


class Tee:
    """Copies the pipes `outputs` (each to its stream: a child's stdout to ours, its stderr to ours) into
    `log`, on a thread of its own. The log keeps what the terminal cannot take and the other way round."""

    def __init__(self, log: Path, outputs: list[tuple[IO[bytes], IO[str]]]) -> None:
        self._log = open(log, "ab", buffering=0)
        self._outputs = outputs
        self.log_error: OSError | None = None
        self._thread = threading.Thread(target=self._pump, name=f"tee-{log.stem}", daemon=True)
        self._thread.start()

    def _pump(self) -> None:
        sel = selectors.DefaultSelector()
        for pipe, stream in self._outputs:
            sel.register(pipe, selectors.EVENT_READ, stream)
        try:
            while sel.get_map():
                for key, _ in sel.select():
                    data = os.read(key.fd, 65536)
                    if not data:
                        sel.unregister(key.fileobj)
                        key.fileobj.close()
                        continue
                    self._to_log(data)
                    _to_stream(key.data, data)
        finally:
            sel.close()
            self._log.close()

    def _to_log(self, data: bytes) -> None:
        if self.log_error is not None:
            return
        try:
            self._log.write(data)
        except OSError as exc:     # a full disk: the terminal still gets it, and the launcher says so
            self.log_error = exc

    def join(self, timeout_s: float) -> None:
        """Wait for the child's pipes to close (a grandchild may hold them open: then stop waiting)."""
        self._thread.join(timeout_s)


def _to_stream(stream: IO[str], data: bytes) -> None:
    try:
        buffer = getattr(stream, "buffer", None)
        if buffer is not None:
            buffer.write(data)
        else:
            stream.write(data.decode(errors="replace"))
        stream.flush()
    except (OSError, ValueError):   # our terminal is gone: the log still has it
        pass
