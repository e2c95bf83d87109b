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

# The 450 floor with 50 robots at the target degradation: tests/uav_robots/test_end_to_end.py's paper setting.
