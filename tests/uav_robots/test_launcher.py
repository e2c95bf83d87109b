"""When the launcher starts the robots: once the UAV flies, or after a bound; real child processes, no mission."""
import subprocess
import sys
import time

import pytest

from uav_robots.cli import build_parser
from uav_robots.run.launcher import Child, Launcher


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


@pytest.mark.process
def test_the_robots_start_once_the_uav_flies(launcher):
    lau, uav, started = launcher
    t0 = time.monotonic()
    lau.robots_due = t0 + 60.0
    assert lau.watch(uav, 30.0, lambda: time.monotonic() >= t0 + 0.3) == 0
    assert len(started) == 1 and 0.3 <= started[0] - t0 < 1.0


@pytest.mark.process
def test_the_robots_start_at_the_latest_after_the_bound(launcher):
    lau, uav, started = launcher
    t0 = time.monotonic()
    lau.robots_due = t0 + 0.5      # as start() sets it, ROBOTS_AT_LATEST_S after the UAV
    assert lau.watch(uav, 30.0, lambda: False) == 0
    assert len(started) == 1 and 0.5 <= started[0] - t0 < 1.2


def test_robots_are_forked_processes_with_their_own_logs_sessions_and_exit_codes(tmp_path):
    """`uav-robots run` forks its robots from a server that imported them once: each is still a
    process of its own, with its own log and Zenoh session, and it ends on SIGTERM or bad input."""
    import os
    import signal

    import zenoh

    from protocol.transport import zenoh_config
    from robot_agents import forked
    from uav_robots.common.ports import free_port

    if not forked.available():
        pytest.skip("no forkserver on this platform")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(zenoh_config('{mode: "router", scouting: {multicast: {enabled: false}}}',
                                     {"listen/endpoints": [endpoint]}))
    robots = bad = None
    try:
        robots = forked.Forked(["--ids", "0-1", "--fleet", "forked", "--connect", endpoint], str(tmp_path / "r.log"))
        bad = forked.Forked(["--fleet", "forked", "--connect", endpoint], str(tmp_path / "bad.log"))
        assert robots.pid not in (None, os.getpid()) and bad.pid != robots.pid
        log = tmp_path / "r.log"
        deadline = time.monotonic() + 20
        while not (log.exists() and "ready" in log.read_text()) and time.monotonic() < deadline:
            assert robots.poll() is None
            time.sleep(0.05)
        assert "robots 0-1 ready (fleet forked)" in log.read_text()
        import psutil   # what ps and pgrep -f show: the robot's command, not the fork server's
        assert "-m robot_agents --ids 0-1 --fleet forked" in " ".join(psutil.Process(robots.pid).cmdline())
        assert bad.wait(timeout=20) == 2
        assert (tmp_path / "bad.log").read_text().strip() == "error: give the robots to host: --id K (repeatable) or --ids 0-49"
        robots.send_signal(signal.SIGTERM)
        assert robots.wait(timeout=20) in (0, 143)
        robots.kill()     # reaped: no signal goes to a pid that may be someone else's by now
    finally:
        for p in (robots, bad):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(timeout=10)
        router.close()
