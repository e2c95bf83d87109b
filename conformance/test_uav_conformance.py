"""UAV conformance: does a UAV (leader) implementation keep the uav-robots protocol?

The suite is router, world and robots at once: a Zenoh router on a free
loopback port, our real world in this process (with its simulated MAVLink
vehicle on a free UDP port) and fake robots that keep the contract or break it
on purpose. It starts the UAV under test from `--uav-cmd` and checks what it
sends. One clean mission is shared by the first group of tests; each failure
case runs a mission of its own. See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import re

import pytest

from conformance.uav_harness import Misbehaviour, MissionRun, error_lines, plan_problem, run_mission
from uav_agent.planning.types import Problem
from uav_agent.planning.validator import validate


RESEND_S = 2.0         # the UAV puts again a plan not acknowledged within this
RESEND_SLACK_S = 1.5   # for the transport and a loaded machine


def _late_robot(opts) -> int:
    return opts.robots - 1


@pytest.fixture(scope="module")
def clean(uav_options, tmp_path_factory) -> MissionRun:
    """A mission with well-behaved robots, one of which comes up only when the UAV is ready to dispatch."""
    run = run_mission(uav_options, Misbehaviour(late=frozenset({_late_robot(uav_options)})),
                      tmp_path_factory.mktemp("clean-mission"))
    print(f"clean mission: exit {run.code} after {run.seconds:.1f} s, {len(run.log.ticks)} ticks")
    return run


def _exited(run: MissionRun, opts) -> None:
    assert run.code is not None, f"the UAV was still running after {opts.mission_timeout_s:g} s\n{run.tail()}"


def _makespan(run: MissionRun) -> int:
    return max(len(p.path) for p in run.first_plans().values()) - 1


def _no_harness_trouble(run: MissionRun) -> None:
    assert not run.log.harness, f"the suite's own robots failed: {run.log.harness[:3]}"


# ---------------------------------------------------------------- a clean mission
def test_uav_token_is_up_before_any_plan_and_gone_after_exit(clean, uav_options):
    _exited(clean, uav_options)
    alive = clean.log.uav_alive
    assert alive and alive[0][1], "no alive/uav liveliness token was ever seen"
    up = alive[0][0]
    assert all(t > up for t, *_ in clean.log.plans), "a plan was sent before alive/uav was declared"
    assert not alive[-1][1], "alive/uav is still declared after the UAV exited"


def test_plans_go_only_to_robots_whose_token_is_up(clean, uav_options):
    _exited(clean, uav_options)
    wrong = clean.log.of("plan-before-token", "plan-unknown")
    assert not wrong, wrong[:3]
    plans = clean.first_plans()
    assert set(plans) == set(clean.truth.starts), \
        f"plans reached robots {sorted(plans)}, the world has robots {sorted(clean.truth.starts)}\n{clean.tail()}"
    late = _late_robot(uav_options)
    first_to_late = min(t for t, rid, *_ in clean.log.plans if rid == late)
    assert first_to_late > clean.log.joined[late]


def test_every_plan_starts_on_the_robots_true_cell_and_ends_on_a_goal(clean, uav_options):
    _exited(clean, uav_options)
    bad = clean.log.of("bad-plan")
    assert not bad, bad[:3]
    plans = clean.first_plans()
    assert plans, f"no plan was sent\n{clean.tail()}"
    for rid, plan in plans.items():
        problem = plan_problem(plan, rid, clean.truth.starts[rid], clean.truth, uav_options.connectivity)
        assert not problem, f"robot {rid}: {problem}"
    goals = sorted(tuple(p.goal) for p in plans.values())
    assert goals == sorted(tuple(g) for g in clean.truth.goals), "the plans do not cover each goal marker once"


def test_the_plans_are_conflict_free(clean, uav_options):
    _exited(clean, uav_options)
    plans = clean.first_plans()
    ids = sorted(plans)
    assert ids, f"no plan was sent\n{clean.tail()}"
    problem = Problem(clean.truth.free, [clean.truth.starts[r] for r in ids], [tuple(plans[r].goal) for r in ids],
                      uav_options.connectivity)
    violations = validate(problem, [[tuple(c) for c in plans[r].path] for r in ids])
    assert violations == [], [v.text for v in violations[:5]]


def test_ticks_start_after_every_ack_and_count_up_by_one(clean, uav_options):
    _exited(clean, uav_options)
    wrong = clean.log.of("tick-order", "tick-before-ack", "tick-plan-id")
    assert not wrong, wrong[:3]
    ticks = [t for _, t in clean.log.ticks]
    makespan = _makespan(clean)
    assert ticks, f"no Tick was sent\n{clean.tail()}"
    assert [t.k for t in ticks] == list(range(1, len(ticks) + 1))
    assert len(ticks) >= makespan, f"{len(ticks)} ticks, but the plans need {makespan}"
    assert {t.ticks for t in ticks} == {makespan}, "Tick.ticks must be the plans' makespan"
    assert len({t.plan_id for t in ticks}) == 1
    last_ack = max(t for t, ack in clean.log.acks)
    assert clean.log.ticks[0][0] > last_ack


def test_the_lockstep_barrier_holds(clean, uav_options):
    _exited(clean, uav_options)
    wrong = clean.log.of("barrier")
    assert not wrong, wrong[:3]
    _no_harness_trouble(clean)


def test_uav_sequence_numbers_increase(clean, uav_options):
    _exited(clean, uav_options)
    tick_seqs = [t.seq for _, t in clean.log.ticks]
    assert all(a < b for a, b in zip(tick_seqs, tick_seqs[1:])), f"Tick seq not increasing: {tick_seqs[:12]}"
    seqs = [s for _, s in clean.log.seqs]
    assert len(seqs) == len(set(seqs)), "two messages from the UAV share a sequence number"


def test_mission_ends_completed_and_the_uav_exits_0(clean, uav_options):
    _exited(clean, uav_options)
    assert clean.code == 0, f"exit code {clean.code}\n{clean.tail()}"
    assert "Traceback" not in clean.stderr + clean.stdout
    ends = clean.log.ends
    assert len(ends) == 1, f"{len(ends)} MissionEnd messages"
    assert ends[0][1].completed is True
    dones = {d.robot: t for t, d in clean.log.dones}
    assert set(dones) == set(clean.truth.starts), "not every robot raised Done: the suite's robots misbehaved"
    assert ends[0][0] > max(dones.values()), "MissionEnd before every robot raised Done"
    assert ends[0][0] > clean.log.ticks[-1][0]
    assert not clean.log.of("after-end", "malformed")


def test_the_world_saw_every_robot_reach_its_goal_without_collision(clean, uav_options):
    _exited(clean, uav_options)
    record = clean.record
    assert record.collisions == 0, record.refused[:3]
    assert record.refused == [], record.refused[:3]
    for rid, plan in clean.first_plans().items():
        assert tuple(record.executed[str(rid)][-1]) == tuple(plan.goal), f"robot {rid} is not on its goal"


def test_the_vehicle_took_off_and_landed(clean, uav_options):
    _exited(clean, uav_options)
    v = clean.vehicle
    assert v is not None
    assert v["max_altitude_m"] > 1.0, f"the vehicle never left the ground: {v['events'][-5:]}"
    assert v["landed_state"] == "ON_GROUND" and not v["armed"], \
        f"the vehicle is {v['landed_state']}, armed {v['armed']} after the UAV exited"


# ---------------------------------------------------------------- robots that fail
def _fails_with_one_line(run: MissionRun, robot: int, opts, since: float) -> None:
    _exited(run, opts)
    assert run.code != 0, f"the UAV exited 0 although robot {robot} failed\n{run.tail()}"
    assert run.exited - since <= opts.abort_s, \
        f"the UAV took {run.exited - since:.1f} s to give up (at most {opts.abort_s:g} s)"
    assert "Traceback" not in run.stderr + run.stdout, run.tail()
    lines = error_lines(run.stderr)
    assert lines, "the UAV failed without a word on stderr"
    assert re.search(rf"\b{robot}\b", lines[-1]), f"the error line does not name robot {robot}: {lines[-1]!r}"
    assert run.log.ends, "no MissionEnd was published"
    assert run.log.ends[-1][1].completed is False, "MissionEnd says completed although a robot failed"
    alive = run.log.uav_alive
    assert alive and not alive[-1][1], "alive/uav is still declared after the UAV exited"
    v = run.vehicle
    if v is not None and v["max_altitude_m"] > 1.0:
        # Safety, not wire format: a leader that gives up must not leave its drone hovering armed.
        assert v["landed_state"] == "ON_GROUND" and not v["armed"], \
            f"after the abort the vehicle is {v['landed_state']}, armed {v['armed']}"


def test_a_refused_plan_ends_the_mission_with_an_error(uav_options, tmp_path):
    victim = min(1, uav_options.robots - 1)
    run = run_mission(uav_options, Misbehaviour(refuse=frozenset({victim})), tmp_path)
    refusals = [t for t, ack in run.log.acks if ack.robot == victim and not ack.ok]
    assert refusals, f"robot {victim} never got a plan to refuse\n{run.tail()}"
    _fails_with_one_line(run, victim, uav_options, refusals[0])
    assert not run.log.ticks, "ticks were sent although a robot refused its plan"
    _no_harness_trouble(run)


def test_a_silent_robot_is_taken_out_of_the_plan(uav_options, tmp_path):
    # It executes its moves but stops reporting from tick 2: the UAV holds at the barrier for the
    # tick deadline, then replans the others from tick 2 without it and finishes, degraded.
    victim = min(1, uav_options.robots - 1)
    run = run_mission(uav_options, Misbehaviour(silent_from={victim: 2}), tmp_path)
    _exited(run, uav_options)
    ticks = [t for _, t in run.log.ticks]
    assert [t.k for t in ticks[:2]] == [1, 2], f"the mission never reached tick 2\n{run.tail()}"
    wrong = run.log.of("barrier", "tick-order", "tick-before-ack", "tick-plan-id")
    assert not wrong, wrong[:3]
    later = [t for t in ticks if t.k > 2]
    assert later and all(t.plan_id != ticks[0].plan_id for t in later), "no new plan after the robot went silent"
    replans = [(rid, p) for _, rid, p, _ in run.log.plans if p.plan_id == later[0].plan_id]
    assert replans and victim not in {rid for rid, _ in replans}, "the silent robot was given the new plan"
    assert all(p.start_tick == 2 for _, p in replans), [p.start_tick for _, p in replans]
    assert run.code == 3, f"a mission finished without robot {victim} must exit 3 (degraded)\n{run.tail()}"
    assert run.record.collisions == 0
    _no_harness_trouble(run)


def test_a_done_the_camera_contradicts_is_no_success(uav_options, tmp_path):
    # It reports every tick as if it followed its plan and raises Done, but never moves: the floor says otherwise.
    liar = uav_options.robots - 1
    run = run_mission(uav_options, Misbehaviour(liar=frozenset({liar})), tmp_path)
    _exited(run, uav_options)
    assert run.code != 0, f"the UAV exited 0 although robot {liar} never left its start\n{run.tail()}"
    assert run.record.collisions == 0
    _no_harness_trouble(run)


@pytest.fixture(scope="module")
def noisy(uav_options, tmp_path_factory) -> MissionRun:
    """A mission in which one robot loses its first plan and puts garbage and forged messages on its keys."""
    rid = uav_options.robots - 1
    return run_mission(uav_options, Misbehaviour(garbage=frozenset({rid}), deaf=frozenset({rid})),
                       tmp_path_factory.mktemp("noisy-mission"))


def test_garbage_on_robot_keys_is_dropped(noisy, uav_options):
    run, rid = noisy, uav_options.robots - 1
    _exited(run, uav_options)
    assert run.code == 0, f"garbage from robot {rid} broke the mission (exit {run.code})\n{run.tail()}"
    assert "Traceback" not in run.stderr + run.stdout
    assert not run.log.violations, run.log.violations[:3]
    assert [e.completed for _, e in run.log.ends] == [True]
    assert len(run.log.ticks) >= _makespan(run)
    dones = {d.robot: t for t, d in run.log.dones}
    assert set(dones) == set(run.truth.starts) and run.log.ends[0][0] > max(dones.values())
    assert run.record.collisions == 0
    _no_harness_trouble(run)


def test_an_unacknowledged_plan_is_resent(noisy, uav_options):
    """docs/protocol.md: the UAV puts a plan again when it is not acknowledged within 2 s."""
    run, rid = noisy, uav_options.robots - 1
    _exited(run, uav_options)
    mine = [(t, p) for t, r, p, up in run.log.plans if r == rid and up]
    assert mine, f"robot {rid} got no plan\n{run.tail()}"
    assert len(mine) >= 2, f"robot {rid} lost its plan and the UAV never put it again\n{run.tail()}"
    (t0, first), (t1, again) = mine[0], mine[1]
    assert t1 - t0 <= RESEND_S + RESEND_SLACK_S, \
        f"the plan was put again after {t1 - t0:.1f} s (at most {RESEND_S:g} s + {RESEND_SLACK_S:g} s)"
    assert (again.plan_id, again.path, tuple(again.goal)) == (first.plan_id, first.path, tuple(first.goal)), \
        "a resent plan must be the same plan (same plan_id and path)"
    assert run.code == 0, f"exit {run.code}\n{run.tail()}"
