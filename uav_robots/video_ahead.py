"""replay.mp4 drawn while the vehicle lands, from the recording so far.

Everything a replay draws (the floor, each robot's cell tick by tick, its plan and goal) is final
once the UAV reports its landing phase, and encoding the 450 mission's 250 frames takes about 4 s,
which the user waited for after the summary. So the launcher renders the video from the samples
received by then while the vehicle descends and the processes stop, and keeps it only if the whole
recording, read back at the end, draws the same; otherwise it renders again.
"""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from protocol.errors import ProtocolError
from protocol.keys import Keys
from protocol.mapfile import format_rows
from protocol.messages import MissionStatus, decode

from . import recording, replay
from .observer import Observer

START_PHASE = "land"        # the mission's phase after which no robot moves
DRAFT_MCAP = ".replay-draft.mcap"
DRAFT_VIDEO = ".replay-draft.mp4"
JOIN_TIMEOUT_S = 300.0      # a 1,000-robot mission's video on a loaded machine stays well inside


def draws_the_same(a: recording.Recording, b: recording.Recording) -> bool:
    """Whether `replay.render` draws the same video from `a` and `b`."""
    return (a.ticks == b.ticks and a.cells == b.cells and a.goals == b.goals and a.paths == b.paths
            and a.starts == b.starts and a.free.shape == b.free.shape and bool(np.array_equal(a.free, b.free)))


class VideoAhead:
    """Watches `observer` for the landing phase (`poll`, cheap to call often), then renders a draft
    video into `out` on a thread; `take` moves it into place if it draws the final recording."""

    def __init__(self, observer: Observer, out: Path, fleet: str, free: np.ndarray) -> None:
        self._observer, self._out, self._fleet = observer, out, fleet
        self._rows = format_rows(free)
        self._key = Keys(fleet).mission_status
        self._seen = 0
        self._thread: threading.Thread | None = None
        self._draft: recording.Recording | None = None

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
                self._thread = threading.Thread(target=self._render, args=(self._observer.since(0),),
                                                name="video-ahead", daemon=True)
                self._thread.start()
                return

    def _render(self, samples: list) -> None:
        mcap = self._out / DRAFT_MCAP
        try:
            # the cell's size in metres is the map's metadata, which the video does not draw
            recording.write_mcap(mcap, samples, f"uavr/{self._fleet}", self._rows, 1.0)
            draft = recording.read_mcap(mcap)
            replay.render(draft, self._out / DRAFT_VIDEO)
            self._draft = draft
        except Exception:  # noqa: BLE001 - only a head start: the video is rendered again at the end
            self._draft = None
        finally:
            mcap.unlink(missing_ok=True)

    def _finish(self) -> recording.Recording | None:
        if self._thread is None:
            return None
        self._thread.join(JOIN_TIMEOUT_S)
        return None if self._thread.is_alive() else self._draft

    def take(self, final: recording.Recording, path: Path) -> bool:
        """True if the draft draws `final` and is now `path`; the draft is gone either way."""
        draft = self._finish()
        video = self._out / DRAFT_VIDEO
        if draft is not None and draws_the_same(draft, final):
            video.replace(path)
            return True
        video.unlink(missing_ok=True)
        return False

    def discard(self) -> None:
        """No video wanted (the outputs are temporary): let the draft end, remove it."""
        self._finish()
        (self._out / DRAFT_VIDEO).unlink(missing_ok=True)
