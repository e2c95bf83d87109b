"""replay.mp4 drawn while the vehicle lands: started by the landing phase, kept only if it draws the final recording."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from protocol.codec import encode
from protocol.keys import Keys
from protocol.messages import MissionStatus
from uav_robots.record.observer import Sample
from protocol.mapfile import format_rows
from uav_robots.record.recording import drawn
from uav_robots.record.video_ahead import DRAFT_VIDEO, VideoAhead

FLEET = "f1"


class Samples:
    """An observer's `since`, fed by the test."""

    def __init__(self) -> None:
        self.samples: list[Sample] = []

    def since(self, i: int) -> list[Sample]:
        return self.samples[i:]

    def status(self, phase: str) -> None:
        self.samples.append(Sample(time.time_ns(), Keys(FLEET).mission_status, encode(MissionStatus(phase=phase))))


FREE = np.ones((6, 8), bool)


def test_the_draft_starts_at_the_landing_phase_once_and_is_kept_only_if_nothing_drawn_came_after(tmp_path: Path):
    feed = Samples()
    ahead = VideoAhead(feed, tmp_path, FLEET, FREE)
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
    assert ahead._finish(), "a draft is drawn from what arrived up to the landing"
    rows = format_rows(FREE)
    # After the draft's samples: a status (not drawn) keeps it; a robot's state, or another map, does not.
    feed.status("landed")
    assert ahead.take(feed.samples, rows, tmp_path / "replay.mp4")
    assert (tmp_path / "replay.mp4").stat().st_size > 0 and not (tmp_path / DRAFT_VIDEO).exists()
    (tmp_path / DRAFT_VIDEO).write_bytes(b"draft")
    other = FREE.copy()
    other[1, 1] = False
    assert not ahead.take(feed.samples, format_rows(other), tmp_path / "again.mp4")
    assert not (tmp_path / DRAFT_VIDEO).exists() and not (tmp_path / "again.mp4").exists()
    (tmp_path / DRAFT_VIDEO).write_bytes(b"draft")
    keys = Keys(FLEET)
    feed.samples.append(Sample(time.time_ns(), keys.states_as([1, 2]), b"{}"))
    assert not ahead.take(feed.samples, rows, tmp_path / "again.mp4")
    assert not (tmp_path / DRAFT_VIDEO).exists() and not (tmp_path / "again.mp4").exists()


def test_what_the_video_draws():
    keys, prefix = Keys(FLEET), Keys(FLEET).prefix
    assert drawn(prefix, keys.states_as([3])) and drawn(prefix, keys.tick) and drawn(prefix, keys.plan(4))
    assert not drawn(prefix, keys.mission_status) and not drawn(prefix, keys.uav_pose)
    assert not drawn(Keys("other").prefix, keys.tick), "another fleet's samples are not this recording's"


def test_no_landing_means_no_draft_and_discard_leaves_nothing(tmp_path: Path):
    feed = Samples()
    ahead = VideoAhead(feed, tmp_path, FLEET, FREE)
    feed.status("executing")
    ahead.poll()
    ahead.discard()
    assert not ahead.take(feed.samples, format_rows(FREE), tmp_path / "replay.mp4") and not list(tmp_path.iterdir())
