"""UAV conformance: a clean mission, kept to the letter (docs/protocol.md, Startup order, Plans and ticks).

The suite plays router, world and robots around the UAV under test, started from
`--uav-cmd` (conftest.py); a mission is shared by the tests of one module. See
docs/protocol.md, "Conformance", and docs/conformance-rules.md.
"""
from __future__ import annotations

import pytest

from conformance.uav_checks import frame_problems, phase_problems, plan_problems, pose_problems
from conformance.uav_harness import Misbehaviour, MissionRun, plan_problem, run_mission
from conformance.uav_steps import ends, exited, makespan_of, no_harness_trouble


def _late_robot(opts) -> int:
    return opts.robots - 1


@pytest.fixture(scope="module")
def clean(uav_options, tmp_path_factory) -> MissionRun:
    """A mission with well-behaved robots, one of which comes up only when the UAV is ready to dispatch."""
    run = run_mission(uav_options, Misbehaviour(late=frozenset({_late_robot(uav_options)})),
                      tmp_path_factory.mktemp("clean-mission"))
    print(f"clean mission: exit {run.code} after {run.seconds:.1f} s, {len(run.log.ticks)} ticks")
    return run


def test_uav_token_is_up_before_any_plan_and_gone_after_exit(clean, uav_options):
    exited(clean, uav_options)
    alive = clean.log.uav_alive
    assert alive and alive[0][1], "no alive/uav liveliness token was ever seen"
    up = alive[0][0]
    assert all(t > up for t, *_ in clean.log.plans), "a plan was sent before alive/uav was declared"
    assert not alive[-1][1], "alive/uav is still declared after the UAV exited"


def test_the_uav_token_stays_up_for_the_whole_mission(clean, uav_options):
    """A robot exits when alive/uav disappears (R33): a flicker mid-mission ends the fleet."""
    exited(clean, uav_options)
    changes = [alive for _, alive in clean.log.uav_alive]
    assert changes[:1] == [True], "no alive/uav liveliness token was ever seen"
    assert changes == [True, False], f"alive/uav went {changes}: it must stay up from before the plans to the end"
    assert not clean.log.ends or clean.log.uav_alive[-1][0] >= clean.log.ends[0][0], \
        "alive/uav was withdrawn before MissionEnd"


def test_plans_go_only_to_robots_whose_token_is_up(clean, uav_options):
    exited(clean, uav_options)
    wrong = clean.log.of("plan-before-token", "plan-unknown")
    assert not wrong, wrong[:3]
    plans = clean.first_plans()
    assert set(plans) == set(clean.truth.starts), \
        f"plans reached robots {sorted(plans)}, the world has robots {sorted(clean.truth.starts)}\n{clean.tail()}"
    late = _late_robot(uav_options)
    first_to_late = min(t for t, rid, *_ in clean.log.plans if rid == late)
    assert first_to_late > clean.log.joined[late]


def test_every_plan_starts_on_the_robots_true_cell_and_ends_on_a_goal(clean, uav_options):
    exited(clean, uav_options)
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
    exited(clean, uav_options)
    plans = clean.first_plans()
    assert plans, f"no plan was sent\n{clean.tail()}"
    problems = plan_problems(plans, 0, clean.truth, clean.record, uav_options.connectivity)
    assert problems == [], problems[:5]


def test_ticks_start_after_every_ack_and_count_up_by_one(clean, uav_options):
    exited(clean, uav_options)
    wrong = clean.log.of("tick-order", "tick-before-ack", "tick-plan-id")
    assert not wrong, wrong[:3]
    ticks = [t for _, t in clean.log.ticks]
    makespan = makespan_of(clean)
    assert ticks, f"no Tick was sent\n{clean.tail()}"
    assert [t.k for t in ticks] == list(range(1, len(ticks) + 1))
    assert len(ticks) >= makespan, f"{len(ticks)} ticks, but the plans need {makespan}"
    assert {t.ticks for t in ticks} == {makespan}, "Tick.ticks must be the plans' makespan"
    assert len({t.plan_id for t in ticks}) == 1
    last_ack = max(t for t, ack in clean.log.acks)
    assert clean.log.ticks[0][0] > last_ack


def test_the_lockstep_barrier_holds(clean, uav_options):
    exited(clean, uav_options)
    wrong = clean.log.of("barrier")
    assert not wrong, wrong[:3]
    no_harness_trouble(clean)


def test_uav_sequence_numbers_increase(clean, uav_options):
    exited(clean, uav_options)
    tick_seqs = [t.seq for _, t in clean.log.ticks]
    assert all(a < b for a, b in zip(tick_seqs, tick_seqs[1:])), f"Tick seq not increasing: {tick_seqs[:12]}"
    seqs = [s for _, s in clean.log.seqs]
    assert len(seqs) == len(set(seqs)), "two messages from the UAV share a sequence number"


def test_mission_ends_completed_and_the_uav_exits_0(clean, uav_options):
    exited(clean, uav_options)
    assert clean.code == 0, f"exit code {clean.code}\n{clean.tail()}"
    assert "Traceback" not in clean.stderr + clean.stdout
    ends = clean.log.ends
    assert len(ends) == 1, f"{len(ends)} MissionEnd messages"
    assert ends[0][1].completed is True
    assert ends[0][0] > clean.log.ticks[-1][0]
    assert not clean.log.of("malformed")


def test_nothing_is_put_to_the_robots_after_mission_end(clean, uav_options):
    exited(clean, uav_options)
    assert clean.log.ends, f"no MissionEnd\n{clean.tail()}"
    wrong = clean.log.of("after-end")
    assert not wrong, wrong[:3]
    # By the UAV's own numbering too (U9: one counter for all it sends): a plan and the end travel on
    # different keys, so one put after the end may arrive first.
    end = min(e.seq for _, e in clean.log.ends)
    later = [f"plan {p.plan_id} to robot {r} (seq {p.seq})" for _, r, p, _ in clean.log.plans if p.seq > end]
    later += [f"Tick {t.k} (seq {t.seq})" for _, t in clean.log.ticks if t.seq > end]
    assert not later, f"put after MissionEnd (seq {end}): {later[:3]}"


def test_the_world_saw_every_robot_reach_its_goal_without_collision(clean, uav_options):
    exited(clean, uav_options)
    record = clean.record
    assert record.collisions == 0, record.refused[:3]
    assert record.refused == [], record.refused[:3]
    for rid, plan in clean.first_plans().items():
        assert tuple(record.executed[str(rid)][-1]) == tuple(plan.goal), f"robot {rid} is not on its goal"


def test_the_vehicle_took_off_and_landed(clean, uav_options):
    exited(clean, uav_options)
    v = clean.vehicle
    assert v is not None
    assert v["max_altitude_m"] > 1.0, f"the vehicle never left the ground: {v['events'][-5:]}"
    assert v["landed_state"] == "ON_GROUND" and not v["armed"], \
        f"the vehicle is {v['landed_state']}, armed {v['armed']} after the UAV exited"


def test_the_status_follows_the_mission_phases(clean, uav_options):
    exited(clean, uav_options)
    statuses = [s for _, s in clean.log.statuses]
    assert statuses, f"no MissionStatus on mission/status\n{clean.tail()}"
    problems = phase_problems(statuses, uav_options.robots, len(clean.log.ticks))
    assert not problems, problems
    assert {"dispatch", "executing", "verify"} <= {s.phase for s in statuses}, [s.phase for s in statuses]


def test_the_pose_stream_covers_the_flight(clean, uav_options):
    exited(clean, uav_options)
    took_off = next((t for t, s in clean.log.statuses if s.phase == "survey"), None)
    problems = pose_problems(clean.log.poses, took_off)
    assert not problems, problems


def test_the_frame_stream_shows_the_uavs_images(clean, uav_options):
    exited(clean, uav_options)
    problems = frame_problems(clean.log.frames, clean.images, ends(clean))
    assert not problems, problems
