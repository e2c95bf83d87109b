"""The simulated vehicle where a tool can tell it from PX4 (issue 30, item 3): MAVSDK's Mission,
MissionRaw and Param plugins, QGroundControl's survey items, typed parameters, per-link message
intervals, global and acceleration setpoints, preflight checks and a kept battery failsafe,
acceleration limits, the guarded flight link, an indoor vehicle and a noisy estimate.

Real MAVLink over UDP on loopback: MAVSDK 4.x (the UAV agent's own library) or a pymavlink client.
"""
from __future__ import annotations

import json
import math
import socket
import threading
import time

import pytest
from pymavlink.dialects.v20 import common as m

from protocol.geo import ned_to_geo
from sim_world.vehicle import Mode, Vehicle, VehicleConfig
from sim_world.vehicle.config import preset
from sim_world.vehicle.params import encode_value

from mavlink_gcs import Client, param_value, px4_mode, set_mode, wait_for
from test_ground_station import gcs  # noqa: F401 - the same ground station fixture, on this module's vehicle

NAN = float("nan")
HOME = (VehicleConfig.home_lat, VehicleConfig.home_lon)
REL = m.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
POSITION_ONLY = 0b110111111000
FORCE_MAGIC = 21196


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def geo(north: float, east: float) -> tuple[float, float]:
    return ned_to_geo(north, east, *HOME)


def airborne(c: Client, vehicle: Vehicle, alt: float = 5.0) -> None:
    assert c.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
    assert c.command(m.MAV_CMD_NAV_TAKEOFF, *[NAN] * 6, VehicleConfig.home_alt_m + alt) == m.MAV_RESULT_ACCEPTED
    wait_for(lambda: vehicle.mode == Mode.HOLD and abs(vehicle.pose()[2] + alt) < 0.01, 10.0, "takeoff")


def reposition(c: Client, north: float, east: float, alt: float) -> int:
    lat, lon = geo(north, east)
    c.send(c.mav.command_int_encode(1, 1, REL, m.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, NAN,
                                    round(lat * 1e7), round(lon * 1e7), alt))
    return c.recv("COMMAND_ACK", cond=lambda a: a.command == m.MAV_CMD_DO_REPOSITION).result




# --- MAVSDK: Mission, MissionRaw, Param, Telemetry ----------------------------------------------

def qgc_survey_plan(rows: int = 6, legs: int = 4) -> str:
    """A QGroundControl .plan as its survey pattern writes it: takeoff, a speed, a camera mode and a
    gimbal pitch, then per transect a waypoint that starts distance triggering, waypoints, one that
    stops it; a return home. The complex item carries the items QGC generated (`Items`)."""
    def simple(seq, command, params, frame=3):
        return {"type": "SimpleItem", "autoContinue": True, "command": command, "doJumpId": seq + 1,
                "frame": frame, "params": params}

    items = [simple(0, m.MAV_CMD_NAV_TAKEOFF, [0, 0, 0, None, *HOME, 15]),
             simple(1, m.MAV_CMD_DO_CHANGE_SPEED, [1, 8, -1, 0, 0, 0, 0], frame=2),
             simple(2, m.MAV_CMD_SET_CAMERA_MODE, [0, 0, NAN, NAN, NAN, NAN, NAN], frame=2),
             simple(3, m.MAV_CMD_DO_MOUNT_CONTROL, [-90, 0, 0, 0, 0, 0, m.MAV_MOUNT_MODE_MAVLINK_TARGETING], frame=2)]
    survey, seq = [], 4
    for row in range(rows):
        for leg in range(legs):
            lat, lon = geo(-4.0 * row, 6.0 * (leg if row % 2 == 0 else legs - 1 - leg))
            survey.append(simple(seq, m.MAV_CMD_NAV_WAYPOINT, [0, 0, 0, None, lat, lon, 15]))
            seq += 1
            if leg in (0, legs - 1):   # a transect's ends: trigger every 3 m from here / stop
                survey.append(simple(seq, m.MAV_CMD_DO_SET_CAM_TRIGG_DIST, [3 if leg == 0 else 0, 0, 1, 0, 0, 0, 0],
                                     frame=2))
                seq += 1
    complex_item = {"type": "ComplexItem", "complexItemType": "survey", "version": 5, "angle": 0,
                    "polygon": [list(geo(0, 0)), list(geo(0, 20)), list(geo(-20, 20)), list(geo(-20, 0))],
                    "TransectStyleComplexItem": {"version": 2, "Items": survey, "CameraTriggerInTurnAround": True,
                                                 "HoverAndCapture": False, "Refly90Degrees": False,
                                                 "TurnAroundDistance": 1, "VisualTransectPoints": [],
                                                 "CameraCalc": {"CameraName": "Manual (no camera specs)",
                                                                "DistanceToSurface": 15, "version": 1}}}
    plan = {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
            "geoFence": {"circles": [], "polygons": [], "version": 2}, "rallyPoints": {"points": [], "version": 2},
            "mission": {"cruiseSpeed": 15, "firmwareType": m.MAV_AUTOPILOT_PX4, "hoverSpeed": 5, "vehicleType": 2,
                        "version": 2, "plannedHomePosition": [*HOME, VehicleConfig.home_alt_m],
                        "items": [*items, complex_item, simple(seq, m.MAV_CMD_NAV_RETURN_TO_LAUNCH, [0] * 7, frame=2)]}}
    return json.dumps(plan).replace("NaN", "null")


@pytest.mark.slow
def test_mavsdk_missions_parameters_and_telemetry_on_the_vehicle():
    """MAVSDK's Mission plugin uploads, downloads and flies a mission with speed, camera and gimbal
    items; MissionRaw imports a QGroundControl survey plan and uploads it, and an item the vehicle
    cannot fly is refused by name; Param writes an INT32 as an INT32; Telemetry gets ALTITUDE and
    ATTITUDE_QUATERNION."""
    from mavsdk import ComponentType, Configuration, Mavsdk
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.mission import Mission, MissionItem, MissionPlan
    from mavsdk.plugins.mission_raw import MissionItem as RawItem, MissionRaw, MissionRawError
    from mavsdk.plugins.param import Param
    from mavsdk.plugins.telemetry import Telemetry

    port = free_udp_port()
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    mavsdk = Mavsdk(config)
    assert mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}").name == "SUCCESS"   # listening first
    vehicle = Vehicle(VehicleConfig(url=f"udpout:127.0.0.1:{port}", time_scale=20.0)).start()
    try:
        system = mavsdk.first_autopilot(10.0)
        assert system is not None
        mission, raw, param = Mission(system), MissionRaw(system), Param(system)
        action, telemetry = Action(system), Telemetry(system)

        # Param: INT32 stays INT32 (the set_param_int set GF_ACTION to 0)
        param.set_param_int("GF_ACTION", 3)
        assert vehicle.param("GF_ACTION") == 3 and param.get_param_int("GF_ACTION") == 3
        param.set_param_float("MPC_XY_VEL_MAX", 15.0)
        assert vehicle.param("MPC_XY_VEL_MAX") == 15.0

        # MissionRaw: a QGroundControl survey plan (waypoints and camera triggers) uploads whole
        imported = raw.import_qgroundcontrol_mission_from_string(qgc_survey_plan())
        survey = imported.mission_items
        assert len(survey) > 30 and {m.MAV_CMD_DO_SET_CAM_TRIGG_DIST, m.MAV_CMD_SET_CAMERA_MODE,
                                     m.MAV_CMD_DO_MOUNT_CONTROL} <= {i.command for i in survey}
        raw.upload_mission(survey)
        assert [(i.command, i.x, i.y) for i in raw.download_mission()] == [(i.command, i.x, i.y) for i in survey]
        # ... and an item it cannot fly is refused, by name, keeping the stored plan
        roi = RawItem(0, REL, m.MAV_CMD_DO_SET_ROI_LOCATION, 1, 1, 0, 0, 0, 0, *(round(v * 1e7) for v in HOME), 5.0, 0)
        with pytest.raises(MissionRawError) as refused:
            raw.upload_mission([roi])
        assert refused.value.result.name == "UNSUPPORTED"
        assert any("DO_SET_ROI_LOCATION" in text and "UNSUPPORTED" in text for _, text in vehicle.statustexts)
        assert len(raw.download_mission()) == len(survey)

        # Mission: upload, download, start, progress to the end
        def wp(north, east, **kw):
            lat, lon = geo(north, east)
            return MissionItem(lat, lon, 6.0, **kw)

        ca = MissionItem.CameraAction
        plan = MissionPlan([wp(0, 0, vehicle_action=MissionItem.VehicleAction.TAKEOFF),
                            wp(12, 0, speed_m_s=6.0, gimbal_pitch_deg=-90.0, gimbal_yaw_deg=0.0,
                                camera_action=ca.TAKE_PHOTO, is_fly_through=False),
                            wp(12, 12, camera_action=ca.START_PHOTO_DISTANCE, camera_photo_distance_m=4.0,
                                is_fly_through=True, loiter_time_s=1.0),
                            wp(0, 12, camera_action=ca.STOP_PHOTO_DISTANCE, yaw_deg=90.0, is_fly_through=False)])
        mission.set_return_to_launch_after_mission(True)
        mission.upload_mission(plan)
        got = mission.download_mission().mission_items
        assert [(round(i.latitude_deg, 6), round(i.longitude_deg, 6), i.camera_action) for i in got] == [
            (round(i.latitude_deg, 6), round(i.longitude_deg, 6), i.camera_action) for i in plan.mission_items]
        action.arm()
        mission.start_mission()
        deadline = time.monotonic() + 40
        while not mission.is_mission_finished() and time.monotonic() < deadline:
            time.sleep(0.05)
        progress = mission.mission_progress()
        assert mission.is_mission_finished() and progress.current == progress.total == 4, progress
        wait_for(lambda: not vehicle.armed, 20.0, "the return home after the mission")
        assert math.hypot(*vehicle.pose()[:2]) < 0.35 and vehicle.pose()[2] == 0.0
        triggers = vehicle.camera_triggers
        assert len(triggers) >= 1 + 12 // 4, triggers   # the photo, then one every 4 m along the second leg
        assert triggers[0].pos[:2] == pytest.approx((12.0, 0.0), abs=0.6)
        assert vehicle.gimbal_deg == (-90.0, 0.0)
        texts = [t for _, t in vehicle.events]
        assert "camera: trigger every 4 m" in texts and "camera: distance triggering off" in texts

        # Telemetry: the streams PX4 sends and MAVSDK reads (ALTITUDE comes at 5 Hz: one more after landing)
        time.sleep(0.5)
        altitude, q = telemetry.altitude(), telemetry.attitude_quaternion()
        assert altitude.altitude_amsl_m == pytest.approx(VehicleConfig.home_alt_m, abs=0.05)
        assert math.isfinite(altitude.altitude_relative_m) and abs(math.hypot(q.w, q.x, q.y, q.z) - 1) < 1e-3
        assert vehicle.bad_frames == 0 and vehicle.refused_strangers == 0
    finally:
        vehicle.stop()
        mavsdk.destroy()
        config.destroy()


# --- parameters -------------------------------------------------------------------------------

def test_parameters_carry_their_own_type(vehicle, gcs):
    def request(name):
        gcs.send(gcs.mav.param_request_read_encode(1, 1, name.encode(), -1))
        return gcs.recv("PARAM_VALUE", cond=lambda p: p.param_id == name)

    first = request("GF_ACTION")
    assert first.param_type == m.MAV_PARAM_TYPE_INT32 and param_value(first) == 2   # bytewise, as PX4 sends it
    assert request("MIS_TAKEOFF_ALT").param_type == m.MAV_PARAM_TYPE_REAL32
    gcs.send(gcs.mav.param_set_encode(1, 1, b"GF_ACTION", encode_value(5, m.MAV_PARAM_TYPE_INT32),
                                      m.MAV_PARAM_TYPE_INT32))
    echo = gcs.recv("PARAM_VALUE", cond=lambda p: p.param_id == "GF_ACTION")
    assert echo.param_type == m.MAV_PARAM_TYPE_INT32 and param_value(echo) == 5 and vehicle.param("GF_ACTION") == 5
    # a float that is no integer, and an INT32 for a float parameter: refused, said, the value kept
    gcs.send(gcs.mav.param_set_encode(1, 1, b"GF_ACTION", 2.5, m.MAV_PARAM_TYPE_REAL32))
    assert param_value(gcs.recv("PARAM_VALUE", cond=lambda p: p.param_id == "GF_ACTION")) == 5
    gcs.said("Param GF_ACTION: INT32, not REAL32: refused")
    gcs.send(gcs.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", encode_value(7, m.MAV_PARAM_TYPE_INT32),
                                      m.MAV_PARAM_TYPE_INT32))
    assert gcs.recv("PARAM_VALUE", cond=lambda p: p.param_id == "MIS_TAKEOFF_ALT").param_value == 2.5
    gcs.said("Param MIS_TAKEOFF_ALT: REAL32, not INT32: refused")
    # a script's whole REAL32 for an INT32 parameter is that integer
    gcs.send(gcs.mav.param_set_encode(1, 1, b"NAV_DLL_ACT", 3.0, m.MAV_PARAM_TYPE_REAL32))
    assert param_value(gcs.recv("PARAM_VALUE", cond=lambda p: p.param_id == "NAV_DLL_ACT")) == 3


# --- telemetry: the streams, per link ---------------------------------------------------------------

def test_message_intervals_are_per_link_and_the_estimator_streams_are_there():
    vehicle = Vehicle(VehicleConfig(url="udpin:127.0.0.1:0", gcs_url="udpin:127.0.0.1:0", time_scale=20.0)).start()
    uav, station = Client(vehicle.local_address[1]), Client(vehicle.address("gcs")[1])
    try:
        for c in (uav, station):
            c.recv("HEARTBEAT")
        att = uav.recv("ATTITUDE")
        q = uav.recv("ATTITUDE_QUATERNION")
        assert abs(math.hypot(q.q1, q.q2, q.q3, q.q4) - 1) < 1e-6 and att.roll == 0.0
        alt = uav.recv("ALTITUDE")
        assert alt.altitude_amsl == pytest.approx(VehicleConfig.home_alt_m) and alt.altitude_relative == 0.0
        status = uav.recv("ESTIMATOR_STATUS")
        assert status.flags & m.ESTIMATOR_POS_HORIZ_ABS and status.pos_horiz_accuracy > 0
        # the ground station silences ATTITUDE on its own link (the issue's -1 silenced every link)
        assert station.command(m.MAV_CMD_SET_MESSAGE_INTERVAL, m.MAVLINK_MSG_ID_ATTITUDE, -1) == m.MAV_RESULT_ACCEPTED
        assert uav.command(m.MAV_CMD_SET_MESSAGE_INTERVAL, m.MAVLINK_MSG_ID_ALTITUDE, 50_000) == m.MAV_RESULT_ACCEPTED
        for c, attitude_us, altitude_us in ((station, -1, 200_000), (uav, 40_000, 50_000)):
            for mid, expected in ((m.MAVLINK_MSG_ID_ATTITUDE, attitude_us), (m.MAVLINK_MSG_ID_ALTITUDE, altitude_us)):
                assert c.command(m.MAV_CMD_GET_MESSAGE_INTERVAL, mid) == m.MAV_RESULT_ACCEPTED
                assert c.recv("MESSAGE_INTERVAL", cond=lambda i, mid=mid: i.message_id == mid).interval_us == expected
        assert station.command(m.MAV_CMD_GET_MESSAGE_INTERVAL, 12345) == m.MAV_RESULT_ACCEPTED
        assert station.recv("MESSAGE_INTERVAL", cond=lambda i: i.message_id == 12345).interval_us == 0  # no such
        time.sleep(0.2)
        station.pending.clear()
        uav.pending.clear()
        assert station.poll("ATTITUDE", 0.6) is None
        assert station.recv("LOCAL_POSITION_NED")   # its other streams flow
        seen = [uav.recv("ATTITUDE") for _ in range(5)]   # the UAV's link still has its attitude
        assert len(seen) == 5
    finally:
        uav.close()
        station.close()
        vehicle.stop()


# --- offboard setpoints --------------------------------------------------------------------------

def _stream(c: Client, make, stop: threading.Event) -> threading.Thread:
    def run():
        while not stop.is_set():
            c.send(make())
            stop.wait(0.05)
    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_global_and_acceleration_setpoints_fly_and_what_cannot_be_flown_is_refused_aloud(vehicle, gcs):
    airborne(gcs, vehicle, 5.0)
    lat, lon = geo(15.0, -10.0)
    stop = threading.Event()
    sender = _stream(gcs, lambda: gcs.mav.set_position_target_global_int_encode(
        0, 1, 1, REL, POSITION_ONLY, round(lat * 1e7), round(lon * 1e7), 9.0, 0, 0, 0, 0, 0, 0, 0, 0), stop)
    try:
        time.sleep(0.2)
        assert set_mode(gcs, 6) == m.MAV_RESULT_ACCEPTED
        wait_for(lambda: math.dist(vehicle.pose()[:3], (15.0, -10.0, -9.0)) < 0.02, 10.0, "the global setpoint")
    finally:
        stop.set()
        sender.join()
    # acceleration only (velocity and position ignored), east at 2 m/s^2 for a while
    accel_only = 0b110000111111
    stop = threading.Event()
    sender = _stream(gcs, lambda: gcs.mav.set_position_target_local_ned_encode(
        0, 1, 1, m.MAV_FRAME_LOCAL_NED, accel_only, 0, 0, 0, 0, 0, 0, 0.0, 2.0, 0.0, 0, 0), stop)
    try:
        t0, east0 = vehicle.sim_time_s, vehicle.pose()[1]
        wait_for(lambda: vehicle.state().vel[1] > 4.0, 5.0, "accelerating east")
        assert vehicle.sim_time_s - t0 >= 4.0 / 2.0 - 0.3 and vehicle.pose()[1] > east0
        assert abs(vehicle.state().vel[0]) < 0.1 and vehicle.mode == Mode.OFFBOARD
    finally:
        stop.set()
        sender.join()
    # what cannot be flown: said once per reason, counted, never silently dropped
    force = m.POSITION_TARGET_TYPEMASK_FORCE_SET | accel_only
    for _ in range(3):
        gcs.send(gcs.mav.set_position_target_local_ned_encode(0, 1, 1, m.MAV_FRAME_LOCAL_NED, force, 0, 0, 0, 0, 0, 0,
                                                               1.0, 0, 0, 0, 0))
        gcs.send(gcs.mav.set_position_target_local_ned_encode(0, 1, 1, m.MAV_FRAME_LOCAL_FLU, POSITION_ONLY, 1, 2, -3,
                                                               0, 0, 0, 0, 0, 0, 0, 0))
    gcs.said("Offboard refused: force setpoint")
    gcs.said("Offboard refused: frame LOCAL_FLU")
    wait_for(lambda: vehicle.refused_setpoints == 6, what="refusals counted")
    assert sum("Offboard refused" in t for _, t in vehicle.statustexts) == 2
    wait_for(lambda: vehicle.mode == Mode.HOLD, 3.0, "hold once the flyable setpoints stop")


# --- safety like PX4 ----------------------------------------------------------------------------

def test_preflight_checks_and_a_kept_battery_failsafe(vehicle, gcs):
    # a pack that empties on the ground: no arming at a low battery, no takeoff at a critical one
    vehicle.set_param("BAT1_CAPACITY", 1.0)
    wait_for(lambda: vehicle.battery_remaining < 0.15, 5.0, "a low battery")
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_DENIED
    assert "BAT_LOW_THR" in gcs.said("Arming denied: low battery").text
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1, FORCE_MAGIC) == m.MAV_RESULT_ACCEPTED  # forced: as PX4
    wait_for(lambda: vehicle.battery_remaining <= 0.07, 5.0, "a critical battery")
    assert gcs.command(m.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == m.MAV_RESULT_DENIED
    gcs.said("Takeoff denied: battery")
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 0) == m.MAV_RESULT_ACCEPTED
    # a fresh pack; armed and left on the ground, it disarms by itself (COM_DISARM_PRFLT)
    vehicle.set_param("BAT1_CAPACITY", 1e6)
    vehicle.set_param("COM_DISARM_PRFLT", 0.5)
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
    wait_for(lambda: not vehicle.armed, 3.0, "the preflight disarm")
    assert "disarmed: no takeoff within 0.5 s of arming" in [t for _, t in vehicle.events]
    vehicle.set_param("COM_DISARM_PRFLT", 10.0)

    # in the air, the battery goes critical: the return it flies is kept
    airborne(gcs, vehicle, 5.0)
    assert reposition(gcs, 25.0, 0.0, 5.0) == m.MAV_RESULT_ACCEPTED
    wait_for(lambda: vehicle.pose()[0] > 20.0, 5.0, "flying north")
    vehicle.set_param("SIM_BAT_HOVER_A", 0.0)   # it drains no further in the air: no emergency during the checks
    used = 1.0 - vehicle.battery_remaining
    vehicle.set_param("BAT1_CAPACITY", 1e6 * used / 0.94)   # 6 % left: critical (BAT_CRIT_THR 7 %)
    wait_for(lambda: vehicle.mode == Mode.RTL, 3.0, "the battery failsafe's return")
    assert vehicle.failsafe_kept == (Mode.RTL, "critical battery")
    assert reposition(gcs, 0.0, 30.0, 5.0) == m.MAV_RESULT_DENIED   # the agent's goto, as in the issue
    assert "failsafe RTL (critical battery" in gcs.said("Reposition denied").text   # (the first of two chunks)
    assert set_mode(gcs, 4, 3) == m.MAV_RESULT_DENIED                # HOLD
    assert set_mode(gcs, 6) == m.MAV_RESULT_DENIED                   # OFFBOARD
    assert gcs.command(m.MAV_CMD_MISSION_START) == m.MAV_RESULT_DENIED
    assert vehicle.mode == Mode.RTL
    assert gcs.command(m.MAV_CMD_NAV_LAND) == m.MAV_RESULT_ACCEPTED   # landing is always taken...
    assert gcs.command(m.MAV_CMD_NAV_RETURN_TO_LAUNCH) == m.MAV_RESULT_DENIED   # ...and kept: not turned back
    assert vehicle.mode == Mode.LAND and vehicle.failsafe_kept == (Mode.LAND, "critical battery")
    wait_for(lambda: not vehicle.armed, 15.0, "landed and disarmed")
    assert vehicle.failsafe_kept is None and "disarmed after landing" in [t for _, t in vehicle.events]


def test_speed_changes_ramp_within_the_acceleration_limit(vehicle, gcs):
    airborne(gcs, vehicle, 5.0)
    samples = []
    assert reposition(gcs, 80.0, 0.0, 5.0) == m.MAV_RESULT_ACCEPTED
    deadline = time.monotonic() + 10
    while vehicle.pose()[0] < 79.98 and time.monotonic() < deadline:
        samples.append((vehicle.sim_time_s, vehicle.state().vel[0]))
        time.sleep(0.01)
    furthest = max(vehicle.pose()[0] for _ in range(20) if time.sleep(0.01) is None)
    accel = vehicle.param("MPC_ACC_HOR")
    rates = [(v1 - v0) / (t1 - t0) for (t0, v0), (t1, v1) in zip(samples, samples[1:]) if t1 - t0 > 0.05]
    assert max(abs(r) for r in rates) <= accel + 1e-6        # 0 to 12 m/s took seconds, not a step
    assert max(v for _, v in samples) == pytest.approx(12.0, abs=0.3)   # the cruise speed
    assert samples[-1][0] - samples[0][0] > 80.0 / 12.0 + 12.0 / accel * 0.9
    stopped = vehicle.pose()[0]
    assert stopped == pytest.approx(80.0, abs=0.02) and furthest <= stopped + 1e-9   # on the target, never past it


# --- the guarded flight link ----------------------------------------------------------------------

def test_the_flight_link_answers_its_companion_only(vehicle, gcs):
    airborne(gcs, vehicle, 5.0)
    companion = vehicle.companion
    assert companion[0] == gcs.mav.srcSystem
    # a stranger's valid, unsigned force-disarm (the issue crashed the drone from 12.5 m with one),
    # from another system, and from another process using the companion's own system id
    for system in (66, gcs.mav.srcSystem):
        stranger = Client(vehicle.local_address[1], system_id=system)
        try:
            stranger.send(stranger.mav.command_long_encode(1, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, FORCE_MAGIC,
                                                           0, 0, 0, 0, 0))
            assert stranger.poll("COMMAND_ACK", 0.5) is None and stranger.poll("HEARTBEAT", 0.1) is None
        finally:
            stranger.close()
    assert vehicle.armed and vehicle.in_air and vehicle.refused_strangers >= 4   # two heartbeats, two commands
    gcs.said("Flight link: refused system 66")
    assert gcs.said(f"Flight link: refused system {gcs.mav.srcSystem}").severity == m.MAV_SEVERITY_CRITICAL
    # the companion still flies it, and its own absurd frames break nothing
    for value in (NAN, math.inf, -1e30):
        gcs.send(gcs.mav.set_position_target_local_ned_encode(0, 1, 1, m.MAV_FRAME_LOCAL_NED, 0, value, value, value,
                                                               value, value, value, value, value, value, value, value))
        gcs.send(gcs.mav.command_long_encode(1, 1, m.MAV_CMD_DO_REPOSITION, 0, value, 0, 0, value, value, value,
                                             value))
    assert reposition(gcs, 5.0, 5.0, 6.0) == m.MAV_RESULT_ACCEPTED
    wait_for(lambda: math.dist(vehicle.pose()[:3], (5.0, 5.0, -6.0)) < 0.01, 5.0, "the companion's goto")
    assert all(math.isfinite(v) for v in vehicle.pose()) and vehicle.companion == companion


def test_a_udpout_flight_link_answers_only_the_address_it_sends_to(udp_port):
    companion = Client(None, listen=udp_port)
    vehicle = Vehicle(VehicleConfig(url=f"udpout:127.0.0.1:{udp_port}", time_scale=20.0)).start()
    stranger = None
    try:
        companion.recv("HEARTBEAT")  # the vehicle calls; the stranger speaks first, from another port
        stranger = Client(vehicle.local_address[1], system_id=66)
        stranger.send(stranger.mav.command_long_encode(1, 1, m.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0))
        assert stranger.poll("COMMAND_ACK", 0.5) is None and vehicle.companion is None and not vehicle.armed
        assert companion.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
        assert vehicle.companion == (companion.mav.srcSystem, ("127.0.0.1", udp_port))
    finally:
        if stranger is not None:
            stranger.close()
        companion.close()
        vehicle.stop()


def test_a_configured_companion_system_is_the_only_one_answered():
    vehicle = Vehicle(VehicleConfig(url="udpin:127.0.0.1:0", companion_system_id=42, time_scale=20.0)).start()
    other, mine = Client(vehicle.local_address[1], system_id=245), None
    try:
        assert other.poll("HEARTBEAT", 0.5) is None and vehicle.companion is None
        mine = Client(vehicle.local_address[1], system_id=42)
        assert mine.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
        assert vehicle.companion[0] == 42 and vehicle.refused_strangers >= 1
    finally:
        other.close()
        if mine is not None:
            mine.close()
        vehicle.stop()


# --- an indoor vehicle, and telemetry as an estimate -------------------------------------------------

@pytest.mark.slow
def test_an_indoor_vehicle_has_a_local_frame_only():
    vehicle = Vehicle(preset("indoor", url="udpin:127.0.0.1:0", time_scale=20.0)).start()
    c = Client(vehicle.local_address[1], heartbeat_hz=4.0)
    try:
        c.recv("HEARTBEAT")
        assert c.recv("LOCAL_POSITION_NED") and c.poll(("GLOBAL_POSITION_INT", "GPS_RAW_INT", "HOME_POSITION"), 1.0) is None
        assert not c.recv("SYS_STATUS").onboard_control_sensors_present & m.MAV_SYS_STATUS_SENSOR_GPS
        assert not c.recv("ESTIMATOR_STATUS").flags & m.ESTIMATOR_POS_HORIZ_ABS
        assert c.command(m.MAV_CMD_REQUEST_MESSAGE, m.MAVLINK_MSG_ID_HOME_POSITION) == m.MAV_RESULT_UNSUPPORTED
        airborne(c, vehicle, 4.0)
        assert reposition(c, 5.0, 5.0, 4.0) == m.MAV_RESULT_DENIED
        c.said("Reposition denied: no global position (no GPS)")
        assert c.command(m.MAV_CMD_NAV_RETURN_TO_LAUNCH) == m.MAV_RESULT_DENIED
        stop = threading.Event()
        sender = _stream(c, lambda: c.mav.set_position_target_local_ned_encode(
            0, 1, 1, m.MAV_FRAME_LOCAL_NED, POSITION_ONLY, -3.0, 4.0, -5.0, 0, 0, 0, 0, 0, 0, 0, 0), stop)
        try:
            time.sleep(0.2)
            assert set_mode(c, 6) == m.MAV_RESULT_ACCEPTED   # offboard in the local frame flies
            c.recv("LOCAL_POSITION_NED", 5.0, cond=lambda p: math.dist((p.x, p.y, p.z), (-3.0, 4.0, -5.0)) < 0.02)
        finally:
            stop.set()
            sender.join()
    finally:
        c.close()
        vehicle.stop()


@pytest.mark.slow
def test_telemetry_is_an_estimate_when_asked():
    vehicle = Vehicle(VehicleConfig(url="udpin:127.0.0.1:0", time_scale=20.0, seed=4, position_bias_m=1.5,
                                    position_noise_m=0.1, attitude_noise_deg=0.5)).start()
    c = Client(vehicle.local_address[1], heartbeat_hz=4.0)
    try:
        airborne(c, vehicle, 6.0)
        assert reposition(c, 10.0, 0.0, 6.0) == m.MAV_RESULT_ACCEPTED
        time.sleep(1.0)
        c.poll("-", 0.1)   # what the socket holds from the flight there
        reported = [c.recv("LOCAL_POSITION_NED") for _ in range(20)]
        mean = [sum(getattr(p, k) for p in reported) / len(reported) for k in "xyz"]
        true = vehicle.pose()[:3]
        # the autopilot holds where it believes it is: the report is on the target, the airframe is off by the bias
        assert mean == pytest.approx([10.0, 0.0, -6.0], abs=0.15)
        assert math.dist(true[:2], (10.0, 0.0)) > 0.3
        assert len({round(p.x, 4) for p in reported}) > 10 and abs(true[2] + 6.0) < 0.01   # noise; no vertical bias
        rolls = [c.recv("ATTITUDE").roll for _ in range(10)]
        assert max(map(abs, rolls)) > 0.0005 and max(map(abs, rolls)) < math.radians(8)   # noise, and the drift held
    finally:
        c.close()
        vehicle.stop()


# --- QGroundControl's items over pymavlink, and the refusals ------------------------------------------

def test_survey_items_fly_and_unknown_items_are_refused_by_name(vehicle, gcs):
    from test_ground_station import item, upload

    cam = [(1, 2, m.MAV_CMD_DO_SET_CAM_TRIGG_DIST, 0, 1, 5.0, 0, 1, 0, 0, 0, NAN),
           (3, 2, m.MAV_CMD_DO_SET_CAM_TRIGG_DIST, 0, 1, 0.0, 0, 0, 0, 0, 0, NAN),
           (4, 2, m.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, 0, 1, -45.0, 10.0, NAN, NAN, 0, 0, 0.0),
           (5, 2, m.MAV_CMD_IMAGE_START_CAPTURE, 0, 1, 0, 0, 1, 0, 0, 0, NAN),
           (6, 2, m.MAV_CMD_DO_DIGICAM_CONTROL, 0, 1, 0, 0, 0, 0, 1, 0, 0.0)]
    items = [item(0, m.MAV_CMD_NAV_TAKEOFF, alt=5.0), cam[0], item(2, m.MAV_CMD_NAV_WAYPOINT, 23.0, 0.0, 5.0),
             *cam[1:], item(7, m.MAV_CMD_NAV_LAND, 23.0, 0.0, 0.0)]
    assert upload(gcs, items) == m.MAV_MISSION_ACCEPTED
    assert gcs.command(m.MAV_CMD_COMPONENT_ARM_DISARM, 1) == m.MAV_RESULT_ACCEPTED
    assert set_mode(gcs, 4, 4) == m.MAV_RESULT_ACCEPTED
    wait_for(lambda: not vehicle.armed, 20.0, "the mission flown and landed")
    triggers = vehicle.camera_triggers
    # once at the start of the transect, every 5 m along it, then IMAGE_START_CAPTURE and DIGICAM_CONTROL
    assert len(triggers) == 1 + 4 + 2, triggers
    assert [t.seq for t in triggers] == list(range(7)) and triggers[1].pos[0] == pytest.approx(5.0, abs=0.6)
    assert vehicle.gimbal_deg == (-45.0, 10.0)
    assert [gcs.recv("CAMERA_TRIGGER", 2.0).seq for _ in range(7)] == list(range(7))   # as PX4 announces them
    # anything else is refused by name, with the result MAVLink defines for it
    spline = (1, REL, m.MAV_CMD_NAV_SPLINE_WAYPOINT, 0, 1, 0, 0, 0, 0, 473977420, 85455940, 5.0)
    assert upload(gcs, [items[0], spline]) == m.MAV_MISSION_UNSUPPORTED
    gcs.said("Mission rejected: item 1 NAV_SPLINE_WAYPOINT (82)")
    terrain = item(0, m.MAV_CMD_NAV_WAYPOINT, 5, 5, 5, frame=m.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT)
    assert upload(gcs, [terrain]) == m.MAV_MISSION_UNSUPPORTED_FRAME
    gcs.said("frame GLOBAL_TERRAIN_ALT_INT: MAV_MISSION_UNSUPPORTED_FRAME")
    delay_until = (0, 2, m.MAV_CMD_NAV_DELAY, 0, 1, -1.0, 12, 0, 0, 0, 0, 0.0)
    assert upload(gcs, [delay_until]) == m.MAV_MISSION_INVALID_PARAM1
