"""MAVSDK 4.x (through `Flight`) flying the simulated autopilot over real UDP on loopback."""
from __future__ import annotations

import math
import socket
import time

import pytest

from protocol.errors import MissionError
from sim_world.vehicle import LandedState, Vehicle, VehicleConfig
from protocol.codec import decode, encode
from protocol.messages import VehiclePose
from uav_agent.flight import Flight
from uav_agent.pose_feed import PoseFeed, read_pose


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def link():
    """A vehicle sending to a port where a Flight listens, like PX4 SITL and its offboard API."""
    port = free_udp_port()
    # Listening before the vehicle opens its socket, whose ephemeral port could otherwise be this one.
    flight = Flight(f"udpin://127.0.0.1:{port}").open()
    vehicle = Vehicle(VehicleConfig(url=f"udpout:127.0.0.1:{port}", time_scale=20.0)).start()
    yield vehicle, flight
    flight.close()
    vehicle.stop()


def test_connect_arm_takeoff_goto_land(link):
    vehicle, flight = link
    flight.connect(timeout_s=10)
    cfg = vehicle.config
    lat, lon, alt = flight.home()
    assert (lat, lon) == pytest.approx((cfg.home_lat, cfg.home_lon), abs=1e-7)
    assert alt == pytest.approx(cfg.home_alt_m, abs=0.01)
    assert not flight.armed and flight.position_ned() == pytest.approx((0.0, 0.0, 0.0), abs=0.02)

    flight.arm()
    assert flight.armed and vehicle.armed

    flight.takeoff(8.0, timeout_s=15)
    assert flight.in_air and vehicle.pose()[2] == pytest.approx(-8.0, abs=0.3)

    reached = flight.goto(-30.0, 25.0, 12.0, yaw_rad=0.5, timeout_s=15)
    assert reached == pytest.approx((-30.0, 25.0, -12.0), abs=0.5)
    time.sleep(0.3)  # let the last telemetry reach the ground station
    north, east, down, _ = vehicle.pose()
    assert (north, east, down) == pytest.approx((-30.0, 25.0, -12.0), abs=0.01)  # lat/lon quantisation only
    assert flight.position_ned() == pytest.approx((north, east, down), abs=0.01)  # both sides convert alike
    assert flight.pose()[3] == pytest.approx(0.5, abs=0.01)
    assert flight.flight_mode == "HOLD"
    # What the pose feed publishes for observers: the same frame and heading, the vehicle's state and battery.
    p = read_pose(flight, 1.5, seq=4)
    assert (p.north_m, p.east_m, p.down_m, p.yaw_rad) == pytest.approx((north, east, down, 0.5), abs=0.01)
    assert abs(p.roll_rad) < 0.05 and abs(p.pitch_rad) < 0.05
    assert (p.armed, p.in_air, p.mode, p.time_s, p.seq) == (True, True, "HOLD", 1.5, 4)
    assert p.battery_pct == pytest.approx(100 * vehicle.battery_remaining, abs=2.0)
    assert decode(encode(p), VehiclePose) == p
    flight.goto(-30.0, 20.0, 12.0, yaw_rad=None, timeout_s=15)  # keep the heading
    time.sleep(0.1)
    assert vehicle.pose()[3] == pytest.approx(0.5, abs=1e-3)

    flight.land(timeout_s=15)
    assert not flight.armed and not vehicle.armed
    assert vehicle.landed_state == LandedState.ON_GROUND and vehicle.pose()[2] == 0.0
    assert vehicle.bad_frames == 0  # MAVSDK sends nothing the vehicle cannot parse


@pytest.mark.slow
def test_an_autopilot_that_streams_nothing_until_asked_and_arms_late_is_connected_and_flown():
    """ArduPilot streams nothing but its heartbeat until a link asks (its SRn_ rates at 0), and MAVSDK asks
    for nothing: without asking, `connect` would wait for a home and a position that never come. It also
    refuses to arm for a while after it starts (its estimator settling): the arm is asked again."""
    port = free_udp_port()
    flight = Flight(f"udpin://127.0.0.1:{port}").open()
    vehicle = Vehicle(VehicleConfig(url=f"udpout:127.0.0.1:{port}", time_scale=20.0, streams_until_asked=True,
                                    ready_after_s=40.0)).start()
    try:
        flight.connect(timeout_s=10)
        assert flight.home()[:2] == pytest.approx((vehicle.config.home_lat, vehicle.config.home_lon), abs=1e-7)
        waited: list[str] = []
        flight.arm(timeout_s=10, on_wait=waited.append)
        assert len(waited) == 1 and "refused to arm" in waited[0] and "estimator not ready" in waited[0], waited
        assert vehicle.sim_time_s >= 40.0
        flight.takeoff(5.0, timeout_s=15)
        assert flight.goto(10.0, 0.0, 5.0, timeout_s=15) == pytest.approx((10.0, 0.0, -5.0), abs=0.5)
        assert flight.battery_pct > 0 and flight.in_air
        flight.land(timeout_s=15)
        assert flight.landed and not vehicle.armed
    finally:
        flight.close()
        vehicle.stop()


def test_connect_times_out_fast_without_a_vehicle():
    url = f"udpin://127.0.0.1:{free_udp_port()}"
    started = time.monotonic()
    with Flight(url) as flight, pytest.raises(MissionError, match=f"no autopilot at {url} within 1 s"):
        flight.connect(timeout_s=1.0)
    assert time.monotonic() - started < 10.0  # bounded by the timeout, not hanging


def test_bad_url_and_bad_arguments_are_one_line_errors(link):
    with pytest.raises(MissionError, match="cannot open MAVLink connection"):
        Flight("carrier-pigeon://nowhere").connect(timeout_s=1)
    _, flight = link
    with pytest.raises(MissionError, match="not connected"):
        flight.arm()
    with pytest.raises(MissionError, match="timeout"):
        flight.connect(timeout_s=-1)
    flight.connect(timeout_s=10)
    with pytest.raises(MissionError, match="takeoff altitude"):
        flight.takeoff(float("nan"))
    with pytest.raises(MissionError, match="finite"):
        flight.goto(0.0, float("inf"), 10.0)


def test_refused_command_is_a_mission_error(link):
    _, flight = link
    flight.connect(timeout_s=10)
    with pytest.raises(MissionError, match="refused to go to"):
        flight.goto(5.0, 5.0, 10.0, timeout_s=5)  # disarmed: the vehicle denies DO_REPOSITION


@pytest.mark.slow
def test_lost_link_ends_a_wait_early(link, monkeypatch):
    """A link silent for LINK_LOSS_S (30 s; 2 here) ends the wait before its own deadline; a shorter
    silence is waited out (tests/uav_agent/test_link_loss.py)."""
    import uav_agent.flight as flight_module

    monkeypatch.setattr(flight_module, "LINK_LOSS_S", 2.0)
    vehicle, flight = link
    flight.connect(timeout_s=10)
    flight.takeoff(5.0, timeout_s=15)
    vehicle.stop()
    started = time.monotonic()
    with pytest.raises(MissionError, match="did not answer|lost the autopilot link"):
        flight.goto(400.0, 400.0, 5.0, timeout_s=15)
    assert time.monotonic() - started < 10.0
    assert not math.isnan(flight.position_ned()[0])


def test_pose_feed_publishes_while_flying_and_drops_what_fails(link, capfd):
    vehicle, flight = link
    flight.connect(timeout_s=10)
    got, calls = [], [0]

    def publish(pose):
        calls[0] += 1
        if calls[0] == 2:
            raise RuntimeError("session closing")   # this one pose is dropped, the feed goes on
        got.append(pose)

    feed = PoseFeed(flight, publish, period_s=0.05)
    try:
        time.sleep(0.3)
        assert got == []                             # nothing before the mission says it flies
        feed.flying(True)
        flight.takeoff(5.0, timeout_s=15)
        time.sleep(0.3)
        feed.flying(False)
        time.sleep(0.2)
        n = len(got)
        time.sleep(0.3)
        assert len(got) == n >= 5                    # stopped when told
    finally:
        feed.close()
    assert got[0].down_m == pytest.approx(0.0, abs=0.3) and not got[0].in_air   # seen on the ground first
    assert min(p.down_m for p in got) == pytest.approx(-5.0, abs=0.3) and got[-1].in_air and got[-1].armed
    assert [p.seq for p in got] == sorted(p.seq for p in got) and len({p.seq for p in got}) == n
    assert "warning: uav pose feed: pose not published: session closing" in capfd.readouterr().err
