"""The world's camera as a real drone's: a MAVLink camera component (Camera Protocol v2) with its
images over HTTP and an H.264 RTP video stream; the UAV's camera sources that take images from
it; a whole mission flown with the MAVLink camera source. Real sockets on loopback throughout."""
from __future__ import annotations

import json
import math
import socket
import subprocess
import sys
import urllib.request
from contextlib import contextmanager

import cv2
import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from mavlink_gcs import Client
from protocol.geo import ned_to_geo
from protocol.keys import Keys
from protocol.messages import WorldInfo
from protocol.transport import MemoryBus, MemoryTransport
from scenes import open_map
from sim_world.camera.mavlink_camera import camera_quaternion
from sim_world.config import WorldConfig
from sim_world.service import World
from uav_agent.camera_source import open_camera_source
from uav_agent.camera_source.base import CameraSourceConfig, body_attitude
from uav_agent.camera_source.mavlink_source import MavlinkSource
from uav_agent.camera_source.video_source import VideoSource
from uav_agent.camera_source.zenoh_source import ZenohSource

CAMERA = 100
# A small camera with a lens, so that what has no MAVLink field (the distortion) is seen to travel.
MODEL = {"width": 1280, "height": 960, "hfov_deg": 70.0, "k1": -0.05, "jpeg_quality": 90}
STARTS, GOALS = [(1, 1), (4, 2), (6, 4)], [(6, 0), (0, 5), (3, 3)]


def udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextmanager
def camera_world(tmp_path, video: str | None = None):
    """A world without a vehicle (its camera hovers over the floor's centre, seeing all of it), whose
    camera is also a MAVLink camera component sending to a free port; yields (world, that port)."""
    port = udp_port()
    m, s = open_map(tmp_path, STARTS, GOALS)
    bus = MemoryBus()
    world = World(WorldConfig(fleet="cam", map=m, scen=s, robots=3, mavlink=None, camera=dict(MODEL),
                              camera_mavlink=f"udpout:127.0.0.1:{port}", camera_video=video), MemoryTransport(bus))
    world.start()
    world.bus = bus
    try:
        yield world, port
    finally:
        world.close()


def info_of(world) -> WorldInfo:
    c = world.cfg
    return WorldInfo(width=8, height=6, cell_size_m=1.0, home_lat=c.home_lat, home_lon=c.home_lon,
                     home_alt_m=c.home_alt_m)


def request(gcs: Client, msg_id: int, kind: str, param2: float = 0.0):
    assert gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, msg_id, param2, target_component=CAMERA) == 0
    return gcs.recv(kind)


def test_the_nadir_quaternion_gives_the_attitude_back():
    s = math.sqrt(0.5)
    assert camera_quaternion(0.0, 0.0, 0.0) == pytest.approx((s, 0.0, -s, 0.0))
    for roll, pitch, yaw in [(0.0, 0.0, 0.0), (0.02, -0.01, 1.2), (-0.3, 0.25, -3.0), (0.1, 0.4, 3.1)]:
        assert body_attitude(camera_quaternion(roll, pitch, yaw)) == pytest.approx((roll, pitch, yaw), abs=1e-9)


def test_a_ground_station_finds_the_camera_and_takes_an_image(tmp_path):
    video_port = udp_port()
    with camera_world(tmp_path, video=f"udp://127.0.0.1:{video_port}?fps=1&width=320") as (world, port):
        gcs = Client(None, listen=port)
        try:
            beat = gcs.recv("HEARTBEAT", 5, lambda m: m.get_srcComponent() == CAMERA)
            assert (beat.type, beat.autopilot, beat.get_srcSystem()) == (mavlink.MAV_TYPE_CAMERA,
                                                                        mavlink.MAV_AUTOPILOT_INVALID, 1)
            info = request(gcs, mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION, "CAMERA_INFORMATION")
            model = world.camera_model
            assert (info.resolution_h, info.resolution_v) == (1280, 960)
            # What a survey planner reads: the pinhole from the focal length and the sensor's size.
            assert info.focal_length / info.sensor_size_h * info.resolution_h == pytest.approx(model.fx, rel=1e-5)
            assert info.focal_length / info.sensor_size_v * info.resolution_v == pytest.approx(model.fy, rel=1e-5)
            assert info.flags & mavlink.CAMERA_CAP_FLAGS_CAPTURE_IMAGE and info.flags & mavlink.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
            assert b"<mavlinkcamera>" in urllib.request.urlopen(info.cam_definition_uri, timeout=5).read()
            beside = info.cam_definition_uri.rsplit("/", 1)[0] + "/calibration.json"
            assert json.loads(urllib.request.urlopen(beside, timeout=5).read())["k1"] == -0.05
            # The older request commands work too, as QGroundControl and MAVSDK still send them.
            assert gcs.command(mavlink.MAV_CMD_REQUEST_CAMERA_SETTINGS, 1, target_component=CAMERA) == 0
            assert gcs.recv("CAMERA_SETTINGS").mode_id == mavlink.CAMERA_MODE_IMAGE
            stream = request(gcs, mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, "VIDEO_STREAM_INFORMATION", 1)
            assert (stream.type, stream.encoding, stream.uri) == (mavlink.VIDEO_STREAM_TYPE_RTPUDP,
                                                                  mavlink.VIDEO_STREAM_ENCODING_H264,
                                                                  f"udp://127.0.0.1:{video_port}")
            assert (stream.resolution_h, stream.resolution_v) == (320, 240)
            assert stream.flags & mavlink.VIDEO_STREAM_STATUS_FLAGS_RUNNING

            gcs.send(gcs.mav.command_long_encode(1, CAMERA, mavlink.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 0, 1, 7, 0, 0, 0))
            ack = gcs.recv("COMMAND_ACK", cond=lambda m: m.command == mavlink.MAV_CMD_IMAGE_START_CAPTURE)
            assert ack.result == mavlink.MAV_RESULT_ACCEPTED
            shot = gcs.recv("CAMERA_IMAGE_CAPTURED", 10)
            assert (shot.image_index, shot.capture_result) == (ack.result_param2, 1)
            # Where the camera was: the world's fixed view over the floor (an exact pose estimate here).
            view = world.camera_view()
            lat, lon = ned_to_geo(view.north_m, view.east_m, world.cfg.home_lat, world.cfg.home_lon)
            assert (shot.lat, shot.lon) == (round(lat * 1e7), round(lon * 1e7))
            assert shot.relative_alt == round(-view.down_m * 1000)
            assert shot.alt == round((world.cfg.home_alt_m - view.down_m) * 1000)
            assert body_attitude(tuple(shot.q)) == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
            image = cv2.imdecode(np.frombuffer(urllib.request.urlopen(shot.file_url, timeout=5).read(), np.uint8),
                                 cv2.IMREAD_COLOR)
            assert image.shape[:2] == (960, 1280)

            # A resend of the same capture (its ACK lost) takes no second image; a request brings the first again.
            assert gcs.command(mavlink.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 7, target_component=CAMERA) == 0
            assert gcs.poll("CAMERA_IMAGE_CAPTURED", 0.5) is None and world.mavlink_camera.images == 1
            again = request(gcs, mavlink.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, "CAMERA_IMAGE_CAPTURED", shot.image_index)
            assert again.file_url == shot.file_url
            assert gcs.command(mavlink.MAV_CMD_DO_SET_SERVO, 1, 1500, target_component=CAMERA) == \
                mavlink.MAV_RESULT_UNSUPPORTED
            # A command for the autopilot is not the camera's to answer.
            gcs.send(gcs.mav.command_long_encode(1, 1, mavlink.MAV_CMD_IMAGE_STOP_CAPTURE, 0, 0, 0, 0, 0, 0, 0, 0))
            assert gcs.poll("COMMAND_ACK", 0.5) is None
            assert world.record().truth["camera_component"]["images"] == 1
        finally:
            gcs.close()


@pytest.mark.slow
def test_mavsdks_camera_plugin_takes_a_photo(tmp_path, monkeypatch):
    """MAVSDK (what real drone apps use) lists the camera, reads its definition and gets its captures."""
    import time

    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.camera import Camera

    from uav_agent.mavsdk_logs import route_mavsdk_logs

    monkeypatch.setenv("HOME", str(tmp_path))   # MAVSDK caches the definition file under ~/.cache
    route_mavsdk_logs()
    with camera_world(tmp_path) as (world, port):
        config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        sdk = Mavsdk(config)
        try:
            sdk.add_any_connection(f"udpin://127.0.0.1:{port}")
            deadline = time.monotonic() + 10
            while not sdk.get_systems() and time.monotonic() < deadline:
                time.sleep(0.05)
            camera = Camera(sdk.get_systems()[0])   # one plugin: a new one starts its discovery again
            cameras = []
            while not cameras and time.monotonic() < deadline:
                cameras = camera.camera_list().cameras
                time.sleep(0.1)
            assert cameras, "MAVSDK found no camera within 10 s"
            info = cameras[0]
            assert (info.component_id, info.model_name, info.horizontal_resolution_px) == (CAMERA, "simulated nadir camera", 1280)
            captures = []
            camera.subscribe_capture_info(lambda capture, _=None: captures.append(capture))
            camera.take_photo(CAMERA)
            while not captures and time.monotonic() < deadline + 5:
                time.sleep(0.05)
            assert captures and captures[0].is_success
            got = captures[0]
            view = world.camera_view()
            assert got.position.relative_altitude_m == pytest.approx(-view.down_m, abs=1e-3)
            assert got.file_url.startswith("http://127.0.0.1:") and got.file_url.endswith(".jpg")
        finally:
            sdk.destroy()
            config.destroy()


def test_the_mavlink_source_gives_the_frame_the_world_gives(tmp_path):
    """Perception gets the same CameraFrame from the MAVLink camera as from world/camera."""
    with camera_world(tmp_path) as (world, port):
        client = MemoryTransport(world.bus)
        zenoh = ZenohSource(client, Keys("cam"), iter(range(1, 1000)).__next__)
        source = open_camera_source(CameraSourceConfig("mavlink", f"udpin:127.0.0.1:{port}"), client, Keys("cam"),
                                    info_of(world), lambda: 0, lambda: (0.0,) * 6, timeout_s=5.0)
        try:
            assert isinstance(source, MavlinkSource)
            calib, direct = source.frame(calibration_only=True), zenoh.frame(calibration_only=True)
            for key in ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"):
                assert getattr(calib, key) == pytest.approx(getattr(direct, key)), key
            assert calib.png == b""
            got, want = source.frame(), zenoh.frame()
            assert (got.width, got.height, got.encoding) == (want.width, want.height, want.encoding) == (1280, 960, "jpeg")
            for key in ("north_m", "east_m", "down_m"):
                assert getattr(got, key) == pytest.approx(getattr(want, key), abs=0.01), key
            assert (got.yaw_rad, got.roll_rad, got.pitch_rad) == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
            image = cv2.imdecode(np.frombuffer(got.png, np.uint8), cv2.IMREAD_GRAYSCALE)
            assert image.shape == (960, 1280)
            found = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_1000)).detectMarkers(image)[1]
            assert sorted(found.ravel().tolist()) == [0, 1, 2]
        finally:
            source.close()
            client.close()


@pytest.mark.slow
def test_the_video_stream_plays_and_gives_frames_with_the_telemetry_pose(tmp_path):
    """A receiver finds the stream as a ground station does (VIDEO_STREAM_INFORMATION) and decodes it."""
    pytest.importorskip("av", reason="the video stream needs PyAV (pip install 'uav-robots[video]')")
    with camera_world(tmp_path, video=f"udp://127.0.0.1:{udp_port()}?fps=10&width=1280") as (world, port):
        pose = (-3.0, 4.0, -9.5, 0.1, 0.0, 0.0)
        source = open_camera_source(CameraSourceConfig("video", f"udpin:127.0.0.1:{port}"), None, Keys("cam"),
                                    info_of(world), lambda: 0, lambda: pose, timeout_s=5.0)
        try:
            assert isinstance(source, VideoSource)
            frame = source.frame()
            assert (frame.width, frame.height) == (1280, 960)
            assert frame.fx == pytest.approx(world.camera_model.fx) and frame.k1 == -0.05   # its calibration
            assert (frame.north_m, frame.east_m, frame.down_m, frame.yaw_rad) == pose[:4]
            image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_GRAYSCALE)
            found = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_1000)).detectMarkers(image)[1]
            assert found is not None and sorted(found.ravel().tolist()) == [0, 1, 2]
            assert world.mavlink_camera.video.frames >= 2 and not world.mavlink_camera.video.error
        finally:
            source.close()


@pytest.mark.parametrize("argv, needle", [
    (["-m", "sim_world", "--camera-video", "tcp://127.0.0.1:5600"], "--camera-video"),
    (["-m", "sim_world", "--camera-video", "udp://127.0.0.1:5600?fps=500"], "fps"),
    (["-m", "uav_agent", "--camera-source", "pigeon"], "--camera-source"),
    (["-m", "uav_agent", "--camera-source", "mavlink", "--camera-calibration", "/nonexistent/cal.json"], "calibration"),
])
@pytest.mark.process
def test_bad_camera_options_are_one_line_and_exit_2(argv, needle):
    res = subprocess.run([sys.executable, *argv], capture_output=True, text=True, timeout=60)
    assert res.returncode == 2, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0] and "Traceback" not in res.stderr


@pytest.mark.slow
@pytest.mark.process
def test_a_whole_mission_with_the_mavlink_camera_source(tmp_path):
    """The UAV triggers every image over MAVLink and fetches it over HTTP, on the default floor and camera."""
    res = subprocess.run([sys.executable, "-m", "uav_robots", "run", "--camera-source", "mavlink", "--out", str(tmp_path),
                          "--quiet"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["completed"] is True and report["uav"]["camera_source"] == "mavlink"
    taken = report["truth"]["camera_component"]
    assert taken["images"] >= 2 and taken["failed"] == 0 and taken["refused"] == 0
