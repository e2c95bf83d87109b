"""Only fresh images count (uav_agent/camera_source/fresh.py): a repeated stamp is a frozen camera's,
and a camera that gives no usable image is asked again for a while, then named in one line."""
from __future__ import annotations

import time

import pytest

from protocol.errors import MissionError
from protocol.messages import CameraFrame
from uav_agent.camera_source.fresh import Freshness, usable


def _frame(seq: int, t: float, png: bytes = b"x") -> CameraFrame:
    return CameraFrame(width=4, height=3, fx=2.0, fy=2.0, cx=1.5, cy=1.0, north_m=0.0, east_m=0.0, down_m=-10.0,
                       yaw_rad=0.0, time_s=t, png=png, seq=seq)


def test_a_stamp_seen_before_is_stale_and_a_calibration_never_is():
    fresh = Freshness()
    assert fresh.stale(_frame(3, 1.5)) is None
    assert fresh.stale(_frame(3, 1.5)) == "a frozen image (seq 3, t=1.50 s, as before)"
    assert fresh.stale(_frame(5, 1.5)) is None and fresh.stale(_frame(3, 2.0)) is None   # another exposure
    assert fresh.stale(_frame(0, 9.0, b"")) is None and fresh.stale(_frame(0, 9.0, b"")) is None
    assert fresh.refused == 1


def test_a_camera_that_comes_back_is_waited_for_and_said_once():
    fresh, said = Freshness(), []
    old = _frame(1, 1.0)
    fresh.stale(old)
    answers = [MissionError("no answer from the world's camera within 30 s"), old, old, _frame(2, 2.0)]

    def take():
        a = answers.pop(0)
        if isinstance(a, Exception):
            raise a
        return a
    assert usable(take, fresh, said.append, retry_s=0.01) == _frame(2, 2.0)
    assert said == ["no answer from the world's camera within 30 s"] and answers == []


def test_a_camera_that_stays_dead_is_one_line_and_a_failed_mission_stops_the_wait_at_once():
    def dead():
        raise MissionError("no answer from the world's camera within 30 s")
    t = time.monotonic()
    with pytest.raises(MissionError, match="the camera gave no usable image for 0.2 s: no answer") as e:
        usable(dead, Freshness(), lambda _: None, outage_s=0.2, retry_s=0.05)
    assert "\n" not in str(e.value) and time.monotonic() - t < 2
    with pytest.raises(MissionError, match="^the camera gave no usable image: no answer"):
        usable(dead, Freshness(), lambda _: None, gone=lambda: True)
