"""Images asked for without waiting for them, and perceived as they arrive.

The world opens the shutter when the request arrives, so the vehicle may fly on
to the next pose while the image is rendered, sent and perceived. One thread
receives the replies in order, another hands each frame to the mission (its
record, the live preview) and to perception, which measures up to `workers`
frames at once (a frame's OpenCV work costs about as long as the flight to the
next pose; one thread fell behind) and folds them into a `Fusion` in their
order: the images are perceived while the vehicle is still flying the survey.

The request and the next flight command travel on different links (Zenoh,
MAVLink), so the vehicle must not fly on before the shutter has opened. After
each request `shoot` waits for a `fence`: a cheap query on the same Zenoh link,
which a world answers after the requests sent before it (our world opens the
shutter as a request arrives and renders afterwards, in order). The vehicle does
not wait for the images themselves: up to `ahead` requests may be in flight, so
a survey flies at the vehicle's pace while the world renders and the mission
perceives behind it (the bound keeps a slow world from piling up requests that
would outlast their timeout). Against a
world that orders its queries otherwise, an image whose published pose is not
where it was asked for is not used: it is listed in `missed`, for the caller to
take again, holding still. So is one whose published attitude leans further than
`max_tilt_rad`: the shutter waits for the vehicle to level, and an image shot
leaning anyway (an attitude read before the vehicle braked once let one through
at 20 degrees) does not show the floor the survey counted on it for. So is an
image that never came (a dead camera leaves its query unanswered) and one that
`stale` refuses (a frozen camera's old image again, camera_source/fresh.py): an
image asked for without a pose (monitoring) is then simply not judged.
"""
from __future__ import annotations

import math
import queue
import threading
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable

from protocol.codec import decode
from protocol.errors import MissionError, ProtocolError
from protocol.messages import CameraFrame
from protocol.transport import PendingRequest

Where = tuple[float, float, float]   # north, east, altitude above home


class Shots:
    """`shoot()` asks for an image and returns once the world has taken it in hand;
    `drain()` waits until every image asked for so far has been perceived."""

    def __init__(self, start: Callable[[], PendingRequest], on_frame: Callable[[CameraFrame], None],
                 perceive: Callable[[CameraFrame], object] | None = None, timeout_s: float = 10.0,
                 fence: Callable[[], object] | None = None, ahead: int = 4,
                 merge: Callable[[object], None] | None = None, workers: int = 1,
                 max_tilt_rad: float | None = None, stale: Callable[[CameraFrame], str | None] | None = None) -> None:
        """`perceive` each frame as it arrives; with `merge`, `perceive` only measures (on up to
        `workers` frames at once) and `merge` folds each result in, in the frames' order."""
        self._start, self._on_frame, self._perceive, self._fence = start, on_frame, perceive, fence
        self._max_tilt_rad = max_tilt_rad
        self._stale = stale
        self._merge = merge
        self._timeout_s, self._ahead = timeout_s, max(1, ahead)
        self._requests: queue.Queue[tuple[PendingRequest, Where | None] | None] = queue.Queue()
        self._frames: queue.Queue[tuple[CameraFrame, Where | None] | None] = queue.Queue()
        self._measured: queue.Queue[Future | None] = queue.Queue()
        self._pool = (ThreadPoolExecutor(workers, thread_name_prefix="shots-measure")
                      if perceive is not None and merge is not None and workers > 1 else None)
        self._cv = threading.Condition()
        self._asked = self._arrived = self._handled = 0
        self._error: str | None = None
        self.frames: list[CameraFrame] = []
        self.missed: list[Where] = []
        self.why_missed: list[str] = []   # for each of `missed`
        self.unused = 0                   # images not used, `missed` or asked for without a pose
        self._threads = [threading.Thread(target=self._receive, name="shots-receive", daemon=True),
                         threading.Thread(target=self._digest, name="shots-perceive", daemon=True)]
        if self._pool is not None:
            self._threads.append(threading.Thread(target=self._merging, name="shots-merge", daemon=True))
        for t in self._threads:
            t.start()

    def shoot(self, where: Where | None = None) -> None:
        """Ask for an image; `where` is where the vehicle holds for it."""
        with self._cv:
            self._cv.wait_for(lambda: self._asked - self._arrived < self._ahead, timeout=self._timeout_s)
            self._asked += 1
        self._requests.put((self._start(), where))
        if self._fence is not None:
            self._fence()

    def done(self) -> bool:
        """Whether every image asked for has been perceived (or failed): `drain` would not wait."""
        with self._cv:
            return self._handled >= self._asked

    def drain(self, first: int | None = None) -> list[CameraFrame]:
        """Every image so far (or the `first` so many), perceived (one that never came is in `missed`);
        MissionError if one did not decode, or none came nor failed in time."""
        with self._cv:
            want = self._asked if first is None else min(first, self._asked)
            # Each image has its own query timeout, and perceiving one takes a second at most.
            limit = (want - self._handled) * (self._timeout_s + 5.0) + 5.0
            if not self._cv.wait_for(lambda: self._handled >= want, timeout=limit):
                raise MissionError(f"{want - self._handled} image(s) neither arrived nor were perceived "
                                   f"within {limit:g} s")
            if self._error is not None:
                raise MissionError(self._error)
            return list(self.frames)

    def close(self) -> None:
        self._requests.put(None)
        for t in self._threads:
            t.join(timeout=self._timeout_s + 5.0)
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)

    def _none(self, where: Where | None, why: str) -> None:
        """An image that never came: to be taken again, not the end of the mission."""
        self._skip(where, why)
        with self._cv:
            self._arrived += 1
            self._handled += 1
            self._cv.notify_all()

    def _skip(self, where: Where | None, why: str) -> None:
        with self._cv:   # two threads skip images: each pose keeps its own reason
            self.unused += 1
            if where is not None:
                self.missed.append(where)
                self.why_missed.append(why)

    def _fail(self, error: str) -> None:
        with self._cv:
            if self._error is None:
                self._error = error
            self._arrived += 1
            self._handled += 1
            self._cv.notify_all()

    def _receive(self) -> None:
        while (job := self._requests.get()) is not None:
            pending, where = job
            try:
                replies = pending.wait()
            except MissionError as exc:   # a MAVLink or video camera source names its own failure
                self._none(where, str(exc))
                continue
            if not replies:   # a dead camera's query ends unanswered (or the world's took too long)
                self._none(where, "no image from the camera")
                continue
            try:
                frame = decode(replies[0], CameraFrame)
            except ProtocolError as exc:
                self._fail(f"the world's camera answered garbage: {exc}")
                continue
            with self._cv:
                self._arrived += 1
                self._cv.notify_all()
            self._frames.put((frame, where))
        self._frames.put(None)

    def _digest(self) -> None:
        while (job := self._frames.get()) is not None:
            self._guarded(lambda: self._take(*job))
        self._measured.put(None)

    def _merging(self) -> None:
        while (job := self._measured.get()) is not None:
            self._guarded(lambda: self._merge(job.result()))

    def _guarded(self, step: Callable[[], bool | None]) -> None:
        """Run one step of an image's handling; unless it handed the image on (True), the
        image is handled, and a failure is the mission's to hear."""
        error = None
        try:
            if step():
                return
        except MissionError as exc:
            error = str(exc)
        except Exception as exc:  # noqa: BLE001 - a fault here must reach the mission, not kill a thread
            error = f"perceiving an image failed: {type(exc).__name__}: {exc}"
        with self._cv:
            self._handled += 1
            if error is not None and self._error is None:
                self._error = error
            self._cv.notify_all()

    def _take(self, frame: CameraFrame, where: Where | None) -> bool:
        """True if the frame went on to be measured and merged."""
        frozen = self._stale(frame) if self._stale is not None else None
        if frozen is not None:   # not even recorded: it shows nothing new
            self._skip(where, frozen)
            return False
        self._on_frame(frame)
        why = None if where is None else miss(frame, where, max_tilt_rad=self._max_tilt_rad)
        if why is not None:
            self._skip(where, why)
            return False
        self.frames.append(frame)
        if self._perceive is None:
            return False
        if self._pool is not None:
            self._measured.put(self._pool.submit(self._perceive, frame))
            return True
        result = self._perceive(frame)
        if self._merge is not None:
            self._merge(result)
        return False


def miss(frame: CameraFrame, where: Where, tolerance_m: float = 1.0, max_tilt_rad: float | None = None) -> str | None:
    """None if the frame's published pose is at `where`, within the hover tolerance and three
    sigmas of the pose estimate's stated error, and (if `max_tilt_rad` is given) its published
    roll and pitch together lean no further than that; else why not."""
    slack = tolerance_m + 3.0 * frame.pose_sigma_m
    north, east, alt = where
    off = max(math.hypot(frame.north_m - north, frame.east_m - east), abs(-frame.down_m - alt))
    if off > slack:
        return f"taken {off:.1f} m from its pose"
    tilt = math.hypot(frame.roll_rad, frame.pitch_rad)
    if max_tilt_rad is not None and tilt > max_tilt_rad:
        return f"taken leaning {math.degrees(tilt):.1f} degrees"
    return None
