"""Robot conformance: executing ticks, the states reported and Done (docs/protocol.md, Plans and ticks).

The suite plays hub, UAV and world around the robot under test, started from
`--robot-cmd` (conftest.py). See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import time

from conformance import Wire
from conformance.robot_steps import MOVE_TIMEOUT_S, QUIET_S, accepted, path_at, run_ticks


def test_ticks_follow_the_plan_and_done_is_raised_once(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (3, 2), (4, 2), (4, 3)]
    accepted(uav, rid, "p-run", path, timeout)
    ticks = len(path) + 1  # two ticks past the plan's end: the robot stays on its goal
    states = run_ticks(uav, world, rid, "p-run", path, ticks, timeout)
    for k, st in enumerate(states, 1):
        reqs = world.requests_for(rid, k)
        assert len(reqs) == 1, f"tick {k}: {len(reqs)} move requests, expected exactly one"
        assert (tuple(reqs[0].frm), tuple(reqs[0].to)) == (path_at(path, k - 1), path_at(path, k)), \
            f"tick {k}: asked {reqs[0].frm} -> {reqs[0].to}"
        assert st.robot == rid and st.tick == k and tuple(st.cell) == path_at(path, k), \
            f"tick {k}: state {st.tick} at {st.cell}, expected {path_at(path, k)}"
    assert uav.until(lambda: len(uav.dones.get(rid, [])) >= 1, timeout), "no Done at the goal"
    time.sleep(QUIET_S)
    dones = uav.dones[rid]
    assert len(dones) == 1, f"Done raised {len(dones)} times"
    assert tuple(dones[0].cell) == path[-1] and dones[0].tick == len(path) - 1
    assert states[-1].status == "done"


def test_refused_move_leaves_the_robot_in_place(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2), (4, 2)]
    world.refuse.add((rid, 2))
    accepted(uav, rid, "p-refused", path, timeout)
    states = run_ticks(uav, world, rid, "p-refused", path, 2, timeout)
    assert tuple(states[1].cell) == (3, 2), "after a refused move the robot must report where it really is"
    time.sleep(QUIET_S)
    assert not uav.dones.get(rid), "Done raised while not on the goal"
    uav.tick(3, 3, "p-refused")
    st3 = uav.state_at(rid, 3, timeout)
    assert st3 is not None and tuple(st3.cell) == (4, 2)
    (req3,) = world.requests_for(rid, 3)
    assert tuple(req3.frm) == (3, 2) and tuple(req3.to) == (4, 2), "the next request must start from the real cell"
    assert uav.until(lambda: len(uav.dones.get(rid, [])) == 1, timeout)


def test_duplicate_and_late_ticks_are_ignored(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    accepted(uav, rid, "p-dup", path, timeout)
    run_ticks(uav, world, rid, "p-dup", path, 2, timeout)
    uav.tick(2, 2, "p-dup")
    uav.tick(1, 2, "p-dup")
    time.sleep(QUIET_S)
    assert len(world.requests_for(rid, 1)) == 1 and len(world.requests_for(rid, 2)) == 1
    assert [s.tick for s in uav.states[rid]] == [1, 2]


def test_states_only_for_executed_ticks(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2), (5, 2)]
    accepted(uav, rid, "p-states", path, timeout)
    time.sleep(QUIET_S)
    assert not uav.states.get(rid), f"states before the first tick: {uav.states.get(rid)}"
    run_ticks(uav, world, rid, "p-states", path, 2, timeout)
    time.sleep(QUIET_S)
    states = uav.states[rid]
    assert [s.tick for s in states] == [1, 2], f"states for ticks {[s.tick for s in states]}, expected [1, 2]"
    assert [s.status for s in states] == ["stepping", "stepping"], [s.status for s in states]


def test_states_name_the_plan_held(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    accepted(uav, rid, "p-named", path, timeout)
    states = run_ticks(uav, world, rid, "p-named", path, 1, timeout)
    accepted(uav, rid, "p-renamed", [(3, 2), (3, 3)], timeout)
    uav.tick(2, 2, "p-renamed")
    st2 = uav.state_at(rid, 2, timeout)
    assert st2 is not None, "no RobotState for tick 2"
    assert [s.plan_id for s in states + [st2]] == ["p-named", "p-renamed"], \
        f"states name plans {[s.plan_id for s in states + [st2]]!r}"


def test_a_tick_for_another_plan_makes_the_robot_stay(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    accepted(uav, rid, "p-mine", path, timeout)
    run_ticks(uav, world, rid, "p-mine", path, 1, timeout)
    uav.tick(2, 2, "p-someone-elses")
    st = uav.state_at(rid, 2, timeout)
    assert st is not None, "no RobotState for a tick naming another plan"
    (req,) = world.requests_for(rid, 2)
    assert tuple(req.frm) == tuple(req.to) == (3, 2), f"a tick for another plan must make it stay: {req.frm} -> {req.to}"
    assert tuple(st.cell) == (3, 2)


def test_a_tick_gap_is_executed_from_where_the_robot_stands(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (3, 2), (4, 2), (4, 3)]
    accepted(uav, rid, "p-gap", path, timeout)
    run_ticks(uav, world, rid, "p-gap", path, 1, timeout)
    uav.tick(3, 4, "p-gap")               # tick 2 was lost
    st = uav.state_at(rid, 3, timeout)
    assert st is not None, "no RobotState for the tick after a gap"
    assert not world.requests_for(rid, 2)
    (req,) = world.requests_for(rid, 3)
    assert (tuple(req.frm), tuple(req.to)) == ((3, 2), (4, 2)), f"tick 3 after a gap: asked {req.frm} -> {req.to}"
    assert tuple(st.cell) == (4, 2)


def test_a_tick_for_another_plan_keeps_the_status(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: a robot that stayed on a tick for another plan keeps the status it had
    (`ready` if it has executed no tick of its plan, `done` on its goal)."""
    accepted(uav, rid, "p-kept", [(2, 2), (3, 2)], timeout)
    uav.tick(1, 1, "p-elses")
    st1 = uav.state_at(rid, 1, timeout)
    assert st1 is not None and st1.status == "ready", f"a stay on another plan's tick before any of its own: {st1}"
    uav.tick(2, 2, "p-kept")
    st2 = uav.state_at(rid, 2, timeout)
    assert st2 is not None and st2.status == "done", f"tick 2 of a two-cell plan: {st2}"
    uav.tick(3, 3, "p-elses")
    st3 = uav.state_at(rid, 3, timeout)
    assert st3 is not None and st3.status == "done", f"a stay on another plan's tick, on its goal: {st3}"


def test_a_refused_move_is_no_error_and_carries_the_worlds_reason(robot, uav, world, rid, timeout):
    """docs/protocol.md, Robot status and Plans and ticks: `status: "error"` only when the world gave no
    answer; a refused move's state has its status after the tick and the world's reason in `error`."""
    path = [(2, 2), (3, 2), (4, 2)]
    world.refuse.update({(rid, 2), (rid, 4)})
    accepted(uav, rid, "p-why", path, timeout)
    states = run_ticks(uav, world, rid, "p-why", path, 4, timeout)   # refused at 2, arrives at 3, refused at 4
    for k in (2, 4):
        st = states[k - 1]
        assert st.status != "error", f"tick {k}: a refused move is no error: {st}"
        assert "refused by the conformance world" in st.error, f"tick {k}: the world's reason belongs in `error`: {st}"
    assert states[1].status == "stepping" and tuple(states[1].cell) == (3, 2), f"tick 2: {states[1]}"
    assert states[3].status == "done" and tuple(states[3].cell) == (4, 2), \
        f"tick 4, its stay on its goal refused: still done there: {states[3]}"


def test_after_an_error_tick_the_robot_goes_on_from_its_last_known_cell(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: `error` is the status of that tick's state only; an error tick counts
    as executed: Tick(k) resent is ignored, Tick(k+1) is asked from the last known cell."""
    world.answer = False
    path = [(2, 2), (3, 2), (4, 2), (5, 2)]
    accepted(uav, rid, "p-err", path, timeout)
    uav.tick(1, 2, "p-err")
    st1 = uav.state_at(rid, 1, max(timeout, MOVE_TIMEOUT_S + 1.0))
    assert st1 is not None and st1.status == "error", f"no error state for tick 1: {st1}"
    world.answer = True
    uav.tick(1, 2, "p-err")
    time.sleep(QUIET_S)
    assert len(world.requests_for(rid, 1)) == 1, "an error tick counts as executed: Tick(1) resent is ignored"
    assert [s.tick for s in uav.states[rid]] == [1], f"states {[s.tick for s in uav.states[rid]]}"
    uav.tick(2, 2, "p-err")
    st2 = uav.state_at(rid, 2, timeout)
    assert st2 is not None, "no RobotState for tick 2"
    (req,) = world.requests_for(rid, 2)
    assert (tuple(req.frm), tuple(req.to)) == ((2, 2), (4, 2)), f"tick 2: asked {req.frm} -> {req.to}"
    assert st2.status == "stepping", f"`error` was tick 1's status only; tick 2 carries its own again: {st2}"


def test_pushed_off_its_goal_it_is_stepping_again(robot, uav, world, rid, timeout):
    """docs/protocol.md, Robot status: `stepping` also after being pushed off its goal; `done` on it."""
    path = [(2, 2), (3, 2)]
    accepted(uav, rid, "p-push", path, timeout)
    run_ticks(uav, world, rid, "p-push", path, 1, timeout)
    assert uav.until(lambda: len(uav.dones.get(rid, [])) == 1, timeout), "no Done at the goal"
    world.refuse.add((rid, 2))
    with world.cv:
        world.positions[rid] = (3, 3)    # pushed: the world answers tick 2 with the cell it stands on
    uav.tick(2, 2, "p-push")
    st2 = uav.state_at(rid, 2, timeout)
    assert st2 is not None and tuple(st2.cell) == (3, 3) and st2.status == "stepping", \
        f"pushed off its goal: stepping at (3, 3), got {st2}"
    uav.tick(3, 3, "p-push")
    st3 = uav.state_at(rid, 3, timeout)
    assert st3 is not None and tuple(st3.cell) == (3, 2) and st3.status == "done", f"back on its goal: {st3}"
    time.sleep(QUIET_S)
    assert len(uav.dones[rid]) == 1, f"one Done per plan: {uav.dones[rid]}"


def test_done_follows_the_state_of_its_tick(robot, hub, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: Done once, right after the state of the first tick at which the plan
    is over and the robot stands on its goal, naming that tick."""
    wire = Wire(hub)
    try:
        path = [(2, 2), (3, 2)]
        accepted(uav, rid, "p-order", path, timeout)
        run_ticks(uav, world, rid, "p-order", path, 1, timeout)
        assert uav.until(lambda: bool(uav.dones.get(rid)), timeout), "no Done at the goal"
        wire.until(lambda: wire.count(uav.keys.done(rid)) >= 1, timeout)   # its own subscriber, maybe later
        order = wire.order()
    finally:
        wire.close()
    state, done = (uav.keys.state(rid), 1), (uav.keys.done(rid), 1)
    assert done in order, f"no Done naming tick 1 among {order}"
    assert state in order and order.index(state) < order.index(done), f"Done came before the state of tick 1: {order}"


def test_a_one_cell_plan_is_done_at_its_first_tick(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: for a one-cell plan, Done at its first tick, never at the ack."""
    accepted(uav, rid, "p-here", [(2, 2)], timeout)
    time.sleep(QUIET_S)
    assert not uav.dones.get(rid), f"Done at the acknowledgement: {uav.dones.get(rid)}"
    uav.tick(1, 0, "p-here")
    st = uav.state_at(rid, 1, timeout)
    assert st is not None and st.status == "done", f"tick 1 of a one-cell plan: {st}"
    assert uav.until(lambda: bool(uav.dones.get(rid)), timeout), "no Done at tick 1"
    assert uav.dones[rid][0].tick == 1, f"Done names tick {uav.dones[rid][0].tick}, expected 1"


def test_no_done_on_a_tick_naming_another_plan(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: never a Done on a tick that names another plan."""
    accepted(uav, rid, "p-mine", [(2, 2)], timeout)
    uav.tick(1, 1, "p-elses")
    assert uav.state_at(rid, 1, timeout) is not None, "no RobotState for a tick naming another plan"
    time.sleep(QUIET_S)
    assert not uav.dones.get(rid), f"Done on a tick naming another plan: {uav.dones.get(rid)}"
    uav.tick(2, 2, "p-mine")
    assert uav.until(lambda: bool(uav.dones.get(rid)), timeout), "no Done on its own plan's tick"
    assert uav.dones[rid][0].tick == 2


def test_done_once_per_plan_and_again_for_a_new_one(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: a plan resent under the id the robot holds raises no second Done;
    a plan with a new id does."""
    path = [(2, 2), (3, 2)]
    accepted(uav, rid, "p-once", path, timeout)
    run_ticks(uav, world, rid, "p-once", path, 1, timeout)
    assert uav.until(lambda: len(uav.dones.get(rid, [])) == 1, timeout), "no Done at the goal"
    uav.plan(rid, "p-once", path)
    assert len(uav.acks_for(rid, "p-once", 2, timeout)) == 2, "the resent plan was not acknowledged again"
    uav.tick(2, 2, "p-once")
    assert uav.state_at(rid, 2, timeout) is not None
    time.sleep(QUIET_S)
    assert len(uav.dones[rid]) == 1, f"a resent plan raised another Done: {uav.dones[rid]}"
    accepted(uav, rid, "p-again", [(3, 2)], timeout)
    uav.tick(3, 3, "p-again")
    assert uav.until(lambda: len(uav.dones.get(rid, [])) == 2, timeout), "no Done for a plan with a new id"
    assert uav.dones[rid][1].tick == 3
