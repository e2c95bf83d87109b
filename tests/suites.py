"""The conformance suites run as a user runs them: a pytest of their own, in its own temporary directory.

pytest keeps only its three newest numbered temporary directories (`/tmp/pytest-of-<user>/pytest-N`) and
deletes older ones as it starts, whoever still uses them: a suite started beside this test run (the
mutation test starts five at a time) deleted the directories of the suites and tests still running, and
their missions failed writing there ("never-up is not a normalized and relative path"). A `--basetemp`
of its own is cleared only for itself.
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def outcome(stdout: str) -> str:
    """pytest's last line ("38 passed in 69.24s"): the counts, not test names that hold "error"."""
    lines = stdout.strip().splitlines()
    return lines[-1] if lines else ""


def run_suite(suite: str, *args: str, timeout: float) -> subprocess.CompletedProcess:
    with tempfile.TemporaryDirectory(prefix="suite-") as base:
        # The suites use no hypothesis; its plugin's import is half of a suite's start (0.7 of 1.5 s), and
        # the mutation test starts 113 of them.
        return subprocess.run([sys.executable, "-m", "pytest", suite, "-q", "-p", "no:cacheprovider",
                               "-p", "no:hypothesispytest", f"--basetemp={base}", *args], cwd=REPO,
                              capture_output=True, text=True, timeout=timeout)
