"""The conformance suites catch every rule: each mutant (our robot or UAV with one rule broken) fails them.

For each rule of conformance/rules.py the suite of its side runs, as a user would
(`pytest --robot-cmd/--uav-cmd`), only the tests the table maps to that rule,
against `python -m conformance.mutants SIDE --break ID`; at least one of them
must fail. Three suites run at a time: on 2 cores they mostly wait (on the
simulated flight, on timeouts the mutants provoke), they do not compute. Our own implementations passing the
same suites is tests/conformance/test_conformance_run.py and tests/conformance/test_uav_conformance_run.py.
"""
from __future__ import annotations

import re
import shlex
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from conformance import mutants
from conformance.rules import DOC, RULES, markdown, rules, since_of_test
from conformance.suite_files import SUITES, suite_files, suite_tests
from suites import run_suite

pytestmark = pytest.mark.mutation

REPO = Path(__file__).resolve().parents[2]
PY = shlex.quote(sys.executable)
ROBOT_ARGS = "--fleet {fleet} --connect {endpoint}"
UAV_ARGS = ("--fleet {fleet} --connect {endpoint} --mavlink udpin://127.0.0.1:{mavlink_port} "
            "--robots {robots} --tick-timeout {tick_timeout}")
# A robot that never comes alive or never answers fails after this, not after the default 10 s. Our robot
# keeps protocol 2: a mutant is held to all of it, whatever its acks state (R71 breaks that).
ROBOT_OPTS = ("--robot-timeout", "5", "--robot-protocol", "2")
# A mutant UAV that never ends its mission is killed after this, not after the default 90 s
# (a clean mission of the suite takes about 10 s).
UAV_OPTS = ("--uav-timeout", "45")
CONTROL = "none"       # the wrapper with no rule broken
WORKERS = 5            # suites at a time: a suite mostly waits (on robots, flights, timeouts), not computes
FAILED = re.compile(r"^(?:FAILED|ERROR) conformance/test_\w+\.py::(\w+)", re.M)


@dataclass(frozen=True)
class Verdict:
    rule: str
    code: int
    failed: frozenset[str]    # test functions that failed or errored
    seconds: float
    tail: str


def _command(side: str, rule: str) -> tuple[str, ...]:
    impl = f"{PY} -m conformance.mutants {side} --break {rule}"
    if side == "uav":
        return ("--uav-cmd", f"{impl} {UAV_ARGS}", *UAV_OPTS)
    return ("--robot-cmd", f"{impl} --id {{id}} {ROBOT_ARGS}", "--robot-pool-cmd", f"{impl} --ids {{ids}} {ROBOT_ARGS}",
            "--robot-ahead-cmd", f"{impl} --id {{id}} {ROBOT_ARGS} --moves ahead",
            "--robot-pool-ahead-cmd", f"{impl} --ids {{ids}} {ROBOT_ARGS} --moves ahead", *ROBOT_OPTS)


def _suite(side: str, rule: str, tests: tuple[str, ...]) -> Verdict:
    argv = ["-rfE", *_command(side, rule)]
    if tests:
        # Only the rule's own tests run, so their first failure already catches the mutant.
        argv += ["-k", " or ".join(tests), "--maxfail=1"]
    t = time.monotonic()
    run = run_suite(*map(str, suite_files(side)), *argv, timeout=400)
    return Verdict(rule, run.returncode, frozenset(FAILED.findall(run.stdout)), time.monotonic() - t,
                   run.stdout[-2500:] + run.stderr[-1000:])


@pytest.fixture(scope="module")
def verdicts() -> dict[str, Verdict]:
    """Every mutant against its rule's tests, UAV missions first (they take longest); and the control,
    the whole robot suite against the wrapper unbroken (CONTROL), beside them rather than after."""
    jobs = [(r.side, r.id, r.tests) for r in rules("uav")] + [("robot", CONTROL, ())] + \
        [(r.side, r.id, r.tests) for r in rules("robot")]
    t = time.monotonic()
    with ThreadPoolExecutor(max_workers=WORKERS) as pool:
        out = {v.rule: v for v in pool.map(lambda job: _suite(*job), jobs)}
    print(f"\n{len(out) - 1} mutants and the control in {time.monotonic() - t:.0f} s wall")
    for r in RULES:
        v = out[r.id]
        print(f"  {r.id:4} exit {v.code} in {v.seconds:5.1f} s, caught by: {', '.join(sorted(v.failed)) or '-'}")
    return out


def test_every_rule_has_a_test_and_a_mutant():
    suites = {"robot": suite_tests("robot"), "uav": suite_tests("uav")}
    for r in RULES:
        assert r.tests, f"{r.id} has no test"
        for name in r.tests:
            assert callable(suites[r.side].get(name)), f"{r.id}: no test {name} in conformance/{SUITES[r.side]}"
    for side in ("robot", "uav"):
        assert sorted(mutants.breaks(side)) == sorted(r.id for r in rules(side)), f"{side}: rules without a mutant " \
            "or mutants without a rule"
    assert len({r.id for r in RULES}) == len(RULES)
    # A robot keeping an older protocol skips the tests of newer rules: each rule needs a test of its own version.
    for r in RULES:
        assert any(since_of_test(r.side, t) <= r.since for t in r.tests), \
            f"{r.id} (since protocol {r.since}) is checked only by tests of newer rules: {r.tests}"


def test_the_rule_table_in_the_docs_is_current():
    assert DOC.read_text() == markdown(), "docs/conformance-rules.md is stale: run python -m conformance.rules --write"


@pytest.mark.timeout(1500)   # the first test waits for every mutant's run (the module fixture)
@pytest.mark.parametrize("rule", [r.id for r in RULES])
@pytest.mark.process
def test_the_suite_catches_the_mutant(verdicts, rule):
    v = verdicts[rule]
    assert v.code == 1, f"mutant {rule} was not caught (pytest exit {v.code})\n{v.tail}"
    mapped = set(next(r for r in RULES if r.id == rule).tests)
    assert v.failed & mapped, f"mutant {rule}: none of the tests mapped to it failed\n{v.tail}"


@pytest.mark.timeout(1500)   # may be the first to wait for the module fixture
@pytest.mark.process
def test_the_mutant_wrapper_unbroken_passes_the_robot_suite(verdicts):
    """The control: the wrapper itself changes nothing, so each failure above is its rule's."""
    v = verdicts[CONTROL]
    assert v.code == 0 and not v.failed, v.tail


@pytest.mark.process
def test_an_unknown_rule_is_a_usage_error():
    run = subprocess.run([sys.executable, "-m", "conformance.mutants", "robot", "--break", "R999", "--id", "1"],
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert "no robot mutant 'R999'" in run.stderr and "Traceback" not in run.stderr
