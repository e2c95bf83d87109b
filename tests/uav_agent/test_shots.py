"""Images asked for on the move: replies taken in order, perceived off the caller's thread,
images taken elsewhere or leaning, never given (a dead camera) or given again (a frozen one) set
aside for a retake, a garbled camera named.

The whole path over Zenoh with the world's camera and a flying vehicle is exercised by
every mission test (tests/uav_robots/test_end_to_end.py); here the camera is a small queryable on
the in-memory transport, so each case can be made to happen."""
from __future__ import annotations

import math
import threading
import time

import pytest

from protocol.codec import decode, encode
from protocol.errors import MissionError
from protocol.messages import CameraFrame, CameraRequest
from protocol.transport import MemoryBus, MemoryTransport
from uav_agent.shots import Shots, miss

KEY = "t/world/camera"


def _frame(seq: int, north: float, east: float, alt: float, sigma: float = 0.0, roll: float = 0.0,
           pitch: float = 0.0) -> CameraFrame:
    return CameraFrame(width=4, height=3, fx=2.0, fy=2.0, cx=1.5, cy=1.0, north_m=north, east_m=east, down_m=-alt,
                       yaw_rad=0.0, time_s=float(seq), png=b"x", seq=seq, pose_sigma_m=sigma, roll_rad=roll,
                       pitch_rad=pitch)


class Camera:
    """Answers each request from a worker thread, a little later, from wherever `pose` says."""

    def __init__(self, transport: MemoryTransport, answer=True) -> None:
        self.pose = (0.0, 0.0, 10.0)
        self.lean = (0.0, 0.0)   # roll, pitch
        self.seq = 0
        self.answer = answer
        self.gate: threading.Event | None = None
        transport.serve(KEY, self._on)

    def _on(self, q) -> None:
        decode(q.payload, CameraRequest)
        self.seq += 1
        seq, pose, lean = self.seq, self.pose, self.lean   # the shutter opens as the request arrives

        def later():
            time.sleep(0.05)
            if self.gate is not None:
                self.gate.wait()
            if self.answer is True:
                q.reply(encode(_frame(seq, *pose, roll=lean[0], pitch=lean[1])))
            elif self.answer == "garbage":
                q.reply(b"\xff not a frame")
            else:
                q.finish()
        threading.Thread(target=later, daemon=True).start()


def _shots(transport, perceived, took, timeout_s=1.0, max_tilt_rad=None):
    return Shots(lambda: transport.request_start(KEY, encode(CameraRequest()), timeout_s), took.append,
                 perceived.append, timeout_s, max_tilt_rad=max_tilt_rad)


def test_images_arrive_in_order_and_are_perceived_while_the_caller_goes_on():
    transport = MemoryTransport(MemoryBus())
    camera = Camera(transport)
    perceived, took = [], []
    shots = _shots(transport, perceived, took)
    try:
        t = time.monotonic()
        for i in range(5):
            camera.pose = (-10.0 * i, 5.0, 10.0)
            shots.shoot((-10.0 * i, 5.0, 10.0))
        frames = shots.drain()
    finally:
        shots.close()
    assert [f.seq for f in frames] == [1, 2, 3, 4, 5] and perceived == frames and took == frames
    assert shots.missed == [] and time.monotonic() - t < 5


def test_an_image_taken_away_from_its_pose_is_set_aside_for_a_retake():
    transport = MemoryTransport(MemoryBus())
    camera = Camera(transport)
    perceived, took = [], []
    shots = _shots(transport, perceived, took)
    try:
        camera.pose = (0.0, 0.0, 10.0)
        shots.shoot((0.0, 0.0, 10.0))
        camera.pose = (0.0, 3.0, 10.0)    # the vehicle already left for the next pose
        shots.shoot((0.0, 0.0, 10.0))
        frames = shots.drain()
    finally:
        shots.close()
    assert [f.seq for f in frames] == [1] and shots.missed == [(0.0, 0.0, 10.0)]
    assert len(took) == 2 and perceived == frames   # recorded, not perceived


def test_an_image_shot_leaning_is_set_aside_for_a_retake_and_says_so():
    """A survey image was once shot at 20 degrees of roll (an attitude read before the vehicle
    braked): its own published attitude tells, and it is taken again holding level."""
    transport = MemoryTransport(MemoryBus())
    camera = Camera(transport)
    perceived, took = [], []
    shots = _shots(transport, perceived, took, max_tilt_rad=math.radians(1.5))
    try:
        camera.lean = (math.radians(0.5), math.radians(-0.6))   # a hover's wobble: used
        shots.shoot((0.0, 0.0, 10.0))
        camera.lean = (math.radians(20.0), 0.0)
        shots.shoot((0.0, 0.0, 10.0))
        frames = shots.drain()
    finally:
        shots.close()
    assert [f.seq for f in frames] == [1] and shots.missed == [(0.0, 0.0, 10.0)]
    assert shots.why_missed == ["taken leaning 20.0 degrees"]
    assert len(took) == 2 and perceived == frames


def test_miss_allows_the_hover_tolerance_and_the_estimates_stated_error():
    assert miss(_frame(1, 0.9, 0.0, 10.0), (0.0, 0.0, 10.0)) is None
    assert miss(_frame(1, 1.2, 0.0, 10.0), (0.0, 0.0, 10.0)) is not None
    assert miss(_frame(1, 1.2, 0.0, 10.0, sigma=0.2), (0.0, 0.0, 10.0)) is None
    assert miss(_frame(1, 0.0, 0.0, 12.0), (0.0, 0.0, 10.0)) is not None
    assert miss(_frame(1, 0.0, 3.0, 10.0), (0.0, 0.0, 10.0)) == "taken 3.0 m from its pose"
    leaning = _frame(1, 0.0, 0.0, 10.0, roll=math.radians(1.2), pitch=math.radians(1.2))
    assert miss(leaning, (0.0, 0.0, 10.0)) is None   # no tilt limit asked for
    assert miss(leaning, (0.0, 0.0, 10.0), max_tilt_rad=math.radians(1.5)) == "taken leaning 1.7 degrees"


def test_a_garbled_camera_is_a_one_line_mission_error():
    transport = MemoryTransport(MemoryBus())
    Camera(transport, answer="garbage")
    shots = _shots(transport, [], [], timeout_s=0.5)
    try:
        shots.shoot()
        with pytest.raises(MissionError, match="the world's camera answered garbage") as exc:
            shots.drain()
    finally:
        shots.close()
    assert "\n" not in str(exc.value)


def test_an_image_a_dead_camera_never_gave_is_set_aside_for_a_retake():
    """camera-off: the query ends unanswered. The pose is taken again (looks.retake, which waits for
    the camera); an image asked for without a pose (monitoring) is simply not judged."""
    transport = MemoryTransport(MemoryBus())
    Camera(transport, answer=False)
    perceived, took = [], []
    shots = _shots(transport, perceived, took, timeout_s=0.5)
    try:
        shots.shoot((0.0, 0.0, 10.0))
        shots.shoot()
        assert shots.drain() == []
    finally:
        shots.close()
    assert shots.missed == [(0.0, 0.0, 10.0)] and shots.why_missed == ["no image from the camera"]
    assert shots.unused == 2 and took == [] and perceived == []


def test_a_frozen_cameras_old_image_is_refused_and_never_perceived():
    """camera-stuck: the camera answers with its last image again, the same seq and time. Refused by
    its stamp (camera_source/fresh.py): not recorded, not perceived, its pose taken again; one asked
    for without a pose (a monitoring image, which could confirm arrivals) is not judged either."""
    from uav_agent.camera_source.fresh import Freshness

    transport = MemoryTransport(MemoryBus())
    frozen = _frame(7, 0.0, 0.0, 10.0)
    transport.serve(KEY, lambda q: q.reply(encode(frozen)))
    perceived, took = [], []
    shots = Shots(lambda: transport.request_start(KEY, encode(CameraRequest()), 1.0), took.append,
                  perceived.append, 1.0, stale=Freshness().stale)
    try:
        for where in ((0.0, 0.0, 10.0), (0.0, 0.0, 10.0), None):
            shots.shoot(where)
        frames = shots.drain()
    finally:
        shots.close()
    assert frames == [frozen] and perceived == [frozen] and took == [frozen]
    assert shots.missed == [(0.0, 0.0, 10.0)] and shots.unused == 2
    assert shots.why_missed == ["a frozen image (seq 7, t=7.00 s, as before)"]


def test_a_perception_fault_reaches_the_caller():
    transport = MemoryTransport(MemoryBus())
    Camera(transport)

    def broken(frame):
        raise ValueError("bad pixels")

    shots = Shots(lambda: transport.request_start(KEY, encode(CameraRequest()), 1.0), lambda f: None, broken, 1.0)
    try:
        shots.shoot()
        with pytest.raises(MissionError, match="perceiving an image failed: ValueError: bad pixels"):
            shots.drain()
    finally:
        shots.close()


def test_the_caller_flies_on_with_several_images_in_flight_up_to_its_bound():
    transport = MemoryTransport(MemoryBus())
    camera = Camera(transport)
    camera.gate = threading.Event()   # no image is sent before the gate opens
    shots = Shots(lambda: transport.request_start(KEY, encode(CameraRequest()), 5.0), lambda f: None, None, 5.0,
                  ahead=3)
    opened = []

    def open_gate():
        time.sleep(0.3)
        opened.append(time.monotonic())
        camera.gate.set()
    try:
        t = time.monotonic()
        for _ in range(3):
            shots.shoot()
        three = time.monotonic()
        threading.Thread(target=open_gate, daemon=True).start()
        shots.shoot()           # the fourth waits for the first image
        four = time.monotonic()
        frames = shots.drain()
    finally:
        shots.close()
    assert three - t < 1.0 and four >= opened[0] and [f.seq for f in frames] == [1, 2, 3, 4]


def test_frames_measured_at_once_are_merged_in_their_order():
    """Two frames measured side by side (the first slower), merged in the order they were taken;
    a measurement that fails is named by drain, and the others are still merged."""
    transport = MemoryTransport(MemoryBus())
    camera = Camera(transport)
    took, merged, running, most = [], [], [0], [0]
    lock = threading.Lock()

    def measure(frame):
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        time.sleep(0.3 if frame.seq % 2 else 0.05)
        with lock:
            running[0] -= 1
        if frame.seq == 4:
            raise ValueError("unreadable")
        return frame.seq

    shots = Shots(lambda: transport.request_start(KEY, encode(CameraRequest()), 2.0), took.append, measure, 2.0,
                  merge=merged.append, workers=2)
    try:
        for i in range(6):
            camera.pose = (-10.0 * i, 5.0, 10.0)
            shots.shoot((-10.0 * i, 5.0, 10.0))
        with pytest.raises(MissionError, match="ValueError: unreadable"):
            shots.drain()
        assert shots.done()
    finally:
        shots.close()
    assert merged == [1, 2, 3, 5, 6] and most[0] == 2 and [f.seq for f in took] == [1, 2, 3, 4, 5, 6]
