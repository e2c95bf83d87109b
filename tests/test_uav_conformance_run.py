"""The UAV conformance suite, run as a user would: against our UAV, and against broken ones."""
from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SUITE = "conformance/test_uav_conformance.py"
UAV_ARGS = "--fleet {fleet} --connect {endpoint} --mavlink udpin://127.0.0.1:{mavlink_port} " \
           "--robots {robots} --tick-timeout {tick_timeout}"


def _suite(*args: str, timeout: float = 280) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pytest", SUITE, "-q", "-p", "no:cacheprovider", *args],
                          cwd=REPO, capture_output=True, text=True, timeout=timeout)


def test_our_uav_conforms():
    run = _suite()
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert " passed" in run.stdout and "failed" not in run.stdout and "error" not in run.stdout


def test_a_uav_that_never_comes_up_fails_the_suite():
    silent = f"{shlex.quote(sys.executable)} -c \"import time; time.sleep(60)\""
    run = _suite("--uav-cmd", silent, "--uav-timeout", "2", "-k", "uav_token_is_up")
    assert run.returncode == 1, run.stdout[-3000:]
    assert "1 failed" in run.stdout, run.stdout[-3000:]
    assert "the UAV was still running after 2 s" in run.stdout


def _broken_uav(tmp_path, name: str, patch: str) -> str:
    """Our UAV with one rule broken by `patch` (Python run before its main), as a --uav-cmd."""
    script = tmp_path / f"{name}.py"
    script.write_text("import sys\n"
                      "from protocol.process import command_main\n"
                      "from uav_agent.cli import build_parser\n"
                      "from uav_agent.fleet import FleetLink\n"
                      "from uav_agent.mission import Mission\n"
                      + patch +
                      "sys.exit(command_main(build_parser))\n")
    return f"{shlex.quote(sys.executable)} {shlex.quote(str(script))} {UAV_ARGS}"


def test_a_uav_without_a_tick_barrier_fails_the_suite(tmp_path):
    # It puts tick k+1 without waiting for the robots' states for tick k.
    cmd = _broken_uav(tmp_path, "hasty_uav", "FleetLink.wait_tick = lambda self, robots, k, timeout, interrupt: {}\n"
                                             "Mission._recover = lambda self, k, faults: None\n")
    run = _suite("--uav-cmd", cmd, "-k", "barrier_holds")
    assert run.returncode == 1, run.stdout[-3000:]
    assert "1 failed" in run.stdout, run.stdout[-3000:]
    assert "FAILED " + SUITE + "::test_the_lockstep_barrier_holds" in run.stdout
    assert "before robots [0, 1, 2] reported tick 1" in run.stdout


def test_a_uav_that_believes_every_done_fails_the_suite(tmp_path):
    # Its verification removed: every robot that raised Done counts as arrived.
    cmd = _broken_uav(tmp_path, "credulous_uav", "def believe(self):\n"
                                                 "    self.verified = {r: r in self.fleet.done for r in self.ids}\n"
                                                 "Mission._verify = believe\n"
                                                 "Mission._off_goal = lambda self: []\n")
    run = _suite("--uav-cmd", cmd, "-k", "contradicts")
    assert run.returncode == 1, run.stdout[-3000:]
    assert "1 failed" in run.stdout and "never left its start" in run.stdout, run.stdout[-3000:]
