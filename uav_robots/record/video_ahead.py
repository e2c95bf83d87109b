"""replay.mp4 drawn while the vehicle lands, from the recording so far.

Everything a replay draws (the floor, each robot's cell tick by tick, its plan and goal) is final
once the UAV reports its landing phase, and encoding the 450 mission's 250 frames takes about 4 s,
which the user waited for after the summary. So the launcher renders the video from the samples
received by then while the vehicle descends and the processes stop, and keeps it only if the whole
recording draws the same (no sample the video draws came after the draft's, the same map);
otherwise it renders again. The draft draws up to the last tick of the plans recorded so far (the
report, which bounds the final video, comes later: `recording.last_tick`), never a tick a message claims.
"""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from protocol.codec import decode
from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.mapfile import format_rows
from protocol.messages import MissionStatus

from . import recording, replay
from .observer import Observer

START_PHASE = "land"        # the mission's phase after which no robot moves
DRAFT_VIDEO = ".replay-draft.mp4"
JOIN_TIMEOUT_S = 300.0      # a 1,000-robot mission's video on a loaded machine stays well inside


class VideoAhead:
    """Watches `observer` for the landing phase (`poll`, cheap to call often), then renders a draft
    video into `out` on a thread; `take` moves it into place if it draws the whole recording."""

    def __init__(self, observer: Observer, out: Path, fleet: str, free: np.ndarray) -> None:
        self._observer, self._out, self._fleet = observer, out, fleet
        self._rows = format_rows(free)
        keys = Keys(fleet)
        self._key, self._prefix = keys.mission_status, keys.prefix
        self._seen = 0
        self._drawn_from = 0          # the samples the draft was rendered from: the first so many
        self._last = 0                # the last tick the draft draws
        self._claimed = 0             # the last tick its samples claim (beyond `_last`: left out)
        self._thread: threading.Thread | None = None
        self._cancel = threading.Event()
        self._done = False

    def poll(self) -> None:
        if self._thread is not None:
            return
        new = self._observer.since(self._seen)
        self._seen += len(new)
        for s in new:
            if s.key != self._key:
                continue
            try:
                phase = decode(s.payload, MissionStatus).phase
            except ProtocolError:
                continue      # not ours to judge: the recording keeps it as it came
            if phase == START_PHASE:
                samples = self._observer.since(0)
                self._drawn_from = len(samples)
                self._thread = threading.Thread(target=self._render, args=(samples,), name="video-ahead",
                                                daemon=True)
                self._thread.start()
                return

    def _render(self, samples: list) -> None:
        try:
            # From the samples as the recording will hold them, not through a draft file: writing
            # and reading one back took as long as drawing 1,000 robots.
            rec = recording.drawn_recording(samples, self._prefix, self._rows)
            self._last, self._claimed = rec.horizon, rec.ticks
            recording.bound(rec, self._last)
            replay.render(rec, self._out / DRAFT_VIDEO, cancel=self._cancel)
            self._done = True
        except Exception:  # noqa: BLE001 - only a head start: the video is rendered again at the end
            self._done = False

    def _finish(self) -> bool:
        """Whether a draft was rendered (waiting for it to end)."""
        if self._thread is None:
            return False
        self._thread.join(JOIN_TIMEOUT_S)
        return not self._thread.is_alive() and self._done

    def take(self, samples: list, rows: list[str] | None, path: Path, last: int | None = None) -> bool:
        """True if the draft draws the recording of `samples` (every sample, in arrival order) on the
        map `rows` up to tick `last` (None: the draft's own bound), and is now `path`; the draft is gone
        either way."""
        same_ticks = last is None or last == self._last or min(last, self._last) >= self._claimed
        fresh = self._finish() and rows == self._rows and same_ticks and not any(
            recording.drawn(self._prefix, s.key) for s in samples[self._drawn_from:])
        video = self._out / DRAFT_VIDEO
        if fresh:
            video.replace(path)
            return True
        video.unlink(missing_ok=True)
        return False

    def discard(self) -> None:
        """No video wanted (temporary outputs, a stop): the draft ends at its next frame and is removed."""
        self._cancel.set()
        self._finish()
        (self._out / DRAFT_VIDEO).unlink(missing_ok=True)
