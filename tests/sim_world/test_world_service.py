"""The world process: move batches, info, record, camera, lifecycle; in memory and over real Zenoh."""
from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol.config import client_config
from conformance import FakeUav, Hub, free_endpoint, stop_process
from protocol.codec import decode, encode
from protocol.keys import Keys
from protocol.messages import (CameraFrame, CameraRequest, MissionEnd, MoveRequest, MoveResult, Record, RecordRequest,
                               WorldInfo, WorldInfoRequest)
from protocol.transport import ZenohTransport
from sim_world.config import WorldConfig
from sim_world.service import World
from scenes import open_map

REPO = Path(__file__).resolve().parents[2]


def ask(client, world, robot, tick, frm, to, timeout=3.0):
    return client.request_start(world.keys.move, encode(MoveRequest(robot=robot, tick=tick, frm=frm, to=to)), timeout)


def result(pending) -> MoveResult:
    (raw,) = pending.wait()
    return decode(raw, MoveResult)


def test_info_and_record_describe_the_site(mem_world):
    world, client = mem_world
    info = decode(client.request(world.keys.world_info, encode(WorldInfoRequest()), 1)[0], WorldInfo)
    assert (info.width, info.height, info.cell_size_m) == (8, 6, 1.0)
    assert (info.home_lat, info.home_lon) == (47.397742, 8.545594)
    rec = decode(client.request(world.keys.record, encode(RecordRequest()), 1)[0], Record)
    assert rec.ticks == 0 and rec.collisions == 0 and rec.refused == []
    assert rec.truth["robots"] == {"0": [0, 0], "1": [1, 0], "2": [5, 5]}
    assert rec.truth["goals"] == [[7, 0], [7, 1], [5, 4]] and rec.truth["rows"][0] == "." * 8
    assert rec.executed == {"0": [(0, 0)], "1": [(1, 0)], "2": [(5, 5)]}


def test_a_tick_is_resolved_once_every_robot_asked(mem_world):
    world, client = mem_world
    # Robot 1 moves on and robot 0 follows it: legal only because the moves are judged together.
    p0 = ask(client, world, 0, 1, (0, 0), (1, 0))
    p1 = ask(client, world, 1, 1, (1, 0), (2, 0))
    time.sleep(0.1)
    assert world.judge.tick == 0, "resolved before every robot asked"
    p2 = ask(client, world, 2, 1, (5, 5), (5, 4))
    r0, r1, r2 = result(p0), result(p1), result(p2)
    assert r0.accepted and r0.cell == (1, 0) and r1.cell == (2, 0) and r2.cell == (5, 4)
    assert world.judge.tick == 1 and world.judge.refused == []


def test_missing_robots_stay_after_the_batch_timeout(mem_world):
    world, client = mem_world
    t0 = time.monotonic()
    r = result(ask(client, world, 0, 1, (0, 0), (0, 1)))
    assert r.accepted and time.monotonic() - t0 >= 0.35
    rec = world.record()
    assert rec.collisions == 0 and rec.executed["1"] == [(1, 0), (1, 0)]
    assert {e["robot"] for e in rec.refused} == {1, 2}
    assert all(not e["collision"] and "no move request" in e["reason"] for e in rec.refused)


def test_collisions_late_ticks_unknown_robots_and_resends(mem_world):
    world, client = mem_world
    # Head-on swap between 0 and 1: both refused and counted; robot 2 walks into... nothing, accepted.
    ps = [ask(client, world, 0, 1, (0, 0), (1, 0)), ask(client, world, 1, 1, (1, 0), (0, 0)),
          ask(client, world, 2, 1, (5, 5), (5, 4))]
    r0, r1, r2 = (result(p) for p in ps)
    assert not r0.accepted and not r1.accepted and "swap" in r0.reason and r0.cell == (0, 0)
    assert r2.accepted
    # The same request again (a lost reply): the same answer, nothing changes.
    again = result(ask(client, world, 2, 1, (5, 5), (5, 4)))
    assert again.accepted and again.cell == (5, 4) and world.judge.tick == 1
    late = result(ask(client, world, 0, 1, (0, 0), (0, 1)))
    assert not late.accepted and "over" in late.reason
    stranger = result(ask(client, world, 9, 2, (3, 3), (3, 4)))
    assert not stranger.accepted and "unknown robot 9" in stranger.reason
    rec = world.record()
    assert rec.collisions == 2
    assert sorted(e["collision"] for e in rec.refused) == [False, False, True, True]


def test_a_later_tick_closes_the_pending_one(mem_world):
    world, client = mem_world
    p = ask(client, world, 0, 1, (0, 0), (0, 1))
    time.sleep(0.05)
    q = ask(client, world, 1, 2, (1, 0), (2, 0))  # robot 1 missed tick 1: the fleet has moved on
    assert result(p).accepted
    time.sleep(0.05)
    assert world.judge.tick == 1
    rq = result(q)  # tick 2 completes at the batch timeout
    assert rq.accepted and rq.cell == (2, 0) and world.judge.tick == 2
    reasons = [e["reason"] for e in world.record().refused]
    assert any("before tick 2 began" in r for r in reasons)


def test_a_move_for_a_tick_far_ahead_is_refused_and_leaves_the_clock(mem_world, capsys):
    """One forged query for tick 100,000 used to be judged: the world's clock jumped there, every
    real move after it was 'over', and the mission aborted with nothing logged."""
    world, client = mem_world
    far = result(ask(client, world, 0, 100_000, (0, 0), (0, 0)))
    assert not far.accepted and "too far ahead" in far.reason and far.cell == (0, 0)
    assert world.judge.tick == 0 and world.record().refused == []
    assert "refused robot 0's move: tick 100000 is too far ahead" in capsys.readouterr().err
    # Up to four ahead is still a move of the mission, judged as always (tick 1, then 5: the others stay).
    ps = [ask(client, world, r, 1, c, c) for r, c in ((0, (0, 0)), (1, (1, 0)), (2, (5, 5)))]
    assert all(result(p).accepted for p in ps) and world.judge.tick == 1
    assert result(ask(client, world, 0, 5, (0, 0), (0, 1))).accepted and world.judge.tick == 5


def test_garbage_gets_no_reply_and_changes_nothing(mem_world, capsys):
    world, client = mem_world
    k = world.keys
    for key in (k.move, k.world_info, k.record, k.camera):
        assert client.request(key, b"\x00\xffnot a message", 0.3) == []
    wrong_version = encode(MoveRequest(robot=0, tick=1, frm=(0, 0), to=(0, 1))).replace(b'"v":1', b'"v":7')
    assert client.request(k.move, wrong_version, 0.3) == []
    assert world.judge.tick == 0 and world.judge.positions[0] == (0, 0)
    err = capsys.readouterr().err
    assert "warning: world:" in err and "Traceback" not in err
    assert result(ask(client, world, 0, 1, (0, 0), (0, 1))).accepted


def test_camera_renders_the_current_positions(mem_world):
    world, client = mem_world
    for r, (frm, to) in {0: ((0, 0), (0, 1)), 1: ((1, 0), (2, 0)), 2: ((5, 5), (5, 4))}.items():
        ask(client, world, r, 1, frm, to)
    assert world.judge.tick == 1
    (raw,) = client.request(world.keys.camera, encode(CameraRequest()), 10)
    frame = decode(raw, CameraFrame)
    image = cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (frame.height, frame.width, 3) and frame.down_m < 0
    # Project robot 0's new cell centre through the published pinhole model: its marker is there.
    det = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_1000))
    corners, ids, _ = det.detectMarkers(image)
    assert ids is not None and sorted(ids.ravel().tolist()) == [0, 1, 2]
    centre = corners[list(ids.ravel()).index(0)][0].mean(axis=0)
    north, east = -(1 + 0.5), 0 + 0.5
    depth = -frame.down_m
    u = frame.cx + frame.fx * (east - frame.east_m) / depth
    v = frame.cy - frame.fy * (north - frame.north_m) / depth
    assert abs(centre[0] - u) < 3 and abs(centre[1] - v) < 3


def test_a_calibration_only_request_gets_the_frame_without_an_image(mem_world):
    world, client = mem_world
    (raw,) = client.request(world.keys.camera, encode(CameraRequest(calibration_only=True)), 10)
    info = decode(raw, CameraFrame)
    assert info.png == b""
    (raw,) = client.request(world.keys.camera, encode(CameraRequest()), 10)
    frame = decode(raw, CameraFrame)
    assert frame.png and cv2.imdecode(np.frombuffer(frame.png, np.uint8), cv2.IMREAD_COLOR) is not None
    # the same calibration and encoding as an image's frame, and a pose from the same estimate
    calibration = ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "encoding",
                   "pose_sigma_m", "yaw_sigma_deg")
    assert {a: getattr(info, a) for a in calibration} == {a: getattr(frame, a) for a in calibration}
    assert abs(info.down_m - frame.down_m) < 1.0 and info.seq != frame.seq


@pytest.mark.process
def test_bad_config_is_one_line_error(tmp_path):
    run = subprocess.run([sys.executable, "-m", "sim_world", "--fleet", "f", "--map", "nosuch.map",
                          "--mavlink", "none"], cwd=REPO, capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and run.stderr.strip().startswith("error:") and len(run.stderr.strip().splitlines()) == 1
    run = subprocess.run([sys.executable, "-m", "sim_world", "--fleet", "bad fleet!", "--mavlink", "none"],
                         cwd=REPO, capture_output=True, text=True, timeout=30)
    assert run.returncode == 2 and "fleet name" in run.stderr


# ------------------------------------------------------------------ over Zenoh
def start_world(hub: Hub, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "sim_world", "--fleet", hub.fleet, "--connect", hub.endpoint,
                             "--robots", "3", "--camera", "ideal", *extra], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)


def wait_alive(hub: Hub, key: str, timeout: float = 15.0) -> bool:
    seen = threading.Event()
    h = hub.transport.watch_alive(key, lambda _k, alive: alive and seen.set())
    try:
        return seen.wait(timeout)
    finally:
        h.close()


@pytest.mark.slow
@pytest.mark.process
def test_world_process_serves_and_leaves_after_the_uav():
    with Hub() as hub:
        uav = FakeUav(hub.transport, hub.keys)
        proc = start_world(hub, "--mavlink", "none")
        try:
            assert wait_alive(hub, hub.keys.alive_world), proc.stderr.read() if proc.poll() is not None else ""
            assert proc.stdout.readline().startswith("world ready: fleet " + hub.fleet)
            raw = hub.transport.request(hub.keys.world_info, encode(WorldInfoRequest()), 5)
            assert decode(raw[0], WorldInfo).width == 24
            uav.end(True)
            time.sleep(1.5)
            assert proc.poll() is None, "the world left while the UAV could still want the record"
            rec = decode(hub.transport.request(hub.keys.record, encode(RecordRequest()), 5)[0], Record)
            assert len(rec.truth["robots"]) == 3
            uav.leave()
            assert proc.wait(15) == 0  # generous: CI machines are loaded; the usual is well under 1 s
            assert "mission ended" in proc.stdout.read()
        finally:
            stop_process(proc)
            uav.close()


@pytest.mark.process
def test_world_process_stops_on_sigterm_and_on_a_lone_mission_end():
    with Hub() as hub:
        proc = start_world(hub, "--mavlink", "none")
        try:
            assert wait_alive(hub, hub.keys.alive_world)
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(15) == 0  # generous: CI machines are loaded; the usual is well under 1 s
        finally:
            stop_process(proc)
        proc = start_world(hub, "--mavlink", "none")
        try:
            assert wait_alive(hub, hub.keys.alive_world)
            hub.transport.put(hub.keys.mission_end, b"garbage first")
            hub.transport.put(hub.keys.mission_end, encode(MissionEnd(completed=False, reason="test")))
            assert proc.wait(15) == 0  # no UAV was ever seen: a short grace, then gone
            assert "warning: world:" in proc.stderr.read()
        finally:
            stop_process(proc)


@pytest.mark.process
def test_world_with_its_vehicle_over_zenoh():
    """The camera follows the vehicle: on the ground the lens sits at its mount height."""
    with Hub() as hub:
        mav = free_endpoint().replace("tcp/", "udpout:")
        proc = start_world(hub, "--mavlink", mav, "--camera", "ideal,width=320,height=240")
        try:
            assert wait_alive(hub, hub.keys.alive_world), proc.stderr.read() if proc.poll() is not None else ""
            raw = hub.transport.request(hub.keys.camera, encode(CameraRequest()), 10)
            frame = decode(raw[0], CameraFrame)
            assert (frame.width, frame.height) == (320, 240)
            assert frame.north_m == pytest.approx(0, abs=1e-6) and frame.down_m == pytest.approx(-0.3, abs=1e-6)
            rec = decode(hub.transport.request(hub.keys.record, encode(RecordRequest()), 5)[0], Record)
            assert rec.truth["vehicle"]["armed"] is False and rec.truth["vehicle"]["url"] == mav
            proc.send_signal(signal.SIGTERM)
            assert proc.wait(15) == 0  # generous: CI machines are loaded; the usual is well under 1 s
        finally:
            stop_process(proc)


def test_world_in_process_on_zenoh_batches_two_clients(tmp_path):
    m, s = open_map(tmp_path, [(0, 0), (2, 0)], [(0, 5), (2, 5)])
    with Hub() as hub:
        world = World(WorldConfig(fleet=hub.fleet, map=m, scen=s, robots=2, mavlink=None, connect=[hub.endpoint]))
        world.start()
        a = ZenohTransport(client_config([hub.endpoint]), "a")
        b = ZenohTransport(client_config([hub.endpoint]), "b")
        try:
            assert wait_alive(hub, hub.keys.alive_world)
            k = Keys(hub.fleet)
            pa = a.request_start(k.move, encode(MoveRequest(robot=0, tick=1, frm=(0, 0), to=(1, 0))), 5)
            pb = b.request_start(k.move, encode(MoveRequest(robot=1, tick=1, frm=(2, 0), to=(1, 0))), 5)
            ra, rb = decode(pa.wait()[0], MoveResult), decode(pb.wait()[0], MoveResult)
            assert not ra.accepted and not rb.accepted and ra.cell == (0, 0) and rb.cell == (2, 0)
            assert world.judge.collisions == 2
        finally:
            a.close()
            b.close()
            world.close()


@pytest.mark.process
def test_world_leaves_when_the_uav_vanishes_mid_mission():
    with Hub() as hub:
        uav = FakeUav(hub.transport, hub.keys)
        proc = start_world(hub, "--mavlink", "none")
        try:
            assert wait_alive(hub, hub.keys.alive_world)
            time.sleep(0.3)
            assert proc.poll() is None
            uav.leave()  # no MissionEnd: the UAV crashed
            assert proc.wait(15) == 0  # generous: CI machines are loaded; the usual is well under 1 s
            assert "the UAV went away" in proc.stdout.read()
        finally:
            stop_process(proc)
            uav.close()


def _world_alone() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "sim_world"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, stdin=subprocess.DEVNULL)


@pytest.mark.slow
@pytest.mark.process
def test_the_world_alone_is_a_sitl_and_stops_within_a_second():
    """No arguments: its own router and the default fleet, the vehicle on PX4 SITL's usual port."""
    from pymavlink import mavutil

    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:14540")
    proc = _world_alone()
    try:
        ready = proc.stdout.readline()
        assert "world ready" in ready and "fleet default" in ready and "listening on" in ready, ready
        hb = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=10)
        assert hb is not None and hb.get_srcComponent() == 1
        t = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=5) == 0
        assert time.monotonic() - t < 1.0, f"SIGTERM took {time.monotonic() - t:.2f} s"
    finally:
        gcs.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.slow
@pytest.mark.process
def test_the_world_stops_promptly_while_it_waits_for_a_router():
    proc = subprocess.Popen([sys.executable, "-m", "sim_world", "--connect", "tcp/127.0.0.1:9", "--mavlink", "none"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        said = proc.stdout.readline()   # imports done, in its connect retries (a loaded machine: seconds)
        assert "waiting up to" in said and "for a Zenoh router at tcp/127.0.0.1:9" in said, said
        t = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=5) == 0, proc.stdout.read()
        # One 1 s connect attempt, then exit; a loaded CI machine adds a little.
        assert time.monotonic() - t < 3.0, f"SIGTERM took {time.monotonic() - t:.2f} s"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_region_of_interest_is_that_part_of_the_whole_image_with_its_principal_point_shifted(mem_world):
    """`CameraRequest.roi_*`: the crop a camera's ROI readout gives (a region past the sensor's
    edge is clipped to it; 0 wide is the whole image)."""
    world, client = mem_world
    (raw,) = client.request(world.keys.camera, encode(CameraRequest()), 10)
    whole = decode(raw, CameraFrame)
    (raw,) = client.request(world.keys.camera, encode(CameraRequest(roi_x=40, roi_y=24, roi_width=200,
                                                                    roi_height=100)), 10)
    part = decode(raw, CameraFrame)
    assert (part.width, part.height, part.cx, part.cy) == (200, 100, whole.cx - 40, whole.cy - 24)
    assert (part.fx, part.fy) == (whole.fx, whole.fy)
    big = cv2.imdecode(np.frombuffer(whole.png, np.uint8), cv2.IMREAD_COLOR).astype(int)
    small = cv2.imdecode(np.frombuffer(part.png, np.uint8), cv2.IMREAD_COLOR).astype(int)
    assert small.shape == (100, 200, 3) and np.abs(big[24:124, 40:240] - small).max() <= 1   # ideal camera: the same
    (raw,) = client.request(world.keys.camera, encode(CameraRequest(roi_x=whole.width - 10, roi_y=0, roi_width=500,
                                                                    roi_height=whole.height + 5)), 10)
    edge = decode(raw, CameraFrame)
    assert (edge.width, edge.height) == (10, whole.height)
    (raw,) = client.request(world.keys.camera, encode(CameraRequest(roi_x=5, roi_width=0, roi_height=50)), 10)
    assert decode(raw, CameraFrame).width == whole.width
