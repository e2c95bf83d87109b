"""A robot of protocol 1 (tests/v1_robot, frozen) against today's robot conformance suite.

docs/protocol.md, Versioning: a robot is held to the rules of the protocol version its PlanAck states
(none stated: 1). The frozen robot passes every rule of protocol 1, the suite says in one line which rules
it was not held to, and held to protocol 2 it fails the rules whose meaning changed.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shlex
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from conformance.rules import newer_rules
from conformance.suite_files import suite_files
from suites import outcome, run_suite

REPO = Path(__file__).resolve().parents[2]
FROZEN = REPO / "tests" / "v1_robot"
DIGEST = "265821862fe3a407e49b45b52c19fcf018a348f7ecc6864e8aac131177cdd11c"
V1 = f"{shlex.quote(sys.executable)} tests/v1_robot/run.py"
ARGS = "--fleet {fleet} --connect {endpoint}"


def _suite(*args: str) -> subprocess.CompletedProcess:
    return run_suite(*map(str, suite_files("robot")), "--robot-cmd", f"{V1} --id {{id}} {ARGS}",
                     "--robot-pool-cmd", f"{V1} --ids {{ids}} {ARGS}", *args, timeout=240)


def test_the_frozen_robot_is_unchanged():
    h = hashlib.sha256()
    for p in sorted(FROZEN.rglob("*.py")):
        if "__pycache__" not in p.parts:
            h.update(p.relative_to(FROZEN).as_posix().encode() + b"\0" + p.read_bytes() + b"\0")
    assert h.hexdigest() == DIGEST, "tests/v1_robot changed: it is a frozen protocol 1 robot (see its README)"


@pytest.mark.slow
@pytest.mark.process
def test_a_protocol_1_robot_passes_the_rules_of_protocol_1():
    run = _suite()
    out = run.stdout
    assert run.returncode == 0, out[-3000:] + run.stderr[-2000:]
    assert " passed" in outcome(out) and "failed" not in outcome(out), out[-3000:]
    (line,) = [x for x in out.splitlines() if x.startswith("robot protocol:")]
    assert "keeps protocol 1 (its first PlanAck states none)" in line, line
    assert all(r.id in line for r in newer_rules("robot", 1)), line
    assert "refuses it on a secured fleet" in line, line


@pytest.mark.slow
@pytest.mark.process
def test_held_to_protocol_2_it_fails_the_rules_that_changed():
    """The four rules whose meaning changed since protocol 1: not held to them, it passes; held, it fails."""
    changed = ["test_moves_are_asked_on_the_key_naming_the_robot",                    # R35
               "test_a_repair_plan_starts_at_its_tick_and_is_switched_to_at_once",   # R16
               "test_a_repair_plan_for_a_past_tick_is_refused",                       # R15
               "test_diagonal_steps_are_moves_when_the_plan_says_8"]                  # R10
    run = _suite("--robot-protocol", "2", "-k", " or ".join(changed), "-rf")
    assert run.returncode == 1, run.stdout[-3000:]
    failed = set(re.findall(r"^FAILED conformance/test_robot_\w+\.py::(\w+)", run.stdout, re.M)) & set(changed)
    assert failed == set(changed), run.stdout[-3000:]


def _free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
@pytest.mark.parametrize("secured", [False, True], ids=["open", "secured"])
@pytest.mark.process
def test_a_uav_serves_protocol_1_robots_and_refuses_them_on_a_secured_fleet(tmp_path, secured):
    """Today's UAV and world with a pool of frozen protocol 1 robots: served on an open fleet (the
    mission completes; one event per robot says what it will not get), refused in one line under
    access control (they ask their moves on the plain key it leaves unreachable)."""
    zport, mport, fleet = _free_port(), _free_port(socket.SOCK_DGRAM), f"v1{os.getpid()}"
    scheme = "tls" if secured else "tcp"
    if secured:
        subprocess.run([sys.executable, "-m", "uav_robots", "secure", "init", "--robots", "4", "--robots-per-process",
                        "4", "--fleet", fleet, "--port", str(zport), str(tmp_path / "sec")], check=True, timeout=60,
                       capture_output=True)

    def session(name: str, flag: str = "--connect") -> list[str]:
        own = ["--zenoh-config", str(tmp_path / "sec" / f"{name}.json5")] if secured else []
        return [*own, flag, f"{scheme}/127.0.0.1:{zport}"]

    out = tmp_path / "out"
    procs = []
    try:
        uav = subprocess.Popen([sys.executable, "-m", "uav_agent", "--fleet", fleet, *session("uav", "--listen"),
                                "--robots", "4", "--mavlink", f"udpin://127.0.0.1:{mport}", "--out", str(out),
                                "--tick-timeout", "3", "--quiet", "--summary", "none"], cwd=REPO,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(uav)
        procs.append(subprocess.Popen([sys.executable, "-m", "sim_world", "--fleet", fleet, *session("world"),
                                       "--robots", "4", "--mavlink", f"udpout:127.0.0.1:{mport}", "--time-scale",
                                       "10", "--camera", "ideal"], cwd=REPO, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
        # protocol 1 takes a config file or an endpoint, not both: the file names the router's
        v1_session = session("robots-0-3")[:2] if secured else session("robots-0-3")
        procs.append(subprocess.Popen([sys.executable, "tests/v1_robot/run.py", "--ids", "0-3", "--fleet", fleet,
                                       *v1_session], cwd=REPO, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL))
        _, err = uav.communicate(timeout=240)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait(10)
    report = json.loads((out / "report.json").read_text())
    if not secured:
        assert uav.returncode == 0 and report["completed"], err[-3000:]
        older = [e for e in report["events"] if e["kind"] == "older-protocol"]
        assert sorted(r for e in older for r in e["robots"]) == [0, 1, 2, 3], report["events"]
        assert "keeps protocol 1: served" in older[0]["what"]
    else:
        assert uav.returncode == 1, err[-3000:]
        last = err.strip().splitlines()[-1]
        assert "keeps protocol 1: it asks its moves on P/world/move, which access control leaves unreachable" \
            in last, last
        assert report["completed"] is False and "keeps protocol 1" in report["reason"]
