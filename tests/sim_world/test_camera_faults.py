"""The world's camera faults (protocol/faults.py camera.off and camera.stuck; executor
sim_world/camera_faults.py): a dead camera leaves its queries unanswered, a frozen one repeats its
last image, pose, time and seq included; pure, then a real world process queried over Zenoh."""
from __future__ import annotations

import signal
import time

import pytest
from test_world_service import start_world, wait_alive

from conformance import Hub, stop_process
from protocol.codec import decode, encode
from protocol.errors import MissionError
from protocol.messages import CameraFrame, CameraRequest, Record, RecordRequest
from sim_world.camera_faults import OFF, STUCK, camera_faults
from sim_world.faults import world_faults


def test_the_windows_say_off_or_stuck_on_the_cameras_clock_and_once_each():
    said: list[str] = []
    cf = camera_faults(["slip:0.1", "camera-off:10+5", "camera-stuck:12+10"], said.append)
    assert [cf.state(t) for t in (9.9, 10, 12, 14.9, 15, 21.9, 22)] == [None, OFF, OFF, OFF, STUCK, STUCK, None]
    assert len(said) == 2 and "camera-off:10+5 acts at t=10.0 s" in said[0] and "until t=15 s" in said[0]
    assert camera_faults(["slip:0.1", "skid:1@2"]) is None
    assert world_faults(["camera-off:1+2", "slip:0.2"]).slip == 0.2   # a camera fault is no slip of 0


def test_a_frozen_camera_repeats_the_newest_image_and_the_component_fails_or_freezes():
    cf = camera_faults(["camera-off:10+5", "camera-stuck:20+5"], lambda _: None)
    assert cf.frozen() is None
    cf.remember(4, "image 4")
    cf.remember(2, "image 2")      # rendered out of order: the newest stays the one repeated
    assert cf.frozen() == "image 4"
    shot = lambda t, seq: (None, None, None, 1.0, None, t, seq, seq)
    expose = cf.expose(lambda: shot(11.0, 7))
    with pytest.raises(MissionError, match="off"):
        expose()
    develop = cf.develop(lambda s: f"image {s[6]}")
    assert develop(shot(5.0, 9)) == "image 9" and develop(shot(21.0, 11)) == "image 9"
    assert (cf.unanswered, cf.repeated) == (1, 1)


@pytest.mark.slow
@pytest.mark.process
def test_a_world_whose_camera_dies_then_freezes():
    """`--mavlink none`: the camera's clock is the world's wall seconds since it started. Off for the
    first 6 s: queries end without a reply. Then one fresh image; from 14 s it is frozen: every image
    request gets that one again, the same bytes; a calibration is still answered, fresh."""
    with Hub() as hub:
        proc = start_world(hub, "--mavlink", "none", "--camera", "ideal,width=320,height=240",
                           "--fault", "camera-off:0+6", "--fault", "camera-stuck:14+600")
        try:
            assert wait_alive(hub, hub.keys.alive_world), proc.stderr.read() if proc.poll() is not None else ""
            ask = lambda **kw: hub.transport.request(hub.keys.camera, encode(CameraRequest(**kw)), 10)
            assert ask() == []                      # dead: no reply, and at once (not after the timeout)
            deadline = time.monotonic() + 30
            while not (cal := ask(calibration_only=True)) and time.monotonic() < deadline:
                time.sleep(0.2)
            assert cal, "the camera never came back"
            (raw,) = ask()
            fresh = decode(raw, CameraFrame)
            assert 6 <= fresh.time_s < 14 and fresh.png
            time.sleep(14.5 - fresh.time_s)
            again = [ask(), ask(roi_x=0, roi_y=0, roi_width=100, roi_height=80)]
            assert again == [[raw], [raw]]          # the same pixels, pose, time and seq
            (cal,) = ask(calibration_only=True)
            assert decode(cal, CameraFrame).time_s > fresh.time_s
            rec = decode(hub.transport.request(hub.keys.record, encode(RecordRequest()), 5)[0], Record)
            assert rec.truth["camera_faults"]["unanswered"] >= 2 and rec.truth["camera_faults"]["repeated"] == 2
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(15) == 0
            out = proc.stdout.read()
            assert "fault camera-off:0+6 acts at t=" in out and "fault camera-stuck:14+600 acts at t=" in out
            assert "answered with a frozen image" in out
        finally:
            stop_process(proc)
