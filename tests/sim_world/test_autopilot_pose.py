"""The world follows an autopilot it does not fly: our vehicle as a process of its own (`uav-robots
vehicle`), the pose read from its MAVLink telemetry (sim_world/pose_follower.py), and a whole
`uav-robots run --autopilot URL --autopilot-pose URL` against it. Real MAVLink over UDP on loopback;
the pure parts (the floor frame pinned at the first home, interpolation, the clock) beside them."""
from __future__ import annotations

import json
import math
import signal
import socket
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import UavRobotsError
from protocol.geo import ned_to_geo
from sim_world.pose_follower import PoseFollower, check_pose_url, parse_origin, pymavlink_url
from sim_world.pose_track import BootClock, FloorFrame, Track, Truth
from sim_world.vehicle import Vehicle, VehicleConfig
from uav_robots.run.launcher import mavsdk_url

from mavlink_gcs import Client, wait_for

m = mavlink
HOME = (47.397742, 8.545594, 488.0)


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def drain(gcs: Client) -> None:
    """Read what the vehicle sent meanwhile: a full socket buffer would drop the next COMMAND_ACK."""
    gcs.poll("none", 0.2)
    gcs.pending.clear()


def test_the_floor_stays_where_the_first_home_put_it_and_poses_come_at_their_instant():
    # An autopilot that moves home where it arms (ArduPilot) must not move the floor.
    frame = FloorFrame()
    assert frame.from_local((1.0, 2.0, -3.0)) is None            # no home yet: nowhere on the floor
    assert frame.on_home(*HOME, 4.0, -2.0, 0.5)                  # home stands at local (4, -2, 0.5)
    assert frame.from_local((4.0, -2.0, 0.5)) == (0.0, 0.0, 0.0)  # ... which is the floor's corner
    assert not frame.on_home(47.3978, 8.5457, 489.0, 15.0, 6.0, -1.0)   # moved at arming: not re-pinned
    assert frame.from_local((14.0, 8.0, -9.5)) == (10.0, 10.0, -10.0)
    # GLOBAL_POSITION_INT lands on the same floor point as the local position does.
    # Local (14, 8, -10), i.e. floor (10, 10, -10.5): 1 m south, 2 m east and 9 m above the moved home.
    lat, lon = ned_to_geo(-1.0, 2.0, 47.3978, 8.5457)
    got = frame.from_global(lat, lon, 498.0)
    assert got is not None and all(abs(a - b) < 0.05 for a, b in zip(got, (10.0, 10.0, -10.5))), got
    # An indoor autopilot: its local origin placed on the floor, no home needed.
    assert FloorFrame((5.0, 6.0, 0.0)).from_local((1.0, 1.0, -2.0)) == (6.0, 7.0, -2.0)
    assert parse_origin("home") is None and parse_origin("5,6,0") == (5.0, 6.0, 0.0)
    with pytest.raises(UavRobotsError, match="--autopilot-origin"):
        parse_origin("5,6")

    # Interpolated between the samples around the instant; past the last, carried on at its velocity.
    track = Track()
    track.add_position(10.0, (0.0, 0.0, -10.0), (10.0, 0.0, 0.0))
    track.add_position(10.1, (1.0, 0.0, -10.0), (10.0, 0.0, 0.0))
    track.add_attitude(10.0, 0.0, -0.1, math.radians(179.0))
    track.add_attitude(10.1, 0.0, -0.1, math.radians(-179.0))
    mid = track.at(10.05)
    assert mid.north_m == pytest.approx(0.5) and abs(abs(mid.yaw_rad) - math.pi) < 1e-9   # the short way round
    assert track.at(10.2).north_m == pytest.approx(2.0) and track.at(20.0).north_m == pytest.approx(6.0)

    # A sample's instant is its autopilot clock plus the link's delay floor: one read 80 ms late by a
    # busy process keeps the instant it was measured.
    clock = BootClock()
    arrivals = [(1.00, 101.001), (1.02, 101.021), (1.04, 101.121), (1.06, 101.061)]
    assert [round(clock.local(b, a), 3) for b, a in arrivals] == [101.001, 101.021, 101.041, 101.061]

    truth = Truth()
    for alt, vz in ((5.0, 8.0), (0.05, 0.0)):      # falling at 8 m/s, then on the floor
        truth.on_position(alt, vz, 3.0)
    assert any("hit the ground at 8.0 m/s" in text for _, text in truth.events)
    assert truth.landed_name() == "ON_GROUND"

    # Links as either tool spells them; a pose link open to other hosts is said, not opened.
    assert pymavlink_url("udpin://127.0.0.1:14550") == "udpin:127.0.0.1:14550"
    assert pymavlink_url("udp://:14550") == "udpin:0.0.0.0:14550"
    assert mavsdk_url("udpin:0.0.0.0:14540") == "udpin://0.0.0.0:14540" and mavsdk_url("udpin://:1") == "udpin://:1"
    with pytest.raises(UavRobotsError, match="--mavlink-bind"):
        check_pose_url("udpin:0.0.0.0:14550", "127.0.0.1")


@pytest.mark.slow
def test_the_followed_pose_is_the_vehicles_at_each_instant_in_flight():
    """Our vehicle sends its telemetry on a third link; the follower asks it for 50 Hz and its pose at
    instants already past matches what the vehicle itself was at each, on the ground, climbing, flying
    and hovering."""
    pose_port = free_port()
    vehicle = Vehicle(VehicleConfig(url="udpin:127.0.0.1:0", pose_url=f"udpout:127.0.0.1:{pose_port}",
                                    time_scale=10.0)).start()
    follower = gcs = None
    try:
        follower = PoseFollower(f"udpin://127.0.0.1:{pose_port}").start()
        gcs = Client(vehicle.local_address[1], heartbeat_hz=4.0)
        wait_for(lambda: follower.pose_at(time.monotonic()) is not None, 10.0, "a followed pose")
        t = time.monotonic()
        time.sleep(1.0)
        samples = sum(1 for s in follower.track._pt if t <= s <= t + 1.0)
        assert samples >= 35, f"{samples} LOCAL_POSITION_NED in 1 s: the 50 Hz asked for was not applied"

        drain(gcs)
        assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
        assert gcs.command(m.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, HOME[2] + 15.0) \
            == m.MAV_RESULT_ACCEPTED
        lat, lon = ned_to_geo(60.0, 30.0, HOME[0], HOME[1])
        seen: list[tuple[float, tuple]] = []   # (instant, the vehicle's true state then)

        def watch(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                now = time.monotonic()
                seen.append((now, vehicle.state()))
                time.sleep(0.037)

        wait_for(lambda: vehicle.state().pos[2] < -14.0, 20.0, "the climb to 15 m")
        drain(gcs)
        assert gcs.command(m.MAV_CMD_DO_REPOSITION, -1, 1, 0, 90.0, lat, lon, HOME[2] + 15.0) == m.MAV_RESULT_ACCEPTED
        watch(0.8)
        wait_for(lambda: math.dist(vehicle.state().pos[:2], (60.0, 30.0)) < 0.2, 20.0, "the goto")
        watch(0.5)
        time.sleep(0.3)   # every instant now lies in the past
        moving = 0
        for at, st in seen:
            p = follower.pose_at(at, 0.25)
            speed = math.hypot(*st.vel)
            moving += math.hypot(*st.vel[:2]) > 3.0
            # The vehicle moves in 20 ms physics steps (0.2 simulated s at time scale 10): the telemetry
            # sampled them, so the pose is within two steps of flight of the truth at that instant.
            tolerance = 0.15 + 2 * 0.2 * max(speed, math.hypot(p.vel_north, p.vel_east, p.vel_down))
            error = math.dist((p.north_m, p.east_m, p.down_m), st.pos)
            assert error < tolerance, f"at {at:.3f}: followed {p[:3]}, true {st.pos} ({speed:.1f} m/s)"
            # and its yaw within two steps of a 90 deg/s turn
            assert abs((p.yaw_rad - st.yaw + math.pi) % (2 * math.pi) - math.pi) < math.radians(40)
        assert moving >= 3, "the vehicle was not seen in flight"
        hover, st = follower.pose_at(time.monotonic(), 0.25), vehicle.state()
        assert math.dist(hover[:3], (60.0, 30.0, -15.0)) < 0.3 and abs(hover.yaw_rad - st.yaw) < 0.01
        truth = follower.truth()
        assert truth["armed"] and truth["landed_state"] == "IN_AIR" and truth["max_altitude_m"] > 14.0
        assert truth["source"] == "telemetry" and truth["bad_frames"] == 0
    finally:
        if gcs is not None:
            gcs.close()
        if follower is not None:
            follower.close()
        vehicle.stop()


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.mark.slow
@pytest.mark.process
def test_a_whole_run_flies_an_external_autopilot_and_renders_from_its_pose(tmp_path):
    """`uav-robots vehicle` started on its own, as a SITL binary; `uav-robots run --autopilot
    --autopilot-pose` starts no vehicle, the UAV flies that one and the world's camera follows it over
    MAVLink (the images show the floor and every robot where they are), and the world's record of the
    vehicle comes from its telemetry."""
    uav_port, pose_port = free_port(), free_port()
    vehicle_log = tmp_path / "vehicle.log"
    with open(vehicle_log, "w") as log:
        vehicle = subprocess.Popen([sys.executable, "-m", "uav_robots", "vehicle", "--mavlink",
                                    f"udpout:127.0.0.1:{uav_port}", "--gcs", f"udpout:127.0.0.1:{pose_port}",
                                    # as ArduCopter: a goto's yaw is not flown, it keeps the heading it has
                                    "--heading", "30", "--param", "SIM_GOTO_YAW=0",
                                    "--time-scale", "10"], stdout=log, stderr=subprocess.STDOUT,
                                   stdin=subprocess.DEVNULL)
    out = tmp_path / "out"
    try:
        run = subprocess.run([sys.executable, "-m", "uav_robots", "run", "--autopilot", f"udpin://127.0.0.1:{uav_port}",
                              "--autopilot-pose", f"udpin:127.0.0.1:{pose_port}", "--robots", "3", "--camera", "ideal",
                              "--time-scale", "10", "--quiet", "--out", str(out)],
                             capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL)
        assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
        assert vehicle.poll() is None, "the launcher must leave an autopilot it did not start alone"
    finally:
        _stop(vehicle)
    report = json.loads((out / "report.json").read_text())
    assert report["completed"] is True and report["processes"]["vehicle"] is None
    perceived = report["perceived"]   # from images rendered where the followed pose said the camera was
    assert perceived["map_matches_truth"] and perceived["robots"] == report["truth"]["robots"], perceived
    # turned 30 degrees, the survey's tiles were what a turned image holds: no cell left for a closer look
    assert report["uav"]["heading_kept_deg"] == pytest.approx(30.0, abs=1.0)
    assert not [e for e in report["events"] if e["kind"] == "closer-look"], report["events"]
    truth = report["truth"]["vehicle"]
    assert truth["source"] == "telemetry" and truth["url"] == f"udpin:127.0.0.1:{pose_port}"
    assert truth["max_altitude_m"] > 5.0 and not truth["armed"] and truth["landed_state"] == "ON_GROUND"
    assert [e for _, e in truth["events"] if e in ("armed", "disarmed")] == ["armed", "disarmed"]
    world_log = (out / "logs" / "world.log").read_text()
    assert f"following the autopilot on udpin:127.0.0.1:{pose_port}" in world_log
    said = vehicle_log.read_text()
    assert "vehicle ready" in said and "takeoff" in said and "landed" in said and "vehicle: stopped" in said


@pytest.mark.slow
@pytest.mark.process
def test_an_indoor_vehicle_without_gps_flies_the_mission_in_its_local_frame(tmp_path):
    """`--vehicle-preset indoor`: no GPS, no home, no global position (PX4 on vision or optical flow). The
    UAV finds no home, flies the autopilot's local frame with offboard position setpoints, and the world
    places the vehicle by its local origin: the mission completes as outdoors."""
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-m", "uav_robots", "run", "--vehicle-preset", "indoor", "--robots", "3",
                          "--camera", "ideal", "--quiet", "--out", str(out)],
                         capture_output=True, text=True, timeout=240, stdin=subprocess.DEVNULL)
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["completed"] is True and report["uav"]["frame"] == "local" and report["uav"]["landed"]
    said = (out / "logs" / "vehicle.log").read_text()
    assert "indoor: no GPS" in said and "Mode HOLD -> OFFBOARD" in said
    assert "Reposition denied" not in said   # never a global goto to an autopilot with no global position
