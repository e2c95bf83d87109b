"""Robot conformance: taking plans, what a robot acknowledges and what it refuses (docs/protocol.md, Plans and ticks).

The suite plays hub, UAV and world around the robot under test, started from
`--robot-cmd` (conftest.py). See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import time

import pytest

from conformance.robot_steps import QUIET_S, accepted, path_at, run_ticks


def test_valid_plan_is_acknowledged(robot, uav, rid, timeout):
    ack = accepted(uav, rid, "p-valid", [(2, 2), (3, 2), (3, 3)], timeout)
    assert ack.robot == rid and ack.plan_id == "p-valid" and ack.error == ""


MALFORMED = {  # docs/protocol.md, Plans and ticks: what a robot refuses with ok: false and a one-line error
    "jump": dict(path=[(2, 2), (4, 2)]),
    "diagonal-under-4": dict(path=[(2, 2), (3, 3)], connectivity=4),
    "diagonal-unstated": dict(path=[(2, 2), (3, 3)]),     # the robot's own connectivity: 4 unless started with 8
    "goal": dict(path=[(2, 2), (3, 2)], goal=(5, 5)),
    "empty": dict(path=[], goal=(2, 2)),
    "other-robot": dict(path=[(2, 2), (3, 2)], for_robot="next"),
}


@pytest.mark.parametrize("case", list(MALFORMED))
def test_a_malformed_plan_is_refused(robot, uav, rid, timeout, case):
    kw = dict(MALFORMED[case])
    if kw.get("for_robot") == "next":
        kw["for_robot"] = rid + 1
    pid = f"p-{case}"
    uav.plan(rid, pid, **kw)
    ack = uav.ack_for(rid, pid, timeout)
    assert ack is not None, f"no PlanAck for malformed plan {pid}"
    assert not ack.ok, f"malformed plan {pid} was accepted"
    assert ack.error and "\n" not in ack.error, f"a refusal needs a one-line error, got {ack.error!r}"
    assert ack.robot == rid
    accepted(uav, rid, "p-good", [(2, 2), (3, 2)], timeout)
    assert robot.poll() is None


def test_a_plan_not_starting_where_the_robot_stands_is_refused(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    accepted(uav, rid, "p-first", path, timeout)
    run_ticks(uav, world, rid, "p-first", path, 1, timeout)         # it stands on (3, 2)
    uav.plan(rid, "p-elsewhere", [(6, 6), (6, 7)])
    ack = uav.ack_for(rid, "p-elsewhere", timeout)
    assert ack is not None, "no PlanAck for a plan that starts elsewhere"
    assert not ack.ok, "a plan that does not start where the robot stands was accepted"
    accepted(uav, rid, "p-from-here", [(3, 2), (3, 3)], timeout)   # a replan from here is fine
    uav.tick(2, 2, "p-from-here")
    assert uav.state_at(rid, 2, timeout) is not None
    (req,) = world.requests_for(rid, 2)
    assert (tuple(req.frm), tuple(req.to)) == ((3, 2), (3, 3)), f"tick 2: asked {req.frm} -> {req.to}"


def test_diagonal_steps_are_moves_when_the_plan_says_8(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 3), (4, 4), (4, 4)]
    uav.plan(rid, "p-diagonal", path, connectivity=8)
    ack = uav.ack_for(rid, "p-diagonal", timeout)
    assert ack is not None, "no PlanAck for an 8-connected plan"
    assert ack.ok, f"a plan with connectivity 8 and diagonal steps was refused: {ack.error}"
    states = run_ticks(uav, world, rid, "p-diagonal", path, 2, timeout)
    for k, st in enumerate(states, 1):
        (req,) = world.requests_for(rid, k)
        assert (tuple(req.frm), tuple(req.to)) == (path[k - 1], path[k]), f"tick {k}: asked {req.frm} -> {req.to}"
        assert tuple(st.cell) == path[k]


def test_a_resent_plan_is_acknowledged_again(robot, uav, rid, timeout):
    path = [(2, 2), (3, 2)]
    accepted(uav, rid, "p-resent", path, timeout)
    uav.plan(rid, "p-resent", path)      # the UAV heard no ack within 2 s and puts it again
    acks = uav.acks_for(rid, "p-resent", 2, timeout)
    assert len(acks) == 2, "a plan resent with the same plan_id was not acknowledged again"
    assert acks[1].ok, f"a resent plan was refused: {acks[1].error}"


def test_another_path_under_the_same_plan_id_is_refused(robot, uav, world, rid, timeout):
    first = [(2, 2), (3, 2)]
    accepted(uav, rid, "p-same", first, timeout)
    uav.plan(rid, "p-same", [(2, 2), (2, 3)])
    acks = uav.acks_for(rid, "p-same", 2, timeout)
    assert len(acks) == 2, "no PlanAck for another path under a plan_id already held"
    assert not acks[1].ok and acks[1].error, "another path under the same plan_id was accepted"
    run_ticks(uav, world, rid, "p-same", first, 1, timeout)
    (req,) = world.requests_for(rid, 1)
    assert tuple(req.to) == (3, 2), "the robot left the plan it had acknowledged"


def test_a_repair_plan_starts_at_its_tick_and_is_switched_to_at_once(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks / Faults and recovery: path[i] is the cell at tick start_tick + i;
    a repair plan (start_tick > 0) names where the robot stands, whatever the robot believed."""
    first = [(2, 2), (3, 2), (4, 2), (5, 2), (6, 2)]
    accepted(uav, rid, "p-first", first, timeout)
    run_ticks(uav, world, rid, "p-first", first, 2, timeout)          # now at (4, 2) after tick 2
    with world.cv:
        world.positions[rid] = (4, 3)       # it slipped: the UAV's camera sees it one cell off
    repair = [(4, 3), (4, 4), (5, 4)]
    uav.plan(rid, "p-repair", repair, start_tick=2)
    ack = uav.ack_for(rid, "p-repair", timeout)
    assert ack is not None and ack.ok, f"a repair plan from where the UAV sees the robot was refused: {ack}"
    for k in (3, 4, 5):
        uav.tick(k, 4, "p-repair")
        st = uav.state_at(rid, k, timeout)
        assert st is not None, f"no RobotState for tick {k}"
        (req,) = world.requests_for(rid, k)
        want = (path_at(repair, k - 3), path_at(repair, k - 2))
        assert (tuple(req.frm), tuple(req.to)) == want, f"tick {k}: asked {req.frm} -> {req.to}, expected {want}"
        assert st.plan_id == "p-repair"


def test_a_repair_plan_for_a_past_tick_is_refused(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    accepted(uav, rid, "p-now", path, timeout)
    run_ticks(uav, world, rid, "p-now", path, 3, timeout)
    uav.plan(rid, "p-past", [(4, 2), (4, 3)], start_tick=1)
    ack = uav.ack_for(rid, "p-past", timeout)
    assert ack is not None and not ack.ok, "a plan starting before the last executed tick was accepted"


def test_a_plan_counts_from_the_highest_tick_seen(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: without `start_tick`, `path[i]` is the cell at tick b + i, b the
    highest tick the robot has seen, ticks heard while it held no plan included."""
    for k in (1, 2, 3):
        uav.tick(k, 3, "p-before-it")
    time.sleep(QUIET_S)
    path = [(2, 2), (3, 2), (4, 2)]
    accepted(uav, rid, "p-late-join", path, timeout)
    uav.tick(4, 5, "p-late-join")
    assert uav.state_at(rid, 4, timeout) is not None, "no RobotState for tick 4"
    (req,) = world.requests_for(rid, 4)
    assert (tuple(req.frm), tuple(req.to)) == ((2, 2), (3, 2)), \
        f"tick 4, the first after a plan taken at tick 3: asked {req.frm} -> {req.to}, expected path[0] -> path[1]"


def test_a_second_plan_before_tick_1_may_start_anywhere(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: until the world's first answer the robot does not know where it
    stands, so it accepts any path[0], a second plan before tick 1 included."""
    accepted(uav, rid, "p-one", [(2, 2), (3, 2)], timeout)
    uav.plan(rid, "p-two", [(5, 5), (5, 6)])
    ack = uav.ack_for(rid, "p-two", timeout)
    assert ack is not None and ack.ok, f"a second plan before tick 1, starting elsewhere, was refused: {ack}"
    uav.tick(1, 1, "p-two")
    assert uav.state_at(rid, 1, timeout) is not None, "no RobotState for tick 1"
    (req,) = world.requests_for(rid, 1)
    assert (tuple(req.frm), tuple(req.to)) == ((5, 5), (5, 6)), f"tick 1: asked {req.frm} -> {req.to}"


def test_a_plan_id_held_before_is_a_new_plan(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: an id the robot held before is not remembered."""
    accepted(uav, rid, "p-a", [(2, 2), (3, 2)], timeout)
    run_ticks(uav, world, rid, "p-a", [(2, 2), (3, 2)], 1, timeout)            # at (3, 2)
    accepted(uav, rid, "p-b", [(3, 2), (3, 3)], timeout)
    uav.tick(2, 2, "p-b")
    assert uav.state_at(rid, 2, timeout) is not None, "no RobotState for tick 2"   # at (3, 3)
    uav.plan(rid, "p-a", [(3, 3), (4, 3)])
    acks = uav.acks_for(rid, "p-a", 2, timeout)
    assert len(acks) == 2 and acks[1].ok, f"p-a again, from where the robot stands, is a new plan: {acks[1:]}"
    uav.tick(3, 3, "p-a")
    assert uav.state_at(rid, 3, timeout) is not None, "no RobotState for tick 3"
    (req,) = world.requests_for(rid, 3)
    assert (tuple(req.frm), tuple(req.to)) == ((3, 3), (4, 3)), f"tick 3: asked {req.frm} -> {req.to}"


def test_every_plan_ack_states_the_protocol_it_keeps(robot, uav, robot_protocol, rid, timeout):
    """docs/protocol.md, Versioning: every PlanAck states `protocol`, the version of this document's rules the
    robot keeps (2; none stated means 1)."""
    uav.plan(rid, "p-version-bad", [(2, 2), (4, 2)])
    assert uav.ack_for(rid, "p-version-bad", timeout) is not None, "no PlanAck for a malformed plan"
    accepted(uav, rid, "p-version", [(2, 2), (3, 2)], timeout)
    stated = sorted({a.protocol for a in uav.acks[rid]})
    assert stated == [robot_protocol], f"its PlanAcks state protocol {stated}, expected {robot_protocol} in every one"
