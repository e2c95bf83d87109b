"""The simulated autopilot, flown by a pymavlink client over real UDP on loopback."""
from __future__ import annotations

import math
import os
import random
import socket
import threading
import time

import pytest
from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import MissionError
from protocol.geo import cell_to_ned, check_home, geo_to_ned, ned_to_cell, ned_to_geo
from sim_world.vehicle import LandedState, Mode, Vehicle, VehicleConfig, step_toward, step_yaw

from mavlink_gcs import GCS_SYSID, Client, wait_for

NAN = float("nan")


@pytest.fixture
def client(vehicle):
    c = Client(vehicle.local_address[1])
    c.recv("HEARTBEAT")  # the vehicle has learned our address
    yield c
    c.close()


# --- geo and kinematics (pure) --------------------------------------------------------

def test_geo_round_trip_and_scale():
    home = (47.397742, 8.545594)
    for north, east in [(0.0, 0.0), (-450.0, 450.0), (123.4, -56.7)]:
        lat, lon = ned_to_geo(north, east, *home)
        back = geo_to_ned(lat, lon, *home)
        assert back == pytest.approx((north, east), abs=1e-6)
    lat, _ = ned_to_geo(111_319.49, 0.0, 0.0, 0.0)
    assert lat == pytest.approx(1.0, abs=1e-4)  # a degree of latitude is ~111.3 km
    # at 60 degrees north a metre east spans twice the longitude it does at the equator
    assert ned_to_geo(0.0, 1000.0, 60.0, 0.0)[1] == pytest.approx(2 * ned_to_geo(0.0, 1000.0, 0.0, 0.0)[1])
    assert ned_to_geo(0.0, 1000.0, 0.0, 179.9999)[1] < -179.99  # wraps across the antimeridian


def test_cells_and_ned_follow_the_image_convention():
    assert cell_to_ned(0, 0, 1.0) == (-0.5, 0.5)
    assert cell_to_ned(3, 7, 2.0) == (-15.0, 7.0)
    assert ned_to_cell(-15.0, 7.0, 2.0) == (3, 7)
    assert ned_to_cell(0.5, -0.5, 1.0) == (-1, -1)  # north of and west of the floor: off-grid


@pytest.mark.parametrize("home", [(91.0, 0.0), (0.0, 181.0), (NAN, 0.0), (89.0, 0.0)])
def test_bad_home_is_refused(home):
    with pytest.raises(MissionError):
        check_home(*home)


def test_step_toward_caps_speeds_and_never_overshoots():
    pos = step_toward((0.0, 0.0, 0.0), (30.0, 40.0, -100.0), 5.0, 2.0, 1.0, 1.0)
    assert math.hypot(pos[0], pos[1]) == pytest.approx(5.0)
    assert pos[0] / pos[1] == pytest.approx(0.75)
    assert pos[2] == pytest.approx(-2.0)  # climbing is negative down
    assert step_toward((0.0, 0.0, -10.0), (0.0, 0.0, 0.0), 5.0, 2.0, 1.0, 1.0)[2] == pytest.approx(-9.0)
    assert step_toward((1.0, 1.0, -1.0), (1.2, 1.0, -1.1), 5.0, 2.0, 1.0, 10.0) == pytest.approx((1.2, 1.0, -1.1))


def test_step_yaw_turns_the_short_way():
    assert step_yaw(math.radians(170), math.radians(-170), 1.0, 1.0) == pytest.approx(math.radians(-170))
    assert step_yaw(0.0, 3.0, 0.5, 1.0) == pytest.approx(0.5)
    assert step_yaw(0.0, -3.0, 0.5, 1.0) == pytest.approx(-0.5)


@pytest.mark.parametrize("kwargs", [dict(time_scale=0), dict(max_speed_m_s=-1), dict(system_id=0),
                                    dict(takeoff_alt_m=200), dict(home_lat=95.0), dict(max_alt_m=NAN)])
def test_bad_config_is_one_line_error(kwargs):
    with pytest.raises(MissionError):
        VehicleConfig(**kwargs)


def test_unusable_url_is_one_line_error():
    with pytest.raises(MissionError, match="cannot open"):
        Vehicle(VehicleConfig(url="udpin:not-a-host-or-port")).start()


# --- over MAVLink ---------------------------------------------------------------------

def test_heartbeat_identifies_a_px4_quadrotor_in_hold(client):
    hb = client.recv("HEARTBEAT")
    assert hb.get_srcSystem() == 1 and hb.get_srcComponent() == 1
    assert hb.type == mavlink.MAV_TYPE_QUADROTOR and hb.autopilot == mavlink.MAV_AUTOPILOT_PX4
    assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    assert (hb.custom_mode >> 16) & 0xFF == 4 and hb.custom_mode >> 24 == 3  # AUTO.LOITER
    state = client.recv("EXTENDED_SYS_STATE")
    assert state.landed_state == mavlink.MAV_LANDED_STATE_ON_GROUND
    for kind in ("GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "SYS_STATUS"):
        client.recv(kind)


def test_arm_takeoff_reposition_land(vehicle, client):
    cfg = vehicle.config
    assert client.command(mavlink.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == mavlink.MAV_RESULT_DENIED  # not armed
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    client.recv("HEARTBEAT", cond=lambda m: m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

    assert client.command(mavlink.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == mavlink.MAV_RESULT_ACCEPTED
    client.recv("GLOBAL_POSITION_INT", cond=lambda m: abs(m.relative_alt - 2_500) < 50)  # MIS_TAKEOFF_ALT, PX4's 2.5
    client.recv("EXTENDED_SYS_STATE", cond=lambda m: m.landed_state == mavlink.MAV_LANDED_STATE_IN_AIR)
    assert vehicle.in_air and vehicle.mode == Mode.HOLD
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0) == mavlink.MAV_RESULT_DENIED  # in the air

    lat, lon = ned_to_geo(20.0, -15.0, cfg.home_lat, cfg.home_lon)
    # relative altitude here; MAVSDK's AMSL variant is covered in test_flight.py
    client.send(client.mav.command_int_encode(1, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                              mavlink.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, 1.0,
                                              round(lat * 1e7), round(lon * 1e7), 12.0))
    assert client.recv("COMMAND_ACK", cond=lambda m: m.command == 192).result == mavlink.MAV_RESULT_ACCEPTED
    client.recv("LOCAL_POSITION_NED", cond=lambda m: math.dist((m.x, m.y, m.z), (20.0, -15.0, -12.0)) < 0.05)
    wait_for(lambda: abs(vehicle.pose()[3] - 1.0) < 1e-3)

    assert client.command(mavlink.MAV_CMD_NAV_LAND, *[NAN] * 7) == mavlink.MAV_RESULT_ACCEPTED
    client.recv("EXTENDED_SYS_STATE", cond=lambda m: m.landed_state == mavlink.MAV_LANDED_STATE_LANDING)
    client.recv("HEARTBEAT", timeout=5, cond=lambda m: not m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
    north, east, down, _ = vehicle.pose()
    assert (north, east, down) == pytest.approx((20.0, -15.0, 0.0), abs=0.05)
    assert vehicle.landed_state == LandedState.ON_GROUND and not vehicle.armed
    assert vehicle.max_altitude_m == pytest.approx(12.0, abs=0.01)
    texts = [text for _, text in vehicle.events]
    for expected in ("armed", "liftoff", "landed", "disarmed after landing"):
        assert expected in texts
    assert vehicle.bad_frames == 0


def test_altitude_is_clamped_to_max():
    with Vehicle(VehicleConfig(url="udpin:127.0.0.1:0", time_scale=20.0, max_alt_m=15.0,
                               takeoff_alt_m=5.0)) as vehicle:
        client = Client(vehicle.local_address[1])
        try:
            assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
            amsl = vehicle.config.home_alt_m + 500.0
            assert client.command(mavlink.MAV_CMD_DO_REPOSITION, -1, 0, 0, NAN, NAN, NAN, amsl) == 0
            client.recv("GLOBAL_POSITION_INT", cond=lambda m: m.relative_alt >= 14_990)
            time.sleep(0.3)
            assert vehicle.max_altitude_m == pytest.approx(15.0, abs=1e-6)
        finally:
            client.close()


def test_parameters_read_set_and_list(client):
    client.send(client.mav.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1))
    value = client.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT")
    assert value.param_value == pytest.approx(2.5) and value.param_type == mavlink.MAV_PARAM_TYPE_REAL32
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 25.0, mavlink.MAV_PARAM_TYPE_REAL32))
    assert client.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT").param_value == 25.0
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 5000.0, mavlink.MAV_PARAM_TYPE_REAL32))
    assert client.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT").param_value == 120.0
    client.send(client.mav.param_request_list_encode(1, 1))
    first = client.recv("PARAM_VALUE", cond=lambda m: m.param_index == 0)
    names = {first.param_id} | {client.recv("PARAM_VALUE", cond=lambda m, i=i: m.param_index == i).param_id
                                for i in range(1, first.param_count)}
    assert len(names) == first.param_count and "MIS_TAKEOFF_ALT" in names


def test_requests_and_unsupported_commands(vehicle, client):
    assert client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == 0
    version = client.recv("AUTOPILOT_VERSION")
    assert version.capabilities & mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION) == 0
    home = client.recv("HOME_POSITION")
    assert (home.latitude, home.longitude) == (round(vehicle.config.home_lat * 1e7), round(vehicle.config.home_lon * 1e7))
    assert client.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
                          100_000) == mavlink.MAV_RESULT_ACCEPTED
    assert client.command(mavlink.MAV_CMD_DO_SET_SERVO, 1, 1500) == mavlink.MAV_RESULT_UNSUPPORTED
    assert client.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 12345) == mavlink.MAV_RESULT_UNSUPPORTED
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, NAN) == mavlink.MAV_RESULT_DENIED
    # broadcast component 0 is answered too; another component's command is not ours to answer
    assert client.command(mavlink.MAV_CMD_DO_SET_SERVO, 1, 1500, target_component=0) == mavlink.MAV_RESULT_UNSUPPORTED
    client.send(client.mav.command_long_encode(1, 100, mavlink.MAV_CMD_DO_SET_SERVO, 0, 1, 1500, 0, 0, 0, 0, 0))
    assert client.poll("COMMAND_ACK", 0.5) is None


def test_offboard_needs_a_setpoint_stream_and_falls_back_to_hold(vehicle, client):
    px4_offboard = (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0)
    assert client.command(mavlink.MAV_CMD_DO_SET_MODE, *px4_offboard) == mavlink.MAV_RESULT_DENIED
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    stop = threading.Event()
    position_only = 0b110111111000

    def stream():
        while not stop.is_set():
            client.send(client.mav.set_position_target_local_ned_encode(
                0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, position_only, -5.0, 8.0, -6.0, 0, 0, 0, 0, 0, 0, 0, 0))
            stop.wait(0.1)

    sender = threading.Thread(target=stream, daemon=True)
    sender.start()
    try:
        time.sleep(0.3)
        assert client.command(mavlink.MAV_CMD_DO_SET_MODE, *px4_offboard) == mavlink.MAV_RESULT_ACCEPTED
        client.recv("HEARTBEAT", cond=lambda m: (m.custom_mode >> 16) & 0xFF == 6)
        wait_for(lambda: math.dist(vehicle.pose()[:3], (-5.0, 8.0, -6.0)) < 0.01)
    finally:
        stop.set()
        sender.join()
    wait_for(lambda: vehicle.mode == Mode.HOLD, timeout=3.0)  # setpoints lost for > 1 s
    assert math.dist(vehicle.pose()[:3], (-5.0, 8.0, -6.0)) < 0.01
    assert any("offboard setpoints lost" in text for _, text in vehicle.events)


def test_garbage_is_counted_and_the_vehicle_keeps_answering(vehicle, client):
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        target = ("127.0.0.1", vehicle.local_address[1])
        forger = mavlink.MAVLink(None, 66, 1)
        good = forger.command_long_encode(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
        bad_crc = bytearray(good.pack(forger))
        bad_crc[-1] ^= 0xFF
        truncated = bytes(good.pack(forger))[:12]
        absurd = forger.set_position_target_local_ned_encode(0, 1, 1, 99, 0, *[NAN] * 11)
        for payload in (os.urandom(200), b"\xfd" * 40, bytes(bad_crc), truncated, absurd.pack(forger), b"\x00"):
            attacker.sendto(payload, target)
        wait_for(lambda: vehicle.bad_frames >= 4)
        assert not vehicle.armed  # the corrupted arm command was dropped
        # still answering, and still to the real ground station, not to the sender of garbage
        client.send(client.mav.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1))
        assert client.recv("PARAM_VALUE").param_value == pytest.approx(2.5)
        assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_ACCEPTED
    finally:
        attacker.close()


def test_ping_is_answered(client):
    client.send(client.mav.ping_encode(123456, 7, 0, 0))
    reply = client.recv("PING")
    assert (reply.time_usec, reply.seq, reply.target_system) == (123456, 7, GCS_SYSID)


def test_stop_ends_threads_and_frees_the_port():
    vehicle = Vehicle(VehicleConfig(url="udpin:127.0.0.1:0")).start()
    port = vehicle.local_address[1]
    threads = list(vehicle._threads)
    vehicle.stop()
    assert not any(t.is_alive() for t in threads)  # stop() gives them 2 s to end
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", port))  # free again
    probe.close()
    vehicle.stop()  # idempotent


def test_forged_frames_with_absurd_values_never_break_the_vehicle(vehicle, client):
    """Well-formed frames (valid CRC) whose fields are NaN, infinite or out of range,
    for every message kind the vehicle handles, from a stranger's socket."""
    rng = random.Random(7)
    forger = mavlink.MAVLink(None, 66, 1)
    absurd = [NAN, math.inf, -math.inf, 0.0, -1.0, 1.0, 1e30, -1e30, 21196.0, 0.5]
    commands = [400, 22, 21, 192, 176, 17, 178, 512, 520, 511, 0, 65535]

    def f():
        return rng.choice(absurd)

    def i32():
        return rng.choice([0, 1, -1, 2**31 - 1, -2**31, 900_000_000])

    makers = [
        lambda: forger.command_long_encode(1, 1, rng.choice(commands), 0, f(), f(), f(), f(), f(), f(), f()),
        lambda: forger.command_int_encode(1, 1, rng.randrange(256), rng.choice(commands), 0, 0, f(), f(), f(), f(),
                                          i32(), i32(), f()),
        lambda: forger.param_set_encode(1, 1, rng.choice([b"MIS_TAKEOFF_ALT", b"MPC_XY_VEL_MAX", b"\xff\x00x"]),
                                        f(), rng.randrange(256)),
        lambda: forger.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", rng.choice([-1, 0, 6, 7, 32767])),
        lambda: forger.set_position_target_local_ned_encode(0, 1, 1, rng.choice([1, 8, 99]), rng.randrange(65536),
                                                            *[f() for _ in range(11)]),
        lambda: forger.set_mode_encode(1, rng.randrange(256), rng.randrange(2**32)),
        lambda: forger.timesync_encode(0, rng.randrange(2**63)),
        lambda: forger.ping_encode(rng.randrange(2**63), rng.randrange(2**32), 0, 0),
    ]
    attacker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        target = ("127.0.0.1", vehicle.local_address[1])
        for _ in range(400):
            attacker.sendto(rng.choice(makers)().pack(forger), target)
            if rng.random() < 0.1:
                attacker.sendto(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))), target)
        time.sleep(0.5)
        assert all(t.is_alive() for t in vehicle._threads)
        assert all(math.isfinite(v) for v in vehicle.pose())
        assert -vehicle.pose()[2] <= vehicle.config.max_alt_m
        client.send(client.mav.param_request_read_encode(1, 1, b"MIS_TAKEOFF_ALT", -1))
        client.recv("PARAM_VALUE", cond=lambda m: m.param_id == "MIS_TAKEOFF_ALT")
        client.recv("HEARTBEAT")
    finally:
        attacker.close()
