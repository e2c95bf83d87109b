"""When the launcher starts the robots: once the UAV flies, or after a bound; real child processes, no mission."""
import subprocess
import sys
import time

import pytest

from uav_robots.cli import build_parser
from uav_robots.launcher import Child, Launcher


@pytest.fixture
def launcher(tmp_path, monkeypatch):
    args = build_parser(["run"]).parse_args(["run", "--out", str(tmp_path)])
    lau = Launcher(args)
    started: list[float] = []
    monkeypatch.setattr(lau, "start_robots", lambda: (started.append(time.monotonic()),
                                                       setattr(lau, "robots_started", True)))
    uav = Child("uav", subprocess.Popen([sys.executable, "-c", "import time; time.sleep(1.5)"]), None)
    lau.children.append(uav)
    yield lau, uav, started
    lau.stop(graceful=False)


def test_the_robots_start_once_the_uav_flies(launcher):
    lau, uav, started = launcher
    t0 = time.monotonic()
    lau.robots_due = t0 + 60.0
    assert lau.watch(uav, 30.0, lambda: time.monotonic() >= t0 + 0.3) == 0
    assert len(started) == 1 and 0.3 <= started[0] - t0 < 1.0


def test_the_robots_start_at_the_latest_after_the_bound(launcher):
    lau, uav, started = launcher
    t0 = time.monotonic()
    lau.robots_due = t0 + 0.5      # as start() sets it, ROBOTS_AT_LATEST_S after the UAV
    assert lau.watch(uav, 30.0, lambda: False) == 0
    assert len(started) == 1 and 0.5 <= started[0] - t0 < 1.2
