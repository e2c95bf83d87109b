"""Whole missions with the honest camera: the estimated pose, lens, JPEG and degradations.

Real processes (world, UAV, robots) through `uav-robots run`; the report's perceived map is
checked against the world's ground truth. The default mission (tests/uav_robots/test_end_to_end.py) runs
the default camera, the realistic one, and checks its registration the same way."""
from __future__ import annotations

import subprocess
import sys

import pytest

from uav_agent.report import load_report

pytestmark = pytest.mark.process   # every test here starts a process

CLI = [sys.executable, "-m", "uav_robots"]


def _mission(tmp_path, camera: str, timeout: float, extra: list[str] = ()):
    res = subprocess.run(CLI + ["run", "--camera", camera, "--out", str(tmp_path), *extra], capture_output=True,
                         text=True, timeout=timeout)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    report = load_report(tmp_path)
    assert report["completed"] is True and report["collisions"] == 0
    assert report["perceived"]["rows"] == report["truth"]["rows"]
    assert report["perceived"]["robots"] == report["truth"]["robots"]
    reg = report["perceived"]["registration"]
    assert reg["by_landmarks"] >= 1 and reg["reprojection_px_max"] < 2.5
    return report


@pytest.mark.slow
def test_default_map_at_the_target_degradation(tmp_path):
    _mission(tmp_path, "realistic,blur_sigma=2,lighting=0.5,noise_std=10,pose_sigma_m=0.5,yaw_sigma_deg=3",
             timeout=600)


@pytest.mark.slow
def test_a_larger_floor_with_20_robots_at_the_target_degradation(tmp_path):
    # Blur 2 sends the survey lower (more pixels per cell); the verification must read robots parked
    # on their goals, inside the pads' green frames. The paper's 450 floor at this degradation (35
    # survey images; a whole mission of about 130 s, too long for every CI run) is checked offline by
    # tests/uav_agent/perception/test_perception_registration.py and `uav-robots bench perception`.
    report = _mission(tmp_path, "realistic,blur_sigma=2,lighting=0.5,noise_std=10,pose_sigma_m=0.5,yaw_sigma_deg=3",
                      timeout=600, extra=["--map", "warehouse:blocks_x=6,blocks_y=8", "--robots", "20"])
    assert all(report["verified"].values()) and report["uav"]["survey_px_per_cell"] > 30
    assert not [e for e in report["events"] if e["kind"] == "done-contradicted"]
