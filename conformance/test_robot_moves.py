"""Robot conformance: asking the world for moves, and what a robot makes of the answers (docs/protocol.md, QoS).

The suite plays hub, UAV and world around the robot under test, started from
`--robot-cmd` (conftest.py). See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import dataclasses
import time

import pytest

from conformance.robot_steps import MOVE_TIMEOUT_S, QUIET_S, accepted, run_ticks


def test_moves_are_asked_on_the_key_naming_the_robot(robot, hub, uav, world, rid, timeout):
    """docs/protocol.md, Keys and Security: `P/world/move/<ids>`, not the plain `P/world/move` that
    access control leaves unreachable (an independent robot asking there passed every other test)."""
    path = [(2, 2), (3, 2), (3, 3)]
    accepted(uav, rid, "p-key", path, timeout)
    run_ticks(uav, world, rid, "p-key", path, 2, timeout)
    with world.cv:
        keys = [key for key, robots in world.move_keys if rid in robots]
    assert len(keys) == 2 and set(keys) == {hub.keys.move_as([rid])}, \
        f"moves asked on {sorted(set(keys))}, expected {hub.keys.move_as([rid])}"


def test_a_robot_without_a_plan_asks_nothing(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: a robot that holds no plan does not know its cell: it asks nothing and
    publishes no state for that tick."""
    uav.tick(1, 2, "p-not-yours")
    uav.tick(2, 2, "p-not-yours")
    time.sleep(QUIET_S)
    assert not world.requests_for(rid, 1) and not world.requests_for(rid, 2), "a robot without a plan asked a move"
    assert not uav.states.get(rid), f"a robot without a plan reported {uav.states.get(rid)}"
    assert robot.poll() is None


@pytest.mark.parametrize("answer", ["none", "garbage"])
def test_no_answer_from_the_world_is_an_error_state(robot, uav, world, rid, timeout, answer):
    """docs/protocol.md: a robot treats a garbage move result as no answer."""
    world.answer, world.garbage = answer != "none", answer == "garbage"
    path = [(2, 2), (3, 2)]
    accepted(uav, rid, "p-silent-world", path, timeout)
    uav.tick(1, 1, "p-silent-world")
    st = uav.state_at(rid, 1, max(timeout, MOVE_TIMEOUT_S + 1.0))   # the robot may wait its move timeout
    assert st is not None, "no RobotState when the world did not answer the move"
    assert st.status == "error" and st.error, f"status {st.status!r} error {st.error!r}"
    assert tuple(st.cell) == (2, 2), f"an error state must name the last known cell (2, 2), not {st.cell}"
    time.sleep(QUIET_S)
    asked = len(world.requests_for(rid, 1))
    assert asked == 1, f"the robot asked {asked} times for tick 1: a robot does not ask twice for a tick"


def test_a_late_answer_within_the_move_timeout_is_taken(robot, uav, world, rid, timeout):
    """docs/protocol.md, QoS: a robot waits 5 s for the world's answer to a move (the world may take its 2 s
    batch timeout and more): an answer after 3 s is an answer, not an error."""
    world.delay_s = 3.0
    path = [(2, 2), (3, 2)]
    accepted(uav, rid, "p-late", path, timeout)
    uav.tick(1, 1, "p-late")
    st = uav.state_at(rid, 1, max(timeout, MOVE_TIMEOUT_S + 2.0))
    assert st is not None, "no RobotState for tick 1"
    assert st.status != "error" and tuple(st.cell) == (3, 2), \
        f"the world answered after 3 s, within the 5 s move timeout, but the robot reported {st}"


def test_a_query_that_ends_without_a_reply_is_no_answer_at_once(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: a query that ends without a reply (no world serves the key) is no
    answer at once, without waiting out the move timeout."""
    world.answer = False   # the fake world finishes the query at once, without a reply
    accepted(uav, rid, "p-ended", [(2, 2), (3, 2)], timeout)
    t0 = time.monotonic()
    uav.tick(1, 1, "p-ended")
    st = uav.state_at(rid, 1, MOVE_TIMEOUT_S + 2.0)
    took = time.monotonic() - t0
    assert st is not None and st.status == "error", f"no error state for a query that ended without a reply: {st}"
    assert took < MOVE_TIMEOUT_S - 2.0, f"the error state came {took:.1f} s after the tick: the query had " \
                                        "ended without a reply at once, nothing was left to wait for"


@pytest.mark.parametrize("other", ["tick", "robot"])
def test_an_answer_for_another_tick_or_robot_is_no_answer(robot, uav, world, rid, timeout, other):
    """docs/protocol.md, Plans and ticks: a reply for another robot or tick is no answer (dropped and counted)."""
    world.reply_with = lambda res: dataclasses.replace(res, **{other: getattr(res, other) + 1})
    accepted(uav, rid, f"p-other-{other}", [(2, 2), (3, 2)], timeout)
    uav.tick(1, 1, f"p-other-{other}")
    st = uav.state_at(rid, 1, max(timeout, MOVE_TIMEOUT_S + 1.0))
    assert st is not None, "no RobotState when the only reply was for another " + other
    assert st.status == "error" and tuple(st.cell) == (2, 2), \
        f"the only reply named another {other}: no answer, an error state at (2, 2); got {st}"
