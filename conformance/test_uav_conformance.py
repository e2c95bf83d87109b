"""UAV conformance: does a UAV (leader) implementation keep the uav-robots protocol?

The suite is router, world and robots at once: a Zenoh router on a free
loopback port, our real world in this process (with its simulated MAVLink
vehicle on a free UDP port) and fake robots that keep the contract or break it
on purpose. It starts the UAV under test from `--uav-cmd` and checks what it
sends. Each mission is shared by the tests of one group (module fixtures): a
clean one, a noisy one (garbage on a robot's keys), one with faults the UAV must
repair (an error, a deviation, a stall and return), a degraded one (a robot
lost, one that keeps failing), and missions that must end early (a refused
plan, a mode the UAV did not command, a robot that never comes up, no world).
See docs/protocol.md, "Conformance", and docs/conformance-rules.md.
"""
from __future__ import annotations

import dataclasses
import re
from concurrent.futures import Future, ThreadPoolExecutor

import pytest

from conformance.uav_checks import (can_reach_a_goal, cells_at, frame_problems, phase_problems, plan_problems,
                                    pose_problems)
from conformance.uav_harness import (ABORT_SLACK_S, QUERY_WAIT_S, STARTUP_WAIT_S, Misbehaviour, MissionRun,
                                     error_lines, plan_problem, run_mission, run_stranded)

RESEND_S = 2.0         # the UAV puts again a plan not acknowledged within this ...
RESEND_SLACK_S = 1.5   # ... give or take this, for the transport and a loaded machine
HOLD_SLACK_S = 0.3     # a UAV holds at the barrier for its tick deadline, less at most this
DONE_WAIT_S = 5.0      # after the last tick: the UAV waits at most this for Done flags, then its camera decides
FAULT_ROBOTS = 5       # robots in the missions with faults: room for several at once
MAX_TRIES = 5          # plans that may name a robot that keeps failing: its first, a repair per strike, slack


def _late_robot(opts) -> int:
    return opts.robots - 1


def _fleet(opts, robots: int):
    return dataclasses.replace(opts, robots=max(opts.robots, robots))


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


def _ends(run: MissionRun) -> float:
    return run.log.ends[0][0] if run.log.ends else run.exited


def _ticks_after(run: MissionRun, k: int) -> list:
    return [t for _, t in run.log.ticks if t.k > k]


def _plan_at(run: MissionRun, k: int) -> str:
    """The plan_id of Tick(k)."""
    return next(t.plan_id for _, t in run.log.ticks if t.k == k)


def _repair_after(run: MissionRun, k: int, what: str):
    """The plan the UAV switched to right after tick k (the first Tick after k names it), and its plans by robot."""
    later = _ticks_after(run, k)
    assert later, f"no tick after tick {k}, when {what}\n{run.tail()}"
    assert later[0].plan_id != _plan_at(run, k), \
        f"Tick {later[0].k} still names plan {later[0].plan_id} after tick {k}, when {what}: the fleet was not held"
    plans = run.plans_by_id().get(later[0].plan_id, {})
    assert plans, f"Tick {later[0].k} names plan {later[0].plan_id}, which no robot was sent"
    return later[0].plan_id, plans


def _fault(run: MissionRun, kind: str, robot: int | None = None):
    f = run.log.fault(kind, robot)
    assert f is not None, (f"the suite never made its {kind} fault (robot {robot}): the mission went another way "
                           f"({len(run.log.ticks)} ticks)\n{run.tail()}")
    return f


# ---------------------------------------------------------------- a clean mission
def test_uav_token_is_up_before_any_plan_and_gone_after_exit(clean, uav_options):
    _exited(clean, uav_options)
    alive = clean.log.uav_alive
    assert alive and alive[0][1], "no alive/uav liveliness token was ever seen"
    up = alive[0][0]
    assert all(t > up for t, *_ in clean.log.plans), "a plan was sent before alive/uav was declared"
    assert not alive[-1][1], "alive/uav is still declared after the UAV exited"


def test_the_uav_token_stays_up_for_the_whole_mission(clean, uav_options):
    """A robot exits when alive/uav disappears (R33): a flicker mid-mission ends the fleet."""
    _exited(clean, uav_options)
    changes = [alive for _, alive in clean.log.uav_alive]
    assert changes[:1] == [True], "no alive/uav liveliness token was ever seen"
    assert changes == [True, False], f"alive/uav went {changes}: it must stay up from before the plans to the end"
    assert not clean.log.ends or clean.log.uav_alive[-1][0] >= clean.log.ends[0][0], \
        "alive/uav was withdrawn before MissionEnd"


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
    assert plans, f"no plan was sent\n{clean.tail()}"
    problems = plan_problems(plans, 0, clean.truth, clean.record, uav_options.connectivity)
    assert problems == [], problems[:5]


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
    assert ends[0][0] > clean.log.ticks[-1][0]
    assert not clean.log.of("malformed")


def test_nothing_is_put_to_the_robots_after_mission_end(clean, uav_options):
    _exited(clean, uav_options)
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


def test_the_status_follows_the_mission_phases(clean, uav_options):
    _exited(clean, uav_options)
    statuses = [s for _, s in clean.log.statuses]
    assert statuses, f"no MissionStatus on mission/status\n{clean.tail()}"
    problems = phase_problems(statuses, uav_options.robots, len(clean.log.ticks))
    assert not problems, problems
    assert {"dispatch", "executing", "verify"} <= {s.phase for s in statuses}, [s.phase for s in statuses]


def test_the_pose_stream_covers_the_flight(clean, uav_options):
    _exited(clean, uav_options)
    took_off = next((t for t, s in clean.log.statuses if s.phase == "survey"), None)
    problems = pose_problems(clean.log.poses, took_off)
    assert not problems, problems


def test_the_frame_stream_shows_the_uavs_images(clean, uav_options):
    _exited(clean, uav_options)
    problems = frame_problems(clean.log.frames, clean.images, _ends(clean))
    assert not problems, problems


# ---------------------------------------------------------------- robots that fail
def _fails_with_one_line(run: MissionRun, opts, since: float, names: str, within: float) -> None:
    """The UAV ends the mission as failed: exit 1 within `within` s of `since`, no traceback, a stderr line
    matching `names`, MissionEnd(completed=false), its token withdrawn, landed."""
    _exited(run, opts)
    assert run.code == 1, f"exit {run.code}, not 1 (a failed or aborted mission)\n{run.tail()}"
    assert run.exited - since <= within, f"the UAV took {run.exited - since:.1f} s to give up (at most {within:g} s)"
    assert "Traceback" not in run.stderr + run.stdout, run.tail()
    lines = error_lines(run.stderr)
    assert any(re.search(names, line) for line in lines), \
        f"no line on stderr names what failed ({names!r}):\n{run.stderr[-1500:]}"
    assert run.log.ends, "no MissionEnd was published"
    assert run.log.ends[-1][1].completed is False, "MissionEnd says completed although the mission failed"
    alive = run.log.uav_alive
    assert alive and not alive[-1][1], "alive/uav is still declared after the UAV exited"
    v = run.vehicle
    if v is not None and v["max_altitude_m"] > 1.0:
        # Safety, not wire format: a leader that gives up must not leave its drone hovering armed.
        assert v["landed_state"] == "ON_GROUND" and not v["armed"], \
            f"after the abort the vehicle is {v['landed_state']}, armed {v['armed']}"


def _refuser(opts) -> int:
    return min(1, opts.robots - 1)


@pytest.fixture(scope="module")
def refused(uav_options, tmp_path_factory) -> MissionRun:
    """A mission in which a robot refuses its first plan."""
    return run_mission(uav_options, Misbehaviour(refuse=frozenset({_refuser(uav_options)})),
                       tmp_path_factory.mktemp("refused"))


def test_a_refused_plan_ends_the_mission_with_an_error(refused, uav_options):
    run, victim = refused, _refuser(uav_options)
    refusals = [t for t, ack in run.log.acks if ack.robot == victim and not ack.ok]
    assert refusals, f"robot {victim} never got a plan to refuse\n{run.tail()}"
    _fails_with_one_line(run, uav_options, refusals[0], rf"\b{victim}\b", uav_options.abort_s)
    assert not run.log.ticks, "ticks were sent although a robot refused its plan"
    _no_harness_trouble(run)


def test_an_aborted_mission_end_says_why(refused, uav_options):
    """docs/protocol.md, End of mission: MissionEnd(completed=false, the reason)."""
    run, victim = refused, _refuser(uav_options)
    _exited(run, uav_options)
    assert run.log.ends, f"no MissionEnd was published\n{run.tail()}"
    end = run.log.ends[-1][1]
    assert end.completed is False and re.search(rf"\b{victim}\b", end.reason), \
        f"MissionEnd {end.reason!r} does not say that robot {victim} refused its plan"


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
    replans = [(t, rid, p) for t, rid, p, _ in run.log.plans if p.plan_id == later[0].plan_id]
    assert replans and victim not in {rid for _, rid, _ in replans}, "the silent robot was given the new plan"
    assert all(p.start_tick == 2 for *_, p in replans), [p.start_tick for *_, p in replans]
    held = replans[0][0] - run.log.ticks[1][0]
    assert held >= uav_options.tick_timeout_s - HOLD_SLACK_S, \
        f"the UAV gave up on the silent robot {held:.1f} s after Tick 2, before its tick deadline " \
        f"({uav_options.tick_timeout_s:g} s)"
    assert held <= uav_options.abort_s, f"the UAV held the fleet {held:.1f} s (at most {uav_options.abort_s:g} s)"
    assert run.code == 3, f"a mission finished without robot {victim} must exit 3 (degraded)\n{run.tail()}"
    assert run.record.collisions == 0
    _no_harness_trouble(run)


def test_a_done_the_camera_contradicts_is_no_success(uav_options, tmp_path):
    # It reports every tick as if it followed its plan and raises Done, but never moves: the floor says otherwise.
    liar = uav_options.robots - 1
    run = run_mission(uav_options, Misbehaviour(liar=frozenset({liar})), tmp_path)
    _exited(run, uav_options)
    assert run.code in (1, 3), f"the UAV exited {run.code} although robot {liar} never left its start\n{run.tail()}"
    claims = [t for t, e in run.log.events if liar in e.robots]
    assert claims, f"no MissionEvent names robot {liar}, whose Done the camera contradicts"
    assert run.record.collisions == 0
    _no_harness_trouble(run)


# ---------------------------------------------------------------- garbage and forgeries
@pytest.fixture(scope="module")
def noisy(uav_options, tmp_path_factory) -> MissionRun:
    """A mission in which one robot loses the first three puts of its first plan and puts garbage, forged
    and future messages on its keys, and another arrives but never raises Done."""
    rid = uav_options.robots - 1
    return run_mission(uav_options, Misbehaviour(garbage=frozenset({rid}), deaf=frozenset({rid}), deaf_puts=3,
                                                 mute=frozenset({0})),
                       tmp_path_factory.mktemp("noisy-mission"))


def _one_plan(run: MissionRun, why: str) -> None:
    plans = {t.plan_id for _, t in run.log.ticks}
    assert len(plans) == 1, f"the UAV repaired its plan ({len(plans)} plans ticked): {why}\n{run.tail()}"


def _never_out(run: MissionRun, rid: int, why: str) -> None:
    """Robot `rid` kept the contract: it is in every plan the UAV ticked."""
    plans = run.plans_by_id()
    out = sorted({t.plan_id for _, t in run.log.ticks if rid not in plans.get(t.plan_id, {})})
    assert not out, f"robot {rid} was taken out of the plan ({out[:2]}): {why}\n{run.tail()}"


def test_garbage_on_robot_keys_is_dropped(noisy, uav_options):
    run, rid = noisy, uav_options.robots - 1
    _exited(run, uav_options)
    assert run.code == 0, f"garbage from robot {rid} broke the mission (exit {run.code})\n{run.tail()}"
    assert "Traceback" not in run.stderr + run.stdout
    wrong = [text for kind, text in run.log.violations if kind != "barrier"]   # the barrier: U8 and U23
    assert not wrong, wrong[:3]
    assert [e.completed for _, e in run.log.ends] == [True]
    assert len(run.log.ticks) >= _makespan(run)
    _never_out(run, 0, f"robot {rid} put states naming robot 0 (an error) on its own key")
    assert run.record.collisions == 0
    _no_harness_trouble(run)


def test_a_state_for_a_tick_not_yet_put_reports_nothing(noisy, uav_options):
    """docs/protocol.md, The tick barrier: a state for a tick after the last Tick put is dropped."""
    run, rid = noisy, uav_options.robots - 1
    _exited(run, uav_options)
    assert len(run.log.ticks) >= 4, f"the mission never reached tick 4\n{run.tail()}"
    early = run.log.of("barrier")
    assert not early, f"robot {rid} put states for ticks 3 and 7 during tick 2: {early[:2]}"
    _one_plan(run, f"robot {rid}'s states for ticks 3 and 7 (an error) were taken during tick 2")


def test_state_batch_entries_for_robots_the_key_does_not_name_are_dropped(noisy, uav_options):
    run, rid = noisy, uav_options.robots - 1
    _exited(run, uav_options)
    assert len(run.log.ticks) >= 3, f"the mission never reached tick 3\n{run.tail()}"
    _never_out(run, 0, f"a StateBatch on robot {rid}'s own key said robot 0 erred")
    assert run.code == 0, f"exit {run.code}\n{run.tail()}"


def test_a_robot_that_never_raises_done_is_verified_by_the_camera(noisy, uav_options):
    """docs/protocol.md, Done is a claim: after the last tick the UAV waits at most 5 s for Done, then looks."""
    run = noisy
    _exited(run, uav_options)
    assert 0 not in {d.robot for _, d in run.log.dones}, "the suite's mute robot raised Done"
    record = run.record
    assert tuple(record.executed["0"][-1]) == tuple(run.first_plans()[0].goal), "the mute robot never arrived"
    assert run.code == 0 and [e.completed for _, e in run.log.ends] == [True], \
        f"a robot on its goal without a Done is arrived (the camera decides): exit {run.code}\n{run.tail()}"
    waited = _ends(run) - run.log.ticks[-1][0]
    assert waited <= DONE_WAIT_S + ABORT_SLACK_S, f"MissionEnd came {waited:.1f} s after the last tick"


def test_an_unacknowledged_plan_is_resent(noisy, uav_options):
    """docs/protocol.md: the UAV puts a plan again, every 2 s, while it is not acknowledged."""
    run, rid = noisy, uav_options.robots - 1
    _exited(run, uav_options)
    mine = [(t, p) for t, r, p, up in run.log.plans if r == rid and up]
    assert mine, f"robot {rid} got no plan\n{run.tail()}"
    assert len(mine) >= 4, f"robot {rid} lost its plan 3 times and the UAV put it {len(mine)} times\n{run.tail()}"
    first = mine[0][1]
    gaps = [b[0] - a[0] for a, b in zip(mine[:4], mine[1:4])]
    assert all(RESEND_S - RESEND_SLACK_S <= g <= RESEND_S + RESEND_SLACK_S for g in gaps), \
        f"the plan was put again after {[round(g, 1) for g in gaps]} s (every {RESEND_S:g} s)"
    for _, again in mine[1:4]:
        assert (again.plan_id, again.path, tuple(again.goal)) == (first.plan_id, first.path, tuple(first.goal)), \
            "a resent plan must be the same plan (same plan_id and path)"
    assert run.code == 0, f"exit {run.code}\n{run.tail()}"


# ---------------------------------------------------------------- faults the UAV repairs
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


def _kept_the_contract(run: MissionRun) -> set[int]:
    return set(range(run.robots)) - {r for _, r, *_ in run.log.faults}


def test_every_repair_plan_is_executable_and_reaches_every_working_robot(faults, uav_options):
    run = faults
    _exited(run, uav_options)
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
    _no_harness_trouble(run)


def test_a_robot_in_error_is_taken_out_of_the_plan(faults, uav_options):
    run = faults
    _exited(run, uav_options)
    _, rid, k, _ = _fault(run, "error", 0)
    pid, plans = _repair_after(run, k, f"robot {rid} reported an error at tick {k}")
    assert rid not in plans, f"robot {rid}, in error at tick {k}, was given plan {pid} from that tick"
    assert {p.start_tick for p in plans.values()} == {k}, f"plan {pid} starts at {[p.start_tick for p in plans.values()]}"


def test_a_deviation_is_repaired_from_where_the_robot_stands(faults, uav_options):
    run = faults
    _exited(run, uav_options)
    _, rid, k, _ = _fault(run, "deviation", 1)
    pid, plans = _repair_after(run, k, f"robot {rid} reported a cell off its plan at tick {k}")
    assert rid in plans, f"robot {rid}, which deviated at tick {k}, got no plan of the repair {pid}"
    stood = cells_at(run.record, k)[rid]
    assert plans[rid].start_tick == k and tuple(plans[rid].path[0]) == stood, \
        f"robot {rid}'s repair starts at tick {plans[rid].start_tick} on {tuple(plans[rid].path[0])}; it stood on " \
        f"{stood} after tick {k}"


def test_a_stalled_robot_that_comes_back_rejoins(faults, uav_options):
    run = faults
    _exited(run, uav_options)
    _, rid, k, _ = _fault(run, "stall", 2)
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
    _exited(run, uav_options)
    for kind, rid, k, at in run.log.faults:
        later = _ticks_after(run, k)
        before = next((t for t, tick in run.log.ticks if tick.k > k), _ends(run))
        named = [e for t, e in run.log.events if rid in e.robots and at <= t <= before]
        assert named, f"no MissionEvent named robot {rid} between its {kind} at tick {k} and the next tick " \
                      f"({later[0].k if later else 'none'})"


# ---------------------------------------------------------------- a degraded fleet
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


def test_a_lost_robot_is_taken_out_at_once(degraded, uav_options):
    run = degraded
    _exited(run, uav_options)
    _, rid, k, _ = _fault(run, "lost", 1)
    pid, plans = _repair_after(run, k, f"robot {rid}'s token vanished after tick {k}")
    assert rid not in plans, f"robot {rid}, lost after tick {k}, was given plan {pid}"
    assert {p.start_tick for p in plans.values()} == {k}, f"plan {pid} starts at {[p.start_tick for p in plans.values()]}"
    late = [p.plan_id for _, r, p, _ in run.log.plans if r == rid and p.start_tick >= k]
    assert not late, f"robot {rid}, whose token is gone, was sent plans {late[:3]}"


def test_a_robot_that_keeps_failing_is_quarantined_and_the_rest_finish(degraded, uav_options):
    run, stuck = degraded, 3
    _exited(run, uav_options)
    _fault(run, "stuck", stuck)
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
    _no_harness_trouble(run)


def test_images_during_execution_are_taken_while_the_fleet_holds(degraded, uav_options):
    """docs/protocol.md, Monitoring and Faults: an image is taken at a tick boundary while the fleet holds, the
    robots still working having finished the tick (robot 0 vanished as tick 4 arrived, the others asked 1 s later)."""
    run = degraded
    _exited(run, uav_options)
    _fault(run, "vanished", 0)
    begun, end = run.log.ticks[0][0], _ends(run)
    during = [s for s in run.shutters if begun < s.at < end]
    assert during, f"the UAV took no image during execution, not even for a repair\n{run.tail()}"
    moving = [s for s in during if not s.settled]
    assert not moving, (f"{len(moving)} of {len(during)} images during execution were taken while robots moved: "
                        f"e.g. the world had heard Tick {moving[0].heard} and judged tick {moving[0].judged}")


# ---------------------------------------------------------------- its own vehicle
def test_a_mode_the_uav_did_not_command_ends_the_mission(uav_options, tmp_path):
    """A ground station commands RTL at tick 2; the fleet holds its states of that tick 2 s more."""
    run = run_mission(uav_options, Misbehaviour(rtl_at=2), tmp_path)
    _, _, k, at = _fault(run, "rtl")
    ticked = _ticks_after(run, k)
    assert not ticked, f"the UAV put Tick {ticked[0].k} after the vehicle switched to RTL at tick {k}"
    assert [t for t, e in run.log.events if t >= at], "no MissionEvent says the vehicle left the mission's control"
    _fails_with_one_line(run, uav_options, at, r"RTL|RETURN|[Rr]eturn|mode", uav_options.abort_s)
    _no_harness_trouble(run)


# ---------------------------------------------------------------- bounded waits
# These missions mostly wait out a documented bound (10 to 30 s): started in the background as the
# module begins (those whose tests are selected), they run beside the others, and their tests come last.
def _stranded(opts, tmp) -> dict[str, MissionRun]:
    """The UAV on a router without a world, with a world that answers world/info nothing, and with one
    that answers garbage: three UAVs at once."""
    bound = {"none": STARTUP_WAIT_S, "silent": QUERY_WAIT_S, "garbage": QUERY_WAIT_S}
    with ThreadPoolExecutor(len(bound)) as pool:
        jobs = {w: pool.submit(run_stranded, opts, w, tmp / f"world-{w}", bound[w] + ABORT_SLACK_S + 5)
                for w in bound}
        return {w: job.result() for w, job in jobs.items()}


ABSENT = 0   # the robot whose token never comes up (an id no count of robots is written with)


def _never_up(opts, tmp) -> MissionRun:
    """Robot 0's token never comes up."""
    return run_mission(opts, Misbehaviour(absent=frozenset({ABSENT})), tmp)


def _unacked(opts, tmp) -> MissionRun:
    """Robot 0 cannot execute tick 2; robot 1 never hears the repair that follows (every put of it is lost)."""
    return run_mission(opts, Misbehaviour(error_at={0: 2}, deaf_repair=frozenset({1})), tmp)


SLOW = {"stranded": _stranded, "never_up": _never_up, "unacked": _unacked}
_started: dict[str, Future] = {}


@pytest.fixture(scope="module", autouse=True)
def _slow_missions_in_the_background(request, uav_options, tmp_path_factory):
    wanted = sorted({name for item in request.session.items if item.module is request.module
                     for name in item.fixturenames if name in SLOW})
    pool = ThreadPoolExecutor(max(1, len(wanted)), thread_name_prefix="slow-mission")
    for name in wanted:
        # Each mission's directory is made here, on pytest's own thread: its temporary root is made (and,
        # given --basetemp, emptied first) on the first call, which must not race another thread's.
        _started[name] = pool.submit(SLOW[name], uav_options, tmp_path_factory.mktemp(name))
    try:
        yield
    finally:
        pool.shutdown(wait=True)
        _started.clear()


def _slow(name: str, opts, tmp_path_factory):
    job = _started.get(name)
    return job.result() if job is not None else SLOW[name](opts, tmp_path_factory.mktemp(name))


@pytest.fixture(scope="module")
def stranded(uav_options, tmp_path_factory) -> dict[str, MissionRun]:
    return _slow("stranded", uav_options, tmp_path_factory)


@pytest.fixture(scope="module")
def never_up(uav_options, tmp_path_factory) -> MissionRun:
    return _slow("never_up", uav_options, tmp_path_factory)


@pytest.fixture(scope="module")
def unacked(uav_options, tmp_path_factory) -> MissionRun:
    return _slow("unacked", uav_options, tmp_path_factory)


def test_a_uav_without_a_world_ends_the_mission(stranded, uav_options):
    run = stranded["none"]
    _fails_with_one_line(run, uav_options, run.started, r"[Ww]orld", STARTUP_WAIT_S + ABORT_SLACK_S)


@pytest.mark.parametrize("answer", ["silent", "garbage"])
def test_a_world_that_does_not_answer_its_info_ends_the_mission(stranded, uav_options, answer):
    run = stranded[answer]
    _fails_with_one_line(run, uav_options, run.started, r"info", QUERY_WAIT_S + ABORT_SLACK_S)


def test_a_robot_that_never_comes_up_ends_the_mission(never_up, uav_options):
    run = never_up
    assert not run.log.plans, "plans were put although a robot's token never came up"
    # Its wait began at its last phase change at the latest (the fleet's other tokens were up before it started).
    since = max((t for t, _ in run.log.statuses), default=run.started)
    _fails_with_one_line(run, uav_options, since, rf"\b{ABSENT}\b", STARTUP_WAIT_S + ABORT_SLACK_S)


def test_an_unacknowledged_repair_is_put_again_and_then_given_up(unacked, uav_options):
    run, deaf = unacked, 1
    _exited(run, uav_options)
    _fault(run, "deaf-repair", deaf)
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
    _no_harness_trouble(run)
