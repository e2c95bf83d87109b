"""UAV conformance: robots that fail, refusing, falling silent or claiming an arrival the camera denies.

The suite plays router, world and robots around the UAV under test, started from
`--uav-cmd` (conftest.py); a mission is shared by the tests of one module. See
docs/protocol.md, "Conformance", and docs/conformance-rules.md.
"""
from __future__ import annotations

import re

import pytest

from conformance.uav_harness import Misbehaviour, MissionRun, run_mission
from conformance.uav_steps import exited, fails_with_one_line, no_harness_trouble


HOLD_SLACK_S = 0.3     # a UAV holds at the barrier for its tick deadline, less at most this


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
    fails_with_one_line(run, uav_options, refusals[0], rf"\b{victim}\b", uav_options.abort_s)
    assert not run.log.ticks, "ticks were sent although a robot refused its plan"
    no_harness_trouble(run)


def test_an_aborted_mission_end_says_why(refused, uav_options):
    """docs/protocol.md, End of mission: MissionEnd(completed=false, the reason)."""
    run, victim = refused, _refuser(uav_options)
    exited(run, uav_options)
    assert run.log.ends, f"no MissionEnd was published\n{run.tail()}"
    end = run.log.ends[-1][1]
    assert end.completed is False and re.search(rf"\b{victim}\b", end.reason), \
        f"MissionEnd {end.reason!r} does not say that robot {victim} refused its plan"


def test_a_silent_robot_is_taken_out_of_the_plan(uav_options, tmp_path):
    # It executes its moves but stops reporting from tick 2: the UAV holds at the barrier for the
    # tick deadline, then replans the others from tick 2 without it and finishes, degraded.
    victim = min(1, uav_options.robots - 1)
    run = run_mission(uav_options, Misbehaviour(silent_from={victim: 2}), tmp_path)
    exited(run, uav_options)
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
    no_harness_trouble(run)


def test_a_done_the_camera_contradicts_is_no_success(uav_options, tmp_path):
    # It reports every tick as if it followed its plan and raises Done, but never moves: the floor says otherwise.
    liar = uav_options.robots - 1
    run = run_mission(uav_options, Misbehaviour(liar=frozenset({liar})), tmp_path)
    exited(run, uav_options)
    assert run.code in (1, 3), f"the UAV exited {run.code} although robot {liar} never left its start\n{run.tail()}"
    claims = [t for t, e in run.log.events if liar in e.robots]
    assert claims, f"no MissionEvent names robot {liar}, whose Done the camera contradicts"
    assert run.record.collisions == 0
    no_harness_trouble(run)
