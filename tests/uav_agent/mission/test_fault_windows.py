"""Window faults in whole missions (protocol/faults.py camera.off and link.mavlink): a dead camera
for a while, a short loss of the MAVLink link, and one long enough for the vehicle's own
datalink-loss failsafe to act. Each is a real `uav-robots run`: the world, our vehicle, the UAV
and the robots as processes, Zenoh on loopback, MAVLink over UDP. camera.stuck is proven on a
world process (tests/sim_world/test_camera_faults.py) and the UAV's refusal of its images
(tests/uav_agent/test_shots.py, test_fresh_images.py)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.process, pytest.mark.slow]   # whole missions

CLI = [sys.executable, "-m", "uav_robots", "run"]   # the default mission, its realistic camera included


def _run(out: Path, *faults: str, timeout: float = 240) -> tuple[subprocess.CompletedProcess, dict]:
    res = subprocess.run([*CLI, "--out", str(out), *(a for f in faults for a in ("--fault", f))],
                         capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    assert "Traceback" not in res.stderr + res.stdout, res.stderr[-3000:]
    return res, json.loads((out / "report.json").read_text())


def test_a_camera_dead_for_a_while_is_waited_for_and_the_mission_completes(tmp_path):
    """camera-off:20+80: from 20 s (the world's simulated clock, 2 s of wall time at the default time
    scale of 10) the camera answers nothing for 80 s: the survey's image never comes. The UAV sets it
    aside, holds over its pose and asks again until the camera is back, and completes."""
    out = tmp_path / "out"
    res, report = _run(out, "camera-off:20+80")
    assert res.returncode == 0, res.stdout[-3000:]
    assert report["outcome"] == "completed" and report["collisions"] == 0
    assert report["run"]["faults"] == ["camera-off:20+80"]
    assert report["truth"]["camera_faults"]["unanswered"] >= 1        # the world's record: it did land
    kinds = {e["kind"] for e in report["events"]}
    assert kinds & {"retake", "camera-outage"}, report["events"]
    assert "fault camera-off:20+80 acts at t=" in (out / "logs" / "world.log").read_text()


def test_a_short_loss_of_the_mavlink_link_is_waited_out(tmp_path):
    """mavlink-loss:0+60: from liftoff the flight link carries nothing for 60 simulated seconds (6 s of
    wall time, under the vehicle's COM_DL_LOSS_T of 10 s): the take-off is flown blind and its commands
    sent again; the vehicle's failsafe never acts, and the mission completes."""
    out = tmp_path / "out"
    res, report = _run(out, "mavlink-loss:0+60")
    assert res.returncode == 0, res.stdout[-3000:]
    assert report["outcome"] == "completed" and report["collisions"] == 0
    assert report["run"]["faults"] == ["mavlink-loss:0+60"]
    vehicle = (out / "logs" / "vehicle.log").read_text()
    assert "fault injected: the flight link carries nothing for 60 s, from 0 s after liftoff" in vehicle
    assert "fault over: the flight link is back" in vehicle and "Data link lost" not in vehicle


def test_a_long_loss_of_the_mavlink_link_is_the_vehicles_failsafe_and_ends_the_mission_naming_it(tmp_path):
    """mavlink-loss:0+200: 20 s of wall time without the link. The vehicle holds after COM_DL_LOSS_T
    (10 s), returns after COM_FAIL_ACT_T (5 s more: NAV_DLL_ACT 2) and lands at home. The UAV waits
    for the link (LINK_LOSS_S, 30 s), sees on its return what the autopilot did, and ends the mission
    aborted naming the lost link, commanding nothing over the autopilot: a report, no hang."""
    out = tmp_path / "out"
    res, report = _run(out, "mavlink-loss:0+200")
    assert res.returncode == 1, res.stdout[-3000:]
    assert report["outcome"] == "aborted" and report["run"]["faults"] == ["mavlink-loss:0+200"]
    # On a machine too loaded for the vehicle's clock to keep its pace the link may come back after the
    # UAV gave up on it (LINK_LOSS_S): then the reason is that, and the failsafe is still named.
    assert "datalink-loss failsafe" in report["reason"], report["reason"]
    if "MAVLink link was lost" in report["reason"]:   # back in time: the UAV saw what the autopilot did
        assert report["uav"].get("left_to_autopilot") and report["uav"]["landed"], report["uav"]
    vehicle = (out / "logs" / "vehicle.log").read_text()
    assert "Data link lost: holding, RTL in 5 s" in vehicle and "Failsafe: data link lost, RTL" in vehicle
