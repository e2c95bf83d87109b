"""The simulated vehicle as a ground station sees it: the mission protocol and AUTO.MISSION,
RTL, STATUSTEXT, the battery, the geofence, the datalink-loss failsafe, the signed
ground-station link and the loopback binding. Real MAVLink over UDP on loopback; the
mission flight and `uav-robots run --gcs` use the real processes."""
from __future__ import annotations

import json
import math
import signal
import socket
import subprocess
import sys
import time

import psutil
import pytest
from pymavlink.dialects.v20 import common as mavlink

from protocol.errors import MissionError
from protocol.geo import ned_to_geo
from sim_world.vehicle import LandedState, Mode, Vehicle, VehicleConfig

from mavlink_gcs import Client, px4_mode, set_mode, set_param, wait_for

NAN = float("nan")
m = mavlink
REL = m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
KEY = bytes(range(32))


def free_port(kind=socket.SOCK_DGRAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def gcs(vehicle):
    c = Client(vehicle.local_address[1], heartbeat_hz=4.0)
    c.recv("HEARTBEAT")
    yield c
    c.close()


def item(seq: int, command: int, north: float = 0.0, east: float = 0.0, alt: float = 0.0, p1: float = 0.0,
         frame: int = REL, home=(VehicleConfig.home_lat, VehicleConfig.home_lon)):
    """A MISSION_ITEM_INT's fields (without target) at (north, east) from home; (0, 0) is "here"."""
    lat, lon = ned_to_geo(north, east, *home)
    x, y = (0, 0) if north == east == 0 else (round(lat * 1e7), round(lon * 1e7))
    return (seq, frame, command, 0, 1, p1, 0.0, 0.0, NAN, x, y, alt)


def plan(legs=((20.0, 0.0), (20.0, 20.0), (0.0, 20.0)), alt: float = 6.0):
    """Takeoff, a waypoint per leg, RTL."""
    items = [item(0, m.MAV_CMD_NAV_TAKEOFF, alt=alt)]
    items += [item(i + 1, m.MAV_CMD_NAV_WAYPOINT, n, e, alt) for i, (n, e) in enumerate(legs)]
    items.append(item(len(items), m.MAV_CMD_NAV_RETURN_TO_LAUNCH, frame=m.MAV_FRAME_MISSION))
    return items


def upload(c: Client, items, target=(1, 1)) -> int:
    """Answer the vehicle's requests until its MISSION_ACK; returns the ack's result."""
    c.send(c.mav.mission_count_encode(*target, len(items), m.MAV_MISSION_TYPE_MISSION))
    while True:
        msg = c.recv(("MISSION_REQUEST_INT", "MISSION_ACK"))
        if msg.get_type() == "MISSION_ACK":
            return msg.type
        c.send(c.mav.mission_item_int_encode(*target, *items[msg.seq], m.MAV_MISSION_TYPE_MISSION))


def download(c: Client) -> list:
    c.send(c.mav.mission_request_list_encode(1, 1, m.MAV_MISSION_TYPE_MISSION))
    count = c.recv("MISSION_COUNT").count
    got = []
    for seq in range(count):
        c.send(c.mav.mission_request_int_encode(1, 1, seq, m.MAV_MISSION_TYPE_MISSION))
        got.append(c.recv("MISSION_ITEM_INT", cond=lambda msg, s=seq: msg.seq == s))
    c.send(c.mav.mission_ack_encode(1, 1, m.MAV_MISSION_ACCEPTED, m.MAV_MISSION_TYPE_MISSION))
    return got


def said(c: Client, words: str, timeout: float = 3.0):
    return c.said(words, timeout)


def fly_to(c: Client, north: float, east: float, alt: float) -> int:
    lat, lon = ned_to_geo(north, east, VehicleConfig.home_lat, VehicleConfig.home_lon)
    c.send(c.mav.command_int_encode(1, 1, REL, m.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, NAN,
                                    round(lat * 1e7), round(lon * 1e7), alt))
    return c.recv("COMMAND_ACK", cond=lambda msg: msg.command == m.MAV_CMD_DO_REPOSITION).result


def airborne_at(c: Client, vehicle: Vehicle, alt: float) -> None:
    assert c.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
    assert c.command(m.MAV_CMD_NAV_TAKEOFF, *[NAN] * 6, VehicleConfig.home_alt_m + alt) == m.MAV_RESULT_ACCEPTED
    wait_for(lambda: vehicle.mode == Mode.HOLD and abs(vehicle.pose()[2] + alt) < 0.05, what="takeoff")


# --- the mission protocol --------------------------------------------------------------

def test_upload_download_clear_and_refusals(vehicle, gcs):
    items = plan()
    assert upload(gcs, items) == m.MAV_MISSION_ACCEPTED
    said(gcs, "Mission uploaded: 5 items")
    got = download(gcs)
    assert [(g.seq, g.frame, g.command, g.x, g.y, g.z) for g in got] == [
        (i[0], i[1], i[2], i[9], i[10], pytest.approx(i[11])) for i in items]
    current = gcs.recv("MISSION_CURRENT", cond=lambda msg: msg.total == 5)
    assert current.seq == 0 and current.mission_state == m.MISSION_STATE_NOT_STARTED
    gcs.send(gcs.mav.mission_set_current_encode(1, 1, 2))
    gcs.recv("MISSION_CURRENT", cond=lambda msg: msg.seq == 2)

    # an item this vehicle cannot fly refuses the whole upload, and keeps the stored mission
    bad = [*items[:2], (2, REL, m.MAV_CMD_NAV_SPLINE_WAYPOINT, 0, 1, 0, 0, 0, 0, 1, 1, 5.0)]
    assert upload(gcs, bad) == m.MAV_MISSION_UNSUPPORTED
    said(gcs, "Mission rejected: item 2")
    assert upload(gcs, [item(0, m.MAV_CMD_NAV_WAYPOINT, 5, 5, 5, frame=m.MAV_FRAME_LOCAL_NED)]) == \
        m.MAV_MISSION_UNSUPPORTED_FRAME
    gcs.send(gcs.mav.mission_count_encode(1, 1, 3, m.MAV_MISSION_TYPE_FENCE))
    ack = gcs.recv("MISSION_ACK")
    assert (ack.type, ack.mission_type) == (m.MAV_MISSION_UNSUPPORTED, m.MAV_MISSION_TYPE_FENCE)
    assert len(download(gcs)) == 5

    gcs.send(gcs.mav.mission_clear_all_encode(1, 1, m.MAV_MISSION_TYPE_MISSION))
    assert gcs.recv("MISSION_ACK").type == m.MAV_MISSION_ACCEPTED
    assert download(gcs) == []
    assert set_mode(gcs, 4, 4) == m.MAV_RESULT_DENIED  # AUTO.MISSION with no mission
    said(gcs, "no mission uploaded")


@pytest.mark.slow
def test_upload_requests_again_and_times_out(vehicle, gcs):
    gcs.send(gcs.mav.mission_count_encode(1, 1, 2, m.MAV_MISSION_TYPE_MISSION))
    first = gcs.recv("MISSION_REQUEST_INT")
    t = time.monotonic()
    again = gcs.recv("MISSION_REQUEST_INT", 2.0)  # the item "got lost": asked again
    assert (first.seq, again.seq) == (0, 0) and time.monotonic() - t < 1.0
    ack = gcs.recv("MISSION_ACK", 8.0)  # a silent ground station: the upload is given up
    assert ack.type == m.MAV_MISSION_OPERATION_CANCELLED
    said(gcs, "Mission upload timed out")


# --- modes, takeoff, STATUSTEXT -------------------------------------------------------------

def test_mavproxy_takeoff_10_climbs_to_10_m_and_low_takeoffs_are_raised(vehicle, gcs):
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
    # MAVProxy's `takeoff 10`: COMMAND_LONG NAV_TAKEOFF, param7 = 10 (meant above home)
    assert gcs.command(m.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10) == m.MAV_RESULT_ACCEPTED
    said(gcs, "taken as 10 m above home")
    gcs.recv("GLOBAL_POSITION_INT", 5.0, cond=lambda msg: abs(msg.relative_alt - 10_000) < 20)
    wait_for(lambda: vehicle.mode == Mode.HOLD)
    time.sleep(0.3)
    assert -vehicle.pose()[2] == pytest.approx(10.0, abs=0.01)  # holds there, not where the climb was called done
    assert gcs.command(m.MAV_CMD_NAV_LAND) == m.MAV_RESULT_ACCEPTED
    wait_for(lambda: not vehicle.armed, 10.0, "landing")
    # a true AMSL altitude 1 m above home is below MIS_TAKEOFF_ALT (2.5 m): raised, as PX4 does
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
    assert gcs.command(m.MAV_CMD_NAV_TAKEOFF, *[NAN] * 6, VehicleConfig.home_alt_m + 1) == m.MAV_RESULT_ACCEPTED
    assert said(gcs, "Using minimum takeoff altitude: 2.50 m").severity == m.MAV_SEVERITY_CRITICAL
    wait_for(lambda: vehicle.mode == Mode.HOLD and abs(vehicle.pose()[2] + 2.5) < 1e-6, what="takeoff to 2.5 m")


def test_statustext_on_every_mode_change_and_refusal(vehicle, gcs):
    assert gcs.command(m.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == m.MAV_RESULT_DENIED
    assert said(gcs, "Takeoff denied: disarmed").severity == m.MAV_SEVERITY_CRITICAL
    assert gcs.command(m.MAV_CMD_DO_SET_SERVO, 1, 1500) == m.MAV_RESULT_UNSUPPORTED
    said(gcs, "Command DO_SET_SERVO refused: UNSUPPORTED")
    assert gcs.command(m.MAV_CMD_GET_HOME_POSITION) == m.MAV_RESULT_ACCEPTED  # MAVProxy asks so at connect
    gcs.recv("HOME_POSITION")
    assert set_mode(gcs, 1) == m.MAV_RESULT_DENIED  # MANUAL needs sticks
    said(gcs, "Mode MANUAL not available")
    assert set_mode(gcs, 4, 5) == m.MAV_RESULT_DENIED  # RTL on the ground
    said(gcs, "Return denied")
    airborne_at(gcs, vehicle, 5.0)
    assert said(gcs, "Mode HOLD -> TAKEOFF").severity == m.MAV_SEVERITY_INFO
    said(gcs, "Mode TAKEOFF -> HOLD")
    assert set_mode(gcs, 3) == m.MAV_RESULT_ACCEPTED  # POSCTL: holds where it is
    said(gcs, "Mode HOLD -> POSCTL")
    assert px4_mode(gcs.recv("HEARTBEAT", cond=lambda hb: px4_mode(hb) == (3, 0))) == (3, 0)
    here = vehicle.pose()[:3]
    time.sleep(0.3)
    assert vehicle.pose()[:3] == pytest.approx(here, abs=1e-6)
    assert set_mode(gcs, 4, 6) == m.MAV_RESULT_ACCEPTED  # LAND
    said(gcs, "Mode POSCTL -> LAND")
    wait_for(lambda: not vehicle.armed, 10.0, "landed and disarmed")
    assert vehicle.landed_state == LandedState.ON_GROUND


def test_rtl_climbs_flies_home_lands_and_disarms(vehicle, gcs):
    assert set_param(gcs, "RTL_RETURN_ALT", 12.0) == 12.0
    airborne_at(gcs, vehicle, 5.0)
    assert fly_to(gcs, 30.0, -20.0, 5.0) == m.MAV_RESULT_ACCEPTED
    wait_for(lambda: math.dist(vehicle.pose()[:2], (30.0, -20.0)) < 0.05, what="reposition")
    assert gcs.command(m.MAV_CMD_NAV_RETURN_TO_LAUNCH) == m.MAV_RESULT_ACCEPTED
    gcs.recv("HEARTBEAT", cond=lambda hb: px4_mode(hb) == (4, 5))
    wait_for(lambda: not vehicle.armed, 15.0, "RTL landed and disarmed")
    assert vehicle.pose()[:3] == pytest.approx((0.0, 0.0, 0.0), abs=0.35)
    assert vehicle.max_altitude_m == pytest.approx(12.0, abs=0.01)  # climbed to the return altitude first


# --- battery -----------------------------------------------------------------------------

@pytest.mark.slow
def test_battery_drains_and_a_critical_battery_brings_it_back(vehicle, gcs):
    full = gcs.recv("BATTERY_STATUS")
    cells = int(vehicle.param("BAT1_N_CELLS"))
    assert full.battery_remaining == 100 and all(v > 4000 for v in full.voltages[:cells])
    assert all(v == 65535 for v in full.voltages[cells:])   # UINT16_MAX: no such cell
    assert set_param(gcs, "BAT1_CAPACITY", 400.0) == 400.0  # 15 A hover: 96 simulated seconds
    airborne_at(gcs, vehicle, 5.0)
    assert fly_to(gcs, 15.0, 0.0, 5.0) == m.MAV_RESULT_ACCEPTED
    draining = gcs.recv("BATTERY_STATUS", cond=lambda b: b.battery_remaining < 90)
    assert draining.current_battery >= 1500 and draining.current_consumed > 40  # cA, mAh
    assert gcs.recv("SYS_STATUS", cond=lambda s: s.battery_remaining < 90).voltage_battery < full.voltages[0] * cells
    assert said(gcs, "Low battery level", 10.0).severity == m.MAV_SEVERITY_WARNING
    assert said(gcs, "Critical battery level", 5.0).severity == m.MAV_SEVERITY_CRITICAL
    said(gcs, "Failsafe: critical battery, RTL")
    gcs.recv("HEARTBEAT", cond=lambda hb: px4_mode(hb) in ((4, 5), (4, 6)))
    wait_for(lambda: not vehicle.armed, 15.0, "battery failsafe landing")
    assert vehicle.landed_state == LandedState.ON_GROUND and vehicle.battery_remaining < 0.07
    assert gcs.recv("BATTERY_STATUS").charge_state >= m.MAV_BATTERY_CHARGE_STATE_CRITICAL


# --- geofence ----------------------------------------------------------------------------

@pytest.mark.slow
def test_geofence_refuses_far_targets_clamps_offboard_and_a_breach_returns(vehicle, gcs):
    assert set_param(gcs, "GF_MAX_HOR_DIST", 30.0) == 30.0
    airborne_at(gcs, vehicle, 5.0)
    assert fly_to(gcs, 100.0, 0.0, 5.0) == m.MAV_RESULT_DENIED
    said(gcs, "Reposition denied: target outside the geofence")

    def setpoint(n, e, d):  # position only
        gcs.send(gcs.mav.set_position_target_local_ned_encode(0, 1, 1, m.MAV_FRAME_LOCAL_NED, 0b110111111000,
                                                               n, e, d, 0, 0, 0, 0, 0, 0, 0, 0))

    for _ in range(3):
        setpoint(1e30, 1e30, -5.0)
        time.sleep(0.05)
    assert set_mode(gcs, 6) == m.MAV_RESULT_ACCEPTED
    said(gcs, "Offboard target outside the geofence")
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        setpoint(1e30, 1e30, -5.0)
        time.sleep(0.05)
    n, e, _ = vehicle.pose()[:3]
    assert math.hypot(n, e) == pytest.approx(30.0, abs=0.06) and n == pytest.approx(e, abs=0.01)
    assert vehicle.mode == Mode.OFFBOARD  # held at the fence: no breach

    assert set_param(gcs, "GF_ACTION", 3.0) == 3.0  # return
    assert set_param(gcs, "GF_MAX_HOR_DIST", 10.0) == 10.0  # now the vehicle is outside
    said(gcs, "Geofence violated")
    fence = m.MAV_SYS_STATUS_GEOFENCE  # what MAVProxy's fence module reads as "fence breach"
    status = gcs.recv("SYS_STATUS", cond=lambda st: not st.onboard_control_sensors_health & fence)
    assert status.onboard_control_sensors_present & status.onboard_control_sensors_enabled & fence
    gcs.recv("HEARTBEAT", cond=lambda hb: px4_mode(hb) == (4, 5))
    wait_for(lambda: not vehicle.armed, 15.0, "geofence return")
    assert math.hypot(*vehicle.pose()[:2]) < 0.35


# --- datalink loss -------------------------------------------------------------------------

@pytest.mark.slow
def test_datalink_loss_holds_then_returns(vehicle, gcs):
    for name, value in (("COM_DL_LOSS_T", 1.0), ("COM_FAIL_ACT_T", 1.0), ("NAV_DLL_ACT", 2.0)):
        assert set_param(gcs, name, value) == value
    airborne_at(gcs, vehicle, 5.0)
    assert fly_to(gcs, 20.0, 0.0, 5.0) == m.MAV_RESULT_ACCEPTED
    time.sleep(2.0)  # heartbeats flow: no failsafe
    assert not any("Data link" in text for _, text in vehicle.statustexts)
    gcs.stop_heartbeats()
    t = time.monotonic()
    assert said(gcs, "Data link lost: holding, RTL in 1 s", 3.0).severity == m.MAV_SEVERITY_CRITICAL
    assert vehicle.mode == Mode.HOLD and time.monotonic() - t >= 0.7  # last heartbeat <= 0.25 s before t
    gcs.recv("HEARTBEAT", 3.0, cond=lambda hb: px4_mode(hb) == (4, 5))  # COM_FAIL_ACT_T later: RTL
    assert time.monotonic() - t >= 1.7
    wait_for(lambda: not vehicle.armed, 15.0, "datalink-loss return")
    assert math.hypot(*vehicle.pose()[:2]) < 0.35


@pytest.mark.slow
def test_mavsdk_heartbeats_keep_the_datalink(udp_port):
    """The UAV agent's MAVSDK link sends heartbeats: a healthy flight never trips the failsafe."""
    from uav_agent.flight import Flight

    # The link listens before the vehicle opens its socket: the vehicle's own (ephemeral) port can
    # then not be the one the link is about to bind (a CI run once failed with BIND_ERROR here).
    flight = Flight(f"udpin://127.0.0.1:{udp_port}").open()
    vehicle = Vehicle(VehicleConfig(url=f"udpout:127.0.0.1:{udp_port}", time_scale=20.0)).start()
    try:
        assert vehicle.set_param("COM_DL_LOSS_T", 2.5) == 2.5  # MAVSDK beats at 1 Hz
        flight.connect(timeout_s=10)
        flight.takeoff(5.0, timeout_s=15)
        time.sleep(4.0)
        flight.goto(10.0, 5.0, 6.0, timeout_s=15)
        assert not any("Data link" in text for _, text in vehicle.statustexts)
        assert vehicle.mode == Mode.HOLD
        flight.land(timeout_s=15)
    finally:
        flight.close()
        vehicle.stop()


# --- the links -----------------------------------------------------------------------------

def test_sockets_are_on_loopback_unless_opened_deliberately(udp_port):
    v = Vehicle(VehicleConfig(url=f"udpout:127.0.0.1:{udp_port}")).start()
    try:
        assert v.local_address[0] == "127.0.0.1"
    finally:
        v.stop()
    with pytest.raises(MissionError, match="--mavlink-bind"):
        VehicleConfig(url="udpin:0.0.0.0:14550")
    with pytest.raises(MissionError, match="not on this machine"):
        VehicleConfig(url="udpout:192.0.2.7:14550")
    VehicleConfig(url="udpin:0.0.0.0:14550", bind_host="0.0.0.0")  # said deliberately
    with pytest.raises(MissionError, match="32 bytes"):
        VehicleConfig(gcs_url="udpin:127.0.0.1:0", signing_key=b"short")


def test_signed_ground_station_link_refuses_unsigned_commands():
    v = Vehicle(VehicleConfig(url="udpin:127.0.0.1:0", gcs_url="udpin:127.0.0.1:0", signing_key=KEY,
                              time_scale=20.0)).start()
    port = v.address("gcs")[1]
    signed, unsigned, wrong = Client(port, key=KEY), Client(port, system_id=246), Client(port, 247, key=b"x" * 32)
    try:
        assert signed.recv("HEARTBEAT").get_signed()  # the vehicle signs too; only a signed sender became a peer
        assert unsigned.poll("HEARTBEAT", 1.0) is None and wrong.poll("HEARTBEAT", 0.2) is None
        unsigned.send(unsigned.mav.command_long_encode(1, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
        wrong.send(wrong.mav.command_long_encode(1, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
        wait_for(lambda: v.refused_unsigned >= 4, what="refusals counted")  # 2 heartbeats, 2 commands
        assert not v.armed
        assert signed.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
        assert v.armed and v.bad_frames == 0
        # the flight link is not signed: the UAV's MAVSDK, which cannot sign, still flies
        flight_link = Client(v.local_address[1])
        assert flight_link.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 0) == m.MAV_RESULT_ACCEPTED
        flight_link.close()
    finally:
        for c in (signed, unsigned, wrong):
            c.close()
        v.stop()


# --- the real processes ----------------------------------------------------------------------

def stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.mark.slow
@pytest.mark.process
def test_world_vehicle_flies_a_mission_uploaded_by_a_ground_station():
    gcs_port = free_port()
    gcs = Client(None, listen=gcs_port, heartbeat_hz=2.0)  # like QGroundControl on 14550
    world = subprocess.Popen([sys.executable, "-m", "sim_world", "--listen", f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}",
                              "--mavlink", f"udpin:127.0.0.1:{free_port()}", "--gcs", f"udpout:127.0.0.1:{gcs_port}",
                              "--time-scale", "10", "--camera", "ideal"], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    try:
        assert "ground station udpout:127.0.0.1" in world.stdout.readline()
        gcs.recv("HEARTBEAT", 15.0)
        ports = psutil.Process(world.pid).net_connections(kind="udp")
        assert ports and all(c.laddr.ip == "127.0.0.1" for c in ports), ports
        assert set_param(gcs, "RTL_RETURN_ALT", 10.0) == 10.0
        items = plan()
        assert upload(gcs, items) == m.MAV_MISSION_ACCEPTED
        assert [g.command for g in download(gcs)] == [i[2] for i in items]
        assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
        assert set_mode(gcs, 4, 4) == m.MAV_RESULT_ACCEPTED
        said(gcs, "Mode HOLD -> MISSION")
        reached = [gcs.recv("MISSION_ITEM_REACHED", 20.0).seq for _ in items]
        assert reached == [0, 1, 2, 3, 4]
        gcs.recv("HEARTBEAT", 5.0, cond=lambda hb: px4_mode(hb) == (4, 5))
        gcs.recv("EXTENDED_SYS_STATE", 20.0, cond=lambda s: s.landed_state == m.MAV_LANDED_STATE_LANDING)
        gcs.recv("HEARTBEAT", 20.0, cond=lambda hb: not hb.base_mode & m.MAV_MODE_FLAG_SAFETY_ARMED)
        gcs.recv("EXTENDED_SYS_STATE", cond=lambda s: s.landed_state == m.MAV_LANDED_STATE_ON_GROUND)
        home = gcs.recv("GLOBAL_POSITION_INT")
        assert abs(home.relative_alt) < 20
        assert gcs.recv("MISSION_CURRENT").mission_state == m.MISSION_STATE_COMPLETE
    finally:
        gcs.close()
        stop(world)


@pytest.mark.slow
@pytest.mark.process
def test_run_with_a_signed_ground_station_completes_while_it_watches(tmp_path):
    key_file = tmp_path / "key.hex"
    key_file.write_text(KEY.hex() + "\n")  # as `openssl rand -hex 32` writes it
    gcs_port = free_port()
    gcs = Client(None, listen=gcs_port, key=KEY)
    run = subprocess.Popen([sys.executable, "-m", "uav_robots", "run", "--camera", "ideal", "--robots", "4", "--quiet",
                            "--gcs", f"udpout:127.0.0.1:{gcs_port}", "--mavlink-key", str(key_file),
                            "--out", str(tmp_path / "out")],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    try:
        hb = gcs.recv("HEARTBEAT", 60.0)
        assert hb.type == m.MAV_TYPE_QUADROTOR and hb.autopilot == m.MAV_AUTOPILOT_PX4 and hb.get_signed()
        gcs.recv("GLOBAL_POSITION_INT", 120.0, cond=lambda p: p.relative_alt > 2_000)  # the UAV flies it
        out, _ = run.communicate(timeout=300)
        assert run.returncode == 0, out[-3000:]
    finally:
        gcs.close()
        stop(run)
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["completed"] is True


def test_the_world_widens_the_geofence_to_cover_a_large_floor():
    from protocol.transport import MemoryBus, MemoryTransport
    from sim_world.config import WorldConfig
    from sim_world.service import World

    small = World(WorldConfig(fleet="t", robots=2, mavlink="udpin:127.0.0.1:0"), MemoryTransport(MemoryBus()))
    big = World(WorldConfig(fleet="t", robots=2, mavlink="udpin:127.0.0.1:0", cell_size_m=100.0),
                MemoryTransport(MemoryBus()))
    try:
        small.start()
        big.start()
        assert small.vehicle.param("GF_MAX_HOR_DIST") == 1000.0  # the default covers it
        h, w = big.truth.free.shape
        assert big.vehicle.param("GF_MAX_HOR_DIST") > math.hypot(h, w) * 100.0
    finally:
        small.close()
        big.close()
