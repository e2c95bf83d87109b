"""The robot conformance suite, run as a user would: against our robot, and against a broken one."""
from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from conformance.suite_files import suite_files
from suites import outcome, run_suite

pytestmark = pytest.mark.process   # every test here starts a process

REPO = Path(__file__).resolve().parents[2]


def _suite(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return run_suite(*map(str, suite_files("robot")), *args, timeout=timeout)


@pytest.mark.slow
def test_our_robot_conforms():
    run = _suite()
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    last = outcome(run.stdout)
    assert " passed" in last and "failed" not in last and "skipped" not in last, last
    assert "the implementation keeps protocol 2 (stated in its first PlanAck): held to every robot rule" in run.stdout


@pytest.mark.slow
def test_our_robot_conforms_with_an_explicit_command_and_id():
    cmd = f"{shlex.quote(sys.executable)} -m robot_agents --ids {{id}} --fleet {{fleet}} --connect {{endpoint}}"
    run = _suite("--robot-cmd", cmd, "--robot-id", "42", "-k", "follow_the_plan")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "1 passed" in run.stdout


@pytest.mark.slow
def test_a_silent_robot_fails_the_suite():
    silent = f"{shlex.quote(sys.executable)} -c \"import time; time.sleep(60)\""
    run = _suite("--robot-cmd", silent, "--robot-timeout", "1", "-k", "liveliness or valid_plan")
    assert run.returncode == 1, run.stdout[-3000:]
    assert "1 failed" in run.stdout and "1 error" in run.stdout, run.stdout[-3000:]
    assert "no liveliness token" in run.stdout


@pytest.mark.slow
def test_a_robot_that_acks_nothing_fails_the_suite(tmp_path):
    # A robot that comes alive but ignores every message: the liveliness test passes, the rest fail.
    mute = tmp_path / "mute_robot.py"
    mute.write_text(
        "import sys, time\n"
        "from protocol.config import client_config\n"
        "from protocol.keys import Keys\n"
        "from protocol.transport import ZenohTransport\n"
        "rid, fleet, ep = int(sys.argv[1]), sys.argv[2], sys.argv[3]\n"
        "with ZenohTransport(client_config([ep])) as t:\n"
        "    tok = t.announce(Keys(fleet).alive_robot(rid))\n"
        "    time.sleep(60)\n")
    cmd = f"{shlex.quote(sys.executable)} {shlex.quote(str(mute))} {{id}} {{fleet}} {{endpoint}}"
    run = _suite("--robot-cmd", cmd, "--robot-timeout", "1", "-k", "liveliness or valid_plan")
    assert run.returncode == 1, run.stdout[-3000:]
    assert "1 failed, 1 passed" in run.stdout, run.stdout[-3000:]
    assert "no PlanAck" in run.stdout


def _cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "uav_robots", "conformance", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)


def test_the_command_takes_cmd_after_the_kind():
    cmd = f"{shlex.quote(sys.executable)} -m robot_agents --id {{id}} --fleet {{fleet}} --connect {{endpoint}}"
    run = _cli("robot", "--cmd", cmd, "-k", "liveliness")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    assert "1 passed" in run.stdout


def test_the_command_lists_the_rules():
    run = _cli("--list-rules", "uav")
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("U1 ") and "R1 " not in run.stdout
    assert "test_the_lockstep_barrier_holds" in run.stdout


def test_the_command_without_a_kind_is_a_usage_error():
    run = _cli()
    assert run.returncode == 2 and "give robot or uav" in run.stderr and "Traceback" not in run.stderr
