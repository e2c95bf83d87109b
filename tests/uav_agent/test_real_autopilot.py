"""Drone-in-the-loop against a real flight stack: ArduCopter SITL, when `UAV_ROBOTS_ARDUPILOT_SITL` names
its binary (tests/ardupilot_sitl.py says how to give one; skipped, saying why, otherwise).

The same checks that tests/uav_agent/test_flight.py, test_autopilot_pose.py and test_failsafes.py make against our
vehicle in CI: MAVSDK flies it (streams asked for, an arm refused while its estimator settles, GUIDED,
arming again after a landing), a whole `uav-robots run --autopilot --autopilot-pose` completes with the
images rendered from its telemetry, and its own failsafes (a critical battery, a ground station's
return home) win and are named. Real time, as ArduPilot runs: minutes, not seconds.
"""
from __future__ import annotations

import json
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from ardupilot_sitl import ArduCopter, binary
from conftest import _free_port
from uav_agent.flight import Flight

pytestmark = [pytest.mark.timeout(900), pytest.mark.slow]

# ArduPilot arms about 38 s after it starts (its estimator and GPS settling), and flies at its own pace.
ARM_S = 120.0


@pytest.fixture
def ports():
    binary()   # skip at once, before ports and folders, when no SITL is named
    return tuple(_free_port(socket.SOCK_DGRAM) for _ in range(3))


def test_mavsdk_flies_arducopter_and_arms_it_again_after_a_landing(tmp_path, ports):
    uav, pose, gcs = ports
    flight = Flight(f"udpin://127.0.0.1:{uav}").open()
    try:
        with ArduCopter(tmp_path / "sitl", uav, pose, gcs) as sitl:
            flight.connect(timeout_s=60)   # ArduPilot streams nothing until asked: connect asks
            assert flight.autopilot == "ARDUPILOT"
            waited: list[str] = []
            flight.arm(timeout_s=ARM_S, on_wait=waited.append)
            assert flight.armed
            flight.takeoff(5.0, timeout_s=60)
            reached = flight.goto(10.0, 5.0, 8.0, yaw_rad=None, timeout_s=60)
            assert reached == pytest.approx((10.0, 5.0, -8.0), abs=0.6)
            assert flight.flight_mode == "OFFBOARD"   # MAVSDK's name for Copter's GUIDED
            flight.land(timeout_s=90)
            assert flight.landed
            # Copter stays in LAND after landing: arming again must not fail on that (or on BRAKE)
            flight.takeoff(4.0, timeout_s=ARM_S)
            assert flight.in_air
            flight.land(timeout_s=90)
            assert flight.landed and sitl.alive(), sitl.said()[-2000:]
    finally:
        flight.close()


def _run(tmp_path: Path, uav: int, pose: int, *args: str, timeout_s: float = 600) -> subprocess.Popen:
    """`uav-robots run` flying the SITL; its progress lines (in logs/uav.log) are the failsafe tests' triggers."""
    return subprocess.Popen([sys.executable, "-m", "uav_robots", "run", "--autopilot", f"udpin://127.0.0.1:{uav}",
                             "--autopilot-pose", f"udpin:127.0.0.1:{pose}", "--robots", "3", "--camera", "ideal",
                             "--out", str(tmp_path / "out"), "--timeout", str(timeout_s), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)


def _finish(proc: subprocess.Popen, timeout_s: float = 700) -> tuple[int, str]:
    try:
        out, _ = proc.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate(timeout=30)
    return proc.returncode, out


def test_a_whole_mission_flies_arducopter_with_the_images_from_its_telemetry(tmp_path, ports):
    uav, pose, gcs = ports
    with ArduCopter(tmp_path / "sitl", uav, pose, gcs) as sitl:
        code, said = _finish(_run(tmp_path, uav, pose))
        assert code == 0, said[-3000:] + sitl.said()[-1000:]
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["completed"] is True and report["collisions"] == 0
    perceived = report["perceived"]   # from images rendered where ArduPilot's telemetry put the camera
    assert perceived["map_matches_truth"] and perceived["robots"] == report["truth"]["robots"], perceived
    truth = report["truth"]["vehicle"]
    assert truth["source"] == "telemetry" and truth["max_altitude_m"] > 5.0
    assert not truth["armed"] and truth["landed_state"] == "ON_GROUND"
    assert report["uav"]["autopilot"] == "ARDUPILOT", report["uav"]


def _when(log: Path, pattern: str, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if log.exists() and re.search(pattern, log.read_text()):
            return
        time.sleep(0.1)
    pytest.fail(f"the UAV's log never said {pattern!r} within {timeout_s:g} s")


def _modes_until_landed(gcs, proc: subprocess.Popen, timeout_s: float) -> list[str]:
    """ArduCopter's modes, from its heartbeats on the ground station's link, until the mission's process
    ends and the vehicle is disarmed: a command of the UAV's over a failsafe would show as a mode."""
    modes: list[str] = []
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        m = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if m is None or (m.get_srcSystem(), m.get_srcComponent()) != (1, 1):
            continue
        mode = mavutil.mode_string_v10(m)
        if not modes or modes[-1] != mode:
            modes.append(mode)
        if proc.poll() is not None and not m.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
            break
    return modes


def _failsafe_mission(tmp_path: Path, ports, params: dict[str, float], trigger) -> tuple[int, dict, float, list, str]:
    """A mission with a ground station on SERIAL2; `trigger(gcs)` once the survey takes its first image.
    (exit code, report, seconds from the trigger to the UAV's abort, the modes from the trigger until
    the vehicle is disarmed, what the run and ArduPilot's SITL printed)."""
    uav, pose, gcs_port = ports
    with ArduCopter(tmp_path / "sitl", uav, pose, gcs_port, params=params) as sitl:
        proc = _run(tmp_path, uav, pose)
        gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255)
        try:
            # a listening pymavlink link answers only once it heard the autopilot (its address)
            assert gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=30) is not None, sitl.said()[-2000:]
            _when(tmp_path / "out" / "logs" / "uav.log", r"survey: image 1/", 300)
            triggered = trigger(gcs) or time.time()
            modes = _modes_until_landed(gcs, proc, 300)
            code, said = _finish(proc, 60)
        finally:
            gcs.close()
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
        report = json.loads((tmp_path / "out" / "report.json").read_text())
        abort = next(e for e in report["events"] if e["kind"] == "abort")
        return code, report, abort["unix"] - triggered, modes, said + sitl.said()


def test_arducopters_critical_battery_failsafe_wins_and_is_named(tmp_path, ports):
    # An analog monitor on the simulated pack; critical under 10.5 V for 1 s -> RTL (Copter's own failsafe)
    params = {"BATT_MONITOR": 4, "BATT_LOW_VOLT": 11.0, "BATT_CRT_VOLT": 10.5, "BATT_FS_CRT_ACT": 2, "BATT_LOW_TIMER": 1}

    def sag(gcs):
        gcs.mav.param_set_send(1, 1, b"SIM_BATT_VOLTAGE", 10.0, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)

    code, report, noticed_s, modes, said = _failsafe_mission(tmp_path, ports, params, sag)
    assert code == 1 and report["outcome"] == "aborted", said[-3000:]
    assert "battery" in report["reason"].lower() and "RETURN_TO_LAUNCH" in report["reason"], report["reason"]
    assert report["uav"].get("left_to_autopilot") == "RETURN_TO_LAUNCH" and report["uav"]["landed"]
    assert noticed_s < 5.0, f"the failsafe was acted on {noticed_s:.1f} s after the battery sagged"
    # GUIDED until the failsafe, then its RTL to the ground: no mode (no command) of the UAV's after it
    assert modes[modes.index("RTL"):] == ["RTL"], modes


def test_a_ground_stations_return_home_in_the_survey_is_noticed_at_once_and_never_overridden(tmp_path, ports):
    def rtl(gcs) -> float:
        gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
        return time.time()

    code, report, noticed_s, modes, said = _failsafe_mission(tmp_path, ports, {}, rtl)
    assert code == 1 and report["outcome"] == "aborted", said[-3000:]
    assert "RETURN_TO_LAUNCH" in report["reason"], report["reason"]
    assert noticed_s < 2.0, f"the RTL was acted on {noticed_s:.1f} s after it was commanded"
    assert modes[modes.index("RTL"):] == ["RTL"], modes
