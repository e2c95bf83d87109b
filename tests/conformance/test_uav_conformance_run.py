"""The UAV conformance suite, run as a user would: against our UAV, and against broken ones."""
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
SUITE = [str(path) for path in suite_files("uav")]


def _suite(*args: str, timeout: float = 280) -> subprocess.CompletedProcess:
    return run_suite(*SUITE, *args, timeout=timeout)


@pytest.mark.slow
def test_our_uav_conforms():
    run = _suite()
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-2000:]
    last = outcome(run.stdout)
    assert " passed" in last and "failed" not in last and "error" not in last, last


@pytest.mark.slow
def test_a_uav_that_never_comes_up_fails_the_suite():
    silent = f"{shlex.quote(sys.executable)} -c \"import time; time.sleep(60)\""
    run = _suite("--uav-cmd", silent, "--uav-timeout", "2", "-k", "uav_token_is_up")
    assert run.returncode == 1, run.stdout[-3000:]
    assert "1 failed" in run.stdout, run.stdout[-3000:]
    assert "the UAV was still running after 2 s" in run.stdout


# UAVs with one rule broken each (a tick barrier left out, every Done believed, ...) are
# conformance.mutants, run against the rules' tests by tests/conformance/test_conformance_mutants.py.
