"""UAV conformance: the bounded waits, each mission waiting one out (docs/protocol.md, Timeouts and waits).

The suite plays router, world and robots around the UAV under test, started from
`--uav-cmd` (conftest.py); a mission is shared by the tests of one module. See
docs/protocol.md, "Conformance", and docs/conformance-rules.md.
"""
from __future__ import annotations

import pytest

from conformance.uav_harness import ABORT_SLACK_S, QUERY_WAIT_S, STARTUP_WAIT_S, MissionRun
from conformance.uav_missions import ABSENT, slow
from conformance.uav_steps import RESEND_S, RESEND_SLACK_S, exited, fails_with_one_line, fault, no_harness_trouble


@pytest.fixture(scope="module")
def stranded(uav_options, tmp_path_factory) -> dict[str, MissionRun]:
    return slow("stranded", uav_options, tmp_path_factory)


@pytest.fixture(scope="module")
def never_up(uav_options, tmp_path_factory) -> MissionRun:
    return slow("never_up", uav_options, tmp_path_factory)


@pytest.fixture(scope="module")
def unacked(uav_options, tmp_path_factory) -> MissionRun:
    return slow("unacked", uav_options, tmp_path_factory)


def test_a_uav_without_a_world_ends_the_mission(stranded, uav_options):
    run = stranded["none"]
    fails_with_one_line(run, uav_options, run.started, r"[Ww]orld", STARTUP_WAIT_S + ABORT_SLACK_S)


@pytest.mark.parametrize("answer", ["silent", "garbage"])
def test_a_world_that_does_not_answer_its_info_ends_the_mission(stranded, uav_options, answer):
    run = stranded[answer]
    fails_with_one_line(run, uav_options, run.started, r"info", QUERY_WAIT_S + ABORT_SLACK_S)


def test_a_robot_that_never_comes_up_ends_the_mission(never_up, uav_options):
    run = never_up
    assert not run.log.plans, "plans were put although a robot's token never came up"
    # Its wait began at its last phase change at the latest (the fleet's other tokens were up before it started).
    since = max((t for t, _ in run.log.statuses), default=run.started)
    fails_with_one_line(run, uav_options, since, rf"\b{ABSENT}\b", STARTUP_WAIT_S + ABORT_SLACK_S)


def test_an_unacknowledged_repair_is_put_again_and_then_given_up(unacked, uav_options):
    run, deaf = unacked, 1
    exited(run, uav_options)
    fault(run, "deaf-repair", deaf)
    pid = next(p.plan_id for _, r, p, _ in run.log.plans if r == deaf and p.start_tick > 0)
    puts = [t for t, r, p, _ in run.log.plans if r == deaf and p.plan_id == pid]
    gaps = [b - a for a, b in zip(puts, puts[1:])]
    assert len(puts) >= 3 and all(g <= RESEND_S + RESEND_SLACK_S for g in gaps), \
        f"repair {pid} was put to robot {deaf} {len(puts)} times, {[round(g, 1) for g in gaps]} s apart " \
        f"(every {RESEND_S:g} s while it is not acknowledged)"
    went_on = next((t for t, tick in run.log.ticks if t > puts[0]), None)
    assert went_on is not None, f"no tick after repair {pid} went unacknowledged: the mission stopped\n{run.tail()}"
    assert went_on - puts[0] <= STARTUP_WAIT_S + ABORT_SLACK_S, \
        f"the fleet held {went_on - puts[0]:.1f} s for robot {deaf}'s ack (at most {STARTUP_WAIT_S:g} s)"
    assert run.code in (0, 3), f"an unacknowledged repair takes the robot out, it does not end the mission: " \
                               f"exit {run.code}\n{run.tail()}"
    assert [e.completed for _, e in run.log.ends] == [True]
    no_harness_trouble(run)
