"""replay.mp4 drawn while the vehicle lands: started by the landing phase, kept only if it draws the final recording."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from protocol.keys import Keys
from protocol.messages import MissionStatus, encode
from uav_robots.observer import Sample
from uav_robots.recording import Recording
from uav_robots.video_ahead import DRAFT_VIDEO, VideoAhead, draws_the_same

FLEET = "f1"


class Samples:
    """An observer's `since`, fed by the test."""

    def __init__(self) -> None:
        self.samples: list[Sample] = []

    def since(self, i: int) -> list[Sample]:
        return self.samples[i:]

    def status(self, phase: str) -> None:
        self.samples.append(Sample(time.time_ns(), Keys(FLEET).mission_status, encode(MissionStatus(phase=phase))))


def recording(ticks: int) -> Recording:
    free = np.ones((6, 8), bool)
    free[2, 3] = False
    return Recording(free, cells={1: {k: (k % 8, 0) for k in range(ticks + 1)}}, goals={1: (ticks % 8, 0)},
                     paths={1: [(k % 8, 0) for k in range(ticks + 1)]}, starts={1: (0, 0)}, ticks=ticks)


def test_the_draft_starts_at_the_landing_phase_once_and_is_kept_only_if_it_draws_the_same(tmp_path: Path):
    feed = Samples()
    ahead = VideoAhead(feed, tmp_path, FLEET, np.ones((6, 8), bool))
    feed.samples.append(Sample(time.time_ns(), Keys(FLEET).mission_status, b"garbage"))
    for phase in ("survey", "executing", "verify"):
        feed.status(phase)
        ahead.poll()
    assert ahead._thread is None, "robots may still move before the landing"
    feed.status("land")
    ahead.poll()
    first = ahead._thread
    assert first is not None
    feed.status("land")
    ahead.poll()
    assert ahead._thread is first, "one draft per mission"
    ahead._finish()
    # Whatever the draft drew from these samples, the decision is the final recording's: a draft that
    # does not draw it is thrown away (the caller renders again), one that does is moved into place.
    ahead._draft = recording(5)
    (tmp_path / DRAFT_VIDEO).write_bytes(b"draft")
    assert not ahead.take(recording(6), tmp_path / "replay.mp4")
    assert not (tmp_path / DRAFT_VIDEO).exists() and not (tmp_path / "replay.mp4").exists()
    (tmp_path / DRAFT_VIDEO).write_bytes(b"draft")
    assert ahead.take(recording(5), tmp_path / "replay.mp4")
    assert (tmp_path / "replay.mp4").read_bytes() == b"draft" and not (tmp_path / DRAFT_VIDEO).exists()


def test_what_the_video_draws_decides_whether_two_recordings_are_the_same():
    a, b = recording(5), recording(5)
    assert draws_the_same(a, b)
    b.events.append({"kind": "camera-deviation"})      # not drawn
    assert draws_the_same(a, b)
    b.free[0, 0] = False
    assert not draws_the_same(a, b)
    c = recording(5)
    c.cells[1][3] = (7, 5)
    assert not draws_the_same(a, c)


def test_no_landing_means_no_draft_and_discard_leaves_nothing(tmp_path: Path):
    feed = Samples()
    ahead = VideoAhead(feed, tmp_path, FLEET, np.ones((6, 8), bool))
    feed.status("executing")
    ahead.poll()
    ahead.discard()
    assert not ahead.take(recording(3), tmp_path / "replay.mp4") and not list(tmp_path.iterdir())
