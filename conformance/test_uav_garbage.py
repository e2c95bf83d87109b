"""UAV conformance: garbage, forgeries and messages from the future on a robot's keys are dropped.

The suite plays router, world and robots around the UAV under test, started from
`--uav-cmd` (conftest.py); a mission is shared by the tests of one module. See
docs/protocol.md, "Conformance", and docs/conformance-rules.md.
"""
from __future__ import annotations

import pytest

from conformance.uav_harness import ABORT_SLACK_S, Misbehaviour, MissionRun, run_mission
from conformance.uav_steps import RESEND_S, RESEND_SLACK_S, ends, exited, makespan_of, no_harness_trouble


DONE_WAIT_S = 5.0      # after the last tick: the UAV waits at most this for Done flags, then its camera decides


def _one_plan(run: MissionRun, why: str) -> None:
    plans = {t.plan_id for _, t in run.log.ticks}
    assert len(plans) == 1, f"the UAV repaired its plan ({len(plans)} plans ticked): {why}\n{run.tail()}"


def _never_out(run: MissionRun, rid: int, why: str) -> None:
    """Robot `rid` kept the contract: it is in every plan the UAV ticked."""
    plans = run.plans_by_id()
    out = sorted({t.plan_id for _, t in run.log.ticks if rid not in plans.get(t.plan_id, {})})
    assert not out, f"robot {rid} was taken out of the plan ({out[:2]}): {why}\n{run.tail()}"


@pytest.fixture(scope="module")
def noisy(uav_options, tmp_path_factory) -> MissionRun:
    """A mission in which one robot loses the first three puts of its first plan and puts garbage, forged
    and future messages on its keys, and another arrives but never raises Done."""
    rid = uav_options.robots - 1
    return run_mission(uav_options, Misbehaviour(garbage=frozenset({rid}), deaf=frozenset({rid}), deaf_puts=3,
                                                 mute=frozenset({0})),
                       tmp_path_factory.mktemp("noisy-mission"))


def test_garbage_on_robot_keys_is_dropped(noisy, uav_options):
    run, rid = noisy, uav_options.robots - 1
    exited(run, uav_options)
    assert run.code == 0, f"garbage from robot {rid} broke the mission (exit {run.code})\n{run.tail()}"
    assert "Traceback" not in run.stderr + run.stdout
    wrong = [text for kind, text in run.log.violations if kind != "barrier"]   # the barrier: U8 and U23
    assert not wrong, wrong[:3]
    assert [e.completed for _, e in run.log.ends] == [True]
    assert len(run.log.ticks) >= makespan_of(run)
    _never_out(run, 0, f"robot {rid} put states naming robot 0 (an error) on its own key")
    assert run.record.collisions == 0
    no_harness_trouble(run)


def test_a_state_for_a_tick_not_yet_put_reports_nothing(noisy, uav_options):
    """docs/protocol.md, The tick barrier: a state for a tick after the last Tick put is dropped."""
    run, rid = noisy, uav_options.robots - 1
    exited(run, uav_options)
    assert len(run.log.ticks) >= 4, f"the mission never reached tick 4\n{run.tail()}"
    early = run.log.of("barrier")
    assert not early, f"robot {rid} put states for ticks 3 and 7 during tick 2: {early[:2]}"
    _one_plan(run, f"robot {rid}'s states for ticks 3 and 7 (an error) were taken during tick 2")


def test_state_batch_entries_for_robots_the_key_does_not_name_are_dropped(noisy, uav_options):
    run, rid = noisy, uav_options.robots - 1
    exited(run, uav_options)
    assert len(run.log.ticks) >= 3, f"the mission never reached tick 3\n{run.tail()}"
    _never_out(run, 0, f"a StateBatch on robot {rid}'s own key said robot 0 erred")
    assert run.code == 0, f"exit {run.code}\n{run.tail()}"


def test_a_robot_that_never_raises_done_is_verified_by_the_camera(noisy, uav_options):
    """docs/protocol.md, Done is a claim: after the last tick the UAV waits at most 5 s for Done, then looks."""
    run = noisy
    exited(run, uav_options)
    assert 0 not in {d.robot for _, d in run.log.dones}, "the suite's mute robot raised Done"
    record = run.record
    assert tuple(record.executed["0"][-1]) == tuple(run.first_plans()[0].goal), "the mute robot never arrived"
    assert run.code == 0 and [e.completed for _, e in run.log.ends] == [True], \
        f"a robot on its goal without a Done is arrived (the camera decides): exit {run.code}\n{run.tail()}"
    waited = ends(run) - run.log.ticks[-1][0]
    assert waited <= DONE_WAIT_S + ABORT_SLACK_S, f"MissionEnd came {waited:.1f} s after the last tick"


def test_an_unacknowledged_plan_is_resent(noisy, uav_options):
    """docs/protocol.md: the UAV puts a plan again, every 2 s, while it is not acknowledged."""
    run, rid = noisy, uav_options.robots - 1
    exited(run, uav_options)
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
