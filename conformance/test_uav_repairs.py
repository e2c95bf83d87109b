"""UAV conformance: faults the UAV repairs, and a degraded fleet (docs/protocol.md, Faults and recovery).

The suite plays router, world and robots around the UAV under test, started from
`--uav-cmd` (conftest.py); a mission is shared by the tests of one module. See
docs/protocol.md, "Conformance", and docs/conformance-rules.md.
"""
from __future__ import annotations

import dataclasses

import pytest

from conformance.uav_checks import can_reach_a_goal, cells_at, plan_problems
from conformance.uav_harness import Misbehaviour, MissionRun, run_mission
from conformance.uav_steps import ends, exited, fault, no_harness_trouble, ticks_after


FAULT_ROBOTS = 5       # robots in the missions with faults: room for several at once
MAX_TRIES = 5          # plans that may name a robot that keeps failing: its first, a repair per strike, slack


def _fleet(opts, robots: int):
    return dataclasses.replace(opts, robots=max(opts.robots, robots))


def _plan_at(run: MissionRun, k: int) -> str:
    """The plan_id of Tick(k)."""
    return next(t.plan_id for _, t in run.log.ticks if t.k == k)


def _repair_after(run: MissionRun, k: int, what: str):
    """The plan the UAV switched to right after tick k (the first Tick after k names it), and its plans by robot."""
    later = ticks_after(run, k)
    assert later, f"no tick after tick {k}, when {what}\n{run.tail()}"
    assert later[0].plan_id != _plan_at(run, k), \
        f"Tick {later[0].k} still names plan {later[0].plan_id} after tick {k}, when {what}: the fleet was not held"
    plans = run.plans_by_id().get(later[0].plan_id, {})
    assert plans, f"Tick {later[0].k} names plan {later[0].plan_id}, which no robot was sent"
    return later[0].plan_id, plans


def _kept_the_contract(run: MissionRun) -> set[int]:
    return set(range(run.robots)) - {r for _, r, *_ in run.log.faults}


@pytest.fixture(scope="module")
def faults(uav_options, tmp_path_factory) -> MissionRun:
    """Five robots: 0 cannot execute tick 2 (an error state), 1 stays once where its plan moves it (from
    tick 4), 2 freezes for a tick (from tick 6: the UAV's tick deadline passes) and comes back; 3 and 4
    keep the contract. Each fault comes at least three ticks after the last."""
    opts = _fleet(uav_options, FAULT_ROBOTS)
    run = run_mission(opts, Misbehaviour(error_at={0: 2}, deviate_at={1: 4}, stall={2: (6, 1)}),
                      tmp_path_factory.mktemp("faults-mission"))
    print(f"faults mission: exit {run.code} after {run.seconds:.1f} s, {len(run.log.ticks)} ticks, "
          f"faults {[(k, r, t) for k, r, t, _ in run.log.faults]}")
    return run


@pytest.fixture(scope="module")
def degraded(uav_options, tmp_path_factory) -> MissionRun:
    """Five robots: 1 vanishes after its state of tick 2 (its token gone before the others report that tick),
    0 as tick 4 arrives (before the others ask their moves); 3 never moves from tick 6 on (it reports where
    it really stands). The rest must finish."""
    opts = _fleet(uav_options, FAULT_ROBOTS)
    run = run_mission(opts, Misbehaviour(lost_at={1: 2}, vanish_at={0: 4}, stuck_from={3: 6}),
                      tmp_path_factory.mktemp("degraded"))
    print(f"degraded mission: exit {run.code} after {run.seconds:.1f} s, {len(run.log.ticks)} ticks, "
          f"{len(run.plans_by_id())} plans")
    return run


def test_every_repair_plan_is_executable_and_reaches_every_working_robot(faults, uav_options):
    run = faults
    exited(run, uav_options)
    plans = run.plans_by_id()
    assert len(plans) >= 2, f"no repair in a mission with faults\n{run.tail()}"
    innocent = _kept_the_contract(run)
    for pid, mine in plans.items():
        start = next(iter(mine.values())).start_tick
        problems = plan_problems(mine, start, run.truth, run.record, uav_options.connectivity)
        assert not problems, f"plan {pid} from tick {start}: {problems[:4]}"
        where = cells_at(run.record, start)
        walls = {c for r, c in where.items() if r not in mine}
        left_out = [r for r in sorted(innocent - set(mine))
                    if can_reach_a_goal(run.truth, where[r], walls, run.truth.goals)]
        assert not left_out, f"plan {pid} from tick {start} leaves out robots {left_out}, which kept the contract"
    assert run.record.collisions == 0, run.record.refused[:3]
    no_harness_trouble(run)


def test_a_robot_in_error_is_taken_out_of_the_plan(faults, uav_options):
    run = faults
    exited(run, uav_options)
    _, rid, k, _ = fault(run, "error", 0)
    pid, plans = _repair_after(run, k, f"robot {rid} reported an error at tick {k}")
    assert rid not in plans, f"robot {rid}, in error at tick {k}, was given plan {pid} from that tick"
    assert {p.start_tick for p in plans.values()} == {k}, f"plan {pid} starts at {[p.start_tick for p in plans.values()]}"


def test_a_deviation_is_repaired_from_where_the_robot_stands(faults, uav_options):
    run = faults
    exited(run, uav_options)
    _, rid, k, _ = fault(run, "deviation", 1)
    pid, plans = _repair_after(run, k, f"robot {rid} reported a cell off its plan at tick {k}")
    assert rid in plans, f"robot {rid}, which deviated at tick {k}, got no plan of the repair {pid}"
    stood = cells_at(run.record, k)[rid]
    assert plans[rid].start_tick == k and tuple(plans[rid].path[0]) == stood, \
        f"robot {rid}'s repair starts at tick {plans[rid].start_tick} on {tuple(plans[rid].path[0])}; it stood on " \
        f"{stood} after tick {k}"


def test_a_stalled_robot_that_comes_back_rejoins(faults, uav_options):
    run = faults
    exited(run, uav_options)
    _, rid, k, _ = fault(run, "stall", 2)
    pid, plans = _repair_after(run, k, f"robot {rid} stalled at tick {k}")
    assert rid not in plans, f"robot {rid}, stalled at tick {k}, was given plan {pid} from that tick"
    again = [p for t, r, p, _ in run.log.plans if r == rid and p.start_tick > k]
    assert again, f"robot {rid} came back after its stall and never got a plan again\n{run.tail()}"
    assert run.code == 0 and [e.completed for _, e in run.log.ends] == [True], \
        f"every robot came back: the mission must complete (exit 0), not {run.code}\n{run.tail()}"
    for rid_, plan in run.plans_by_id()[_plan_at(run, run.log.ticks[-1][1].k)].items():
        assert tuple(run.record.executed[str(rid_)][-1]) == tuple(plan.goal), f"robot {rid_} is not on its goal"


def test_each_fault_is_an_event_as_it_happens(faults, uav_options):
    run = faults
    exited(run, uav_options)
    for kind, rid, k, at in run.log.faults:
        later = ticks_after(run, k)
        before = next((t for t, tick in run.log.ticks if tick.k > k), ends(run))
        named = [e for t, e in run.log.events if rid in e.robots and at <= t <= before]
        assert named, f"no MissionEvent named robot {rid} between its {kind} at tick {k} and the next tick " \
                      f"({later[0].k if later else 'none'})"


def test_a_lost_robot_is_taken_out_at_once(degraded, uav_options):
    run = degraded
    exited(run, uav_options)
    _, rid, k, _ = fault(run, "lost", 1)
    pid, plans = _repair_after(run, k, f"robot {rid}'s token vanished after tick {k}")
    assert rid not in plans, f"robot {rid}, lost after tick {k}, was given plan {pid}"
    assert {p.start_tick for p in plans.values()} == {k}, f"plan {pid} starts at {[p.start_tick for p in plans.values()]}"
    late = [p.plan_id for _, r, p, _ in run.log.plans if r == rid and p.start_tick >= k]
    assert not late, f"robot {rid}, whose token is gone, was sent plans {late[:3]}"


def test_a_robot_that_keeps_failing_is_quarantined_and_the_rest_finish(degraded, uav_options):
    run, stuck = degraded, 3
    exited(run, uav_options)
    fault(run, "stuck", stuck)
    tries = [pid for pid, mine in run.plans_by_id().items() if stuck in mine]
    assert len(tries) <= MAX_TRIES, f"robot {stuck} never moves and was given {len(tries)} plans"
    last = _plan_at(run, run.log.ticks[-1][1].k)
    assert stuck not in run.plans_by_id()[last], f"robot {stuck}, which never moves, is in the last plan"
    assert run.code == 3, f"a mission finished without robots 0, 1 and {stuck} must exit 3 (degraded)\n{run.tail()}"
    assert [e.completed for _, e in run.log.ends] == [True], \
        "MissionEnd must say completed: every robot still working is verified"
    for rid, plan in run.plans_by_id()[last].items():
        assert tuple(run.record.executed[str(rid)][-1]) == tuple(plan.goal), f"robot {rid} is not on its goal"
    assert run.record.collisions == 0, run.record.refused[:3]
    no_harness_trouble(run)


def test_images_during_execution_are_taken_while_the_fleet_holds(degraded, uav_options):
    """docs/protocol.md, Monitoring and Faults: an image is taken at a tick boundary while the fleet holds, the
    robots still working having finished the tick (robot 0 vanished as tick 4 arrived, the others asked 1 s later)."""
    run = degraded
    exited(run, uav_options)
    fault(run, "vanished", 0)
    begun, end = run.log.ticks[0][0], ends(run)
    during = [s for s in run.shutters if begun < s.at < end]
    assert during, f"the UAV took no image during execution, not even for a repair\n{run.tail()}"
    moving = [s for s in during if not s.settled]
    assert not moving, (f"{len(moving)} of {len(during)} images during execution were taken while robots moved: "
                        f"e.g. the world had heard Tick {moving[0].heard} and judged tick {moving[0].judged}")
