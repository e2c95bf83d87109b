"""Only fresh images count: a frame the UAV has already received (the same seq and time stamp) is a
frozen camera's, which would show the floor as it was, and must not confirm what it could not have
seen; and a camera that gives no image, or only a frozen one, is asked again for a while before the
mission gives up on it, since a dead or frozen video pipeline often comes back (a reset, a reconnect).

Every camera source stamps its images: the world's with its seq and simulated time, a MAVLink
camera's with its exposure's time; a repeated stamp cannot be a new exposure.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from typing import Callable

from protocol.errors import MissionError
from protocol.messages import CameraFrame

KEEP = 512            # stamps remembered: far more images than a look holds, so a repeat is caught
OUTAGE_S = 45.0       # wall seconds the UAV asks again for a usable image before it gives up on the camera
RETRY_S = 0.5         # between two asks: a dead camera answers at once, and must not be flooded


class Freshness:
    """The stamps of the images received lately, across every way the mission takes them."""

    def __init__(self) -> None:
        self._order: deque[tuple[int, float]] = deque()
        self._seen: set[tuple[int, float]] = set()
        self._lock = threading.Lock()
        self.refused = 0

    def stale(self, frame: CameraFrame) -> str | None:
        """Why `frame` must not be used (an image seen before), or None; a fresh one is remembered."""
        if not frame.png:   # a calibration: no image to be stale
            return None
        key = (frame.seq, frame.time_s)
        with self._lock:
            if key in self._seen:
                self.refused += 1
                return f"a frozen image (seq {frame.seq}, t={frame.time_s:.2f} s, as before)"
            self._seen.add(key)
            self._order.append(key)
            if len(self._order) > KEEP:
                self._seen.discard(self._order.popleft())
        return None


def usable(take: Callable[[], CameraFrame], fresh: Freshness, on_wait: Callable[[str], None],
           gone: Callable[[], bool] = lambda: False, outage_s: float = OUTAGE_S,
           retry_s: float = RETRY_S) -> CameraFrame:
    """`take()` until it gives a fresh image (or a calibration), for at most `outage_s`; `on_wait(why)`
    once, at the first failure. MissionError naming the camera's last failure at the end, or at once
    when `gone()` (the vehicle or the world failed: no point waiting for the camera)."""
    deadline = time.monotonic() + outage_s
    waited = False
    while True:
        try:
            frame = take()
            why = fresh.stale(frame)
        except MissionError as exc:   # no answer, or garbage: the source names it
            why = str(exc)
        if why is None:
            return frame
        if gone():
            raise MissionError(f"the camera gave no usable image: {why}")
        if time.monotonic() >= deadline:
            raise MissionError(f"the camera gave no usable image for {outage_s:g} s: {why}")
        if not waited:
            on_wait(why)
            waited = True
        time.sleep(retry_s)
