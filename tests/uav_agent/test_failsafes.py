"""The autopilot's safety wins: the agent notices its decision at once, in any phase, and never commands over it.

Real missions (`uav-robots run`) with a ground station on the vehicle's second MAVLink link (as
QGroundControl connects to PX4), which commands a return home or makes the battery critical; the
vehicle's own record says what it did afterwards, and who commanded it.
"""
from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from uav_agent.budget import RESERVE, flight_seconds, shortfall

CLI = [sys.executable, "-m", "uav_robots", "run", "--camera", "ideal", "--robots", "4"]   # progress lines: the trigger


def _mission(tmp_path: Path, gcs_port: int, trigger, when: str, *args: str) -> tuple[int, dict, float]:
    """Run a mission, call `trigger(gcs)` once the UAV's log shows `when` (it returns when it acted, or
    None: now); (exit, report, seconds from the trigger to the UAV's abort event)."""
    out = tmp_path / "out"
    proc = subprocess.Popen([*CLI, "--out", str(out), "--gcs", f"udpout:127.0.0.1:{gcs_port}", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=250)
    try:
        assert gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=60) is not None
        log = out / "logs" / "uav.log"
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and not (log.exists() and re.search(when, log.read_text())):
            time.sleep(0.05)
        triggered = trigger(gcs) or time.time()
        code = proc.wait(120)
    finally:
        gcs.close()
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    report = json.loads((out / "report.json").read_text())
    abort = next(e for e in report["events"] if e["kind"] == "abort")
    return code, report, abort["unix"] - triggered


def _after(events: list, words: str) -> list[str]:
    texts = [t for _, t in events]
    first = next(i for i, t in enumerate(texts) if words in t)
    return texts[first + 1:]


def _commanded(later: list[str]) -> list[str]:
    """What in the vehicle's record after a failsafe came from someone else's command: a mode change
    that is not the failsafe's own course (an RTL ends in its LAND; a worse battery; the disarm after
    landing), or a command the autopilot denied."""
    own = ("after landing", "battery", "RTL -> LAND")
    return [t for t in later if t.startswith("Mode ") and not any(w in t for w in own)] + \
        [t for t in later if "denied" in t.lower()]


@pytest.mark.slow
@pytest.mark.process
def test_a_return_home_commanded_during_the_climb_is_noticed_at_once_and_never_overridden(tmp_path, udp_port):
    # The issue saw an RTL from a ground station seen in 0.1 s, then the agent wait 120 s for its pose.
    def rtl(gcs) -> float:   # once the vehicle climbs through 3 m (PX4 denies a return on the ground)
        # returning where it is, not 30 m up first: the test waits for the landing, in real time
        gcs.mav.param_set_send(1, 1, b"RTL_RETURN_ALT", 0.0, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            m = gcs.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=1)
            if m is not None and m.relative_alt > 3000:
                break
        gcs.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0)
        return time.time()

    code, report, noticed_s = _mission(tmp_path, udp_port, rtl, r"takeoff: arming", "--time-scale", "1")
    assert code == 1 and report["outcome"] == "aborted"
    assert "RETURN_TO_LAUNCH" in report["reason"], report["reason"]
    assert noticed_s < 2.0, f"the RTL was acted on {noticed_s:.1f} s after it was commanded"
    assert report["uav"].get("left_to_autopilot") == "RETURN_TO_LAUNCH"
    # After the autopilot took it, no mode change but its own landing: the mission commanded nothing.
    later = _after(report["truth"]["vehicle"]["events"], "-> RTL")
    assert not _commanded(later), later


@pytest.mark.slow
@pytest.mark.process
def test_a_critical_battery_in_the_survey_returns_the_vehicle_and_names_the_battery(tmp_path, udp_port):
    def drain(gcs):   # a far smaller pack, drained far faster: critical within a simulated second or two
        for name, value in ((b"SIM_BAT_HOVER_A", 1000.0), (b"BAT1_CAPACITY", 900.0)):
            gcs.mav.param_set_send(1, 1, name, value, mavutil.mavlink.MAV_PARAM_TYPE_REAL32)

    code, report, _ = _mission(tmp_path, udp_port, drain, r"survey: image 1/")
    assert code == 1 and report["outcome"] == "aborted", report["reason"]
    assert "battery" in report["reason"] and ("RETURN_TO_LAUNCH" in report["reason"] or "LAND" in report["reason"])
    events = report["truth"]["vehicle"]["events"]
    failsafe = next((t for _, t in events if "battery" in t and "ailsafe" in t), None)
    assert failsafe, events[-8:]
    later = _after(events, failsafe)
    # the failsafe's own mode change first (its line may name no battery), then nobody else's
    first_mode = next(i for i, t in enumerate(later) if t.startswith("Mode "))
    assert not _commanded(later[first_mode + 1:]), later
    assert report["uav"].get("left_to_autopilot") in ("RETURN_TO_LAUNCH", "LAND")


@pytest.mark.slow
@pytest.mark.process
def test_an_injected_battery_fault_is_the_vehicles_to_act_on_and_the_mission_leaves_it_to_it(tmp_path):
    """`--fault battery:6@3` (protocol/faults.py, vehicle.battery): the run spec carries it to our vehicle,
    whose pack holds 6 % after 3 s in the air, under BAT_CRIT_THR: its own failsafe returns it home. The
    mission ends aborted naming that return, commands nothing over it, and the vehicle lands."""
    out = tmp_path / "out"
    res = subprocess.run([*CLI, "--fault", "battery:6@3", "--out", str(out)], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 1, res.stderr[-2000:]
    report = json.loads((out / "report.json").read_text())
    assert report["outcome"] == "aborted" and report["run"]["faults"] == ["battery:6@3"]
    assert "RETURN_TO_LAUNCH" in report["reason"] and "battery" in report["reason"], report["reason"]
    assert report["uav"]["left_to_autopilot"] == "RETURN_TO_LAUNCH" and report["uav"]["landed"]
    assert "fault injected: the pack holds 6% after 3 s in the air" in (out / "logs" / "vehicle.log").read_text()
    events = report["truth"]["vehicle"]["events"]
    later = _after(events, "Failsafe: critical battery")
    assert not _commanded(later), later


def test_the_battery_budget():
    # The survey: 464 images, an hour's pack: refused before it is flown.
    poses = [(-(i // 29) * 15.0, (i % 29) * 15.0, 40.0) for i in range(464)]
    need = flight_seconds(poses, (0.0, 0.0, 10.0))
    assert need > 3600 * (1 - RESERVE)
    why = shortfall(3600.0, need, "the survey of 464 image(s)", 88.0)
    assert why.startswith("battery: 60.0 min of flight left (88 %); the survey of 464 image(s) needs about")
    assert "25% is kept to return and land" in why
    # a small survey fits; an autopilot that says nothing of its pack is not budgeted
    assert shortfall(3600.0, flight_seconds(poses[:9], (0.0, 0.0, 10.0)), "x") is None
    assert shortfall(None, need, "x") is None and shortfall(float("nan"), need, "x") is None

