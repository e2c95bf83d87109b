"""Robot conformance: does a robot implementation keep the uav-robots protocol?

The suite is hub, UAV and world at once (a Zenoh router on a free loopback
port, a fake UAV, a fake move service) and starts the robot under test from
`--robot-cmd`. See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import dataclasses
import json
import signal
import time

import pytest

from conformance import FakeUav, Hub, Wire, free_endpoint, signal_group, start_robot, stop_process
from protocol.codec import decode, encode
from protocol.keys import new_fleet_name
from protocol.messages import MESSAGE_TYPES, MissionEnd, MovesJudged, Plan, Tick

EXIT_S = 5.0
QUIET_S = 0.5  # how long "nothing more arrives" is watched for
MOVE_TIMEOUT_S = 5.0  # docs/protocol.md, QoS: a robot waits this long for the world's answer to a move


def _path_at(path, k):
    return tuple(path[min(k, len(path) - 1)])


def _run_ticks(uav, world, rid, plan_id, path, ticks, timeout):
    """Ticks 1..ticks in lockstep, as the UAV's barrier does; returns the states."""
    states = []
    for k in range(1, ticks + 1):
        uav.tick(k, ticks, plan_id)
        st = uav.state_at(rid, k, timeout)
        assert st is not None, f"no RobotState for tick {k} within {timeout:g} s"
        states.append(st)
    return states


def _accepted(uav, rid, plan_id, path, timeout):
    uav.plan(rid, plan_id, path)
    ack = uav.ack_for(rid, plan_id, timeout)
    assert ack is not None, f"no PlanAck for plan {plan_id} within {timeout:g} s"
    assert ack.ok, f"a valid plan was refused: {ack.error}"
    return ack


def test_liveliness_token_appears(spawn, uav, rid, timeout):
    proc = spawn()
    assert uav.until(lambda: rid in uav.alive, timeout), f"no liveliness token within {timeout:g} s"
    assert proc.poll() is None, f"the robot exited with code {proc.returncode}"


def test_valid_plan_is_acknowledged(robot, uav, rid, timeout):
    ack = _accepted(uav, rid, "p-valid", [(2, 2), (3, 2), (3, 3)], timeout)
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
    _accepted(uav, rid, "p-good", [(2, 2), (3, 2)], timeout)
    assert robot.poll() is None


def test_ticks_follow_the_plan_and_done_is_raised_once(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (3, 2), (4, 2), (4, 3)]
    _accepted(uav, rid, "p-run", path, timeout)
    ticks = len(path) + 1  # two ticks past the plan's end: the robot stays on its goal
    states = _run_ticks(uav, world, rid, "p-run", path, ticks, timeout)
    for k, st in enumerate(states, 1):
        reqs = world.requests_for(rid, k)
        assert len(reqs) == 1, f"tick {k}: {len(reqs)} move requests, expected exactly one"
        assert (tuple(reqs[0].frm), tuple(reqs[0].to)) == (_path_at(path, k - 1), _path_at(path, k)), \
            f"tick {k}: asked {reqs[0].frm} -> {reqs[0].to}"
        assert st.robot == rid and st.tick == k and tuple(st.cell) == _path_at(path, k), \
            f"tick {k}: state {st.tick} at {st.cell}, expected {_path_at(path, k)}"
    assert uav.until(lambda: len(uav.dones.get(rid, [])) >= 1, timeout), "no Done at the goal"
    time.sleep(QUIET_S)
    dones = uav.dones[rid]
    assert len(dones) == 1, f"Done raised {len(dones)} times"
    assert tuple(dones[0].cell) == path[-1] and dones[0].tick == len(path) - 1
    assert states[-1].status == "done"


def test_refused_move_leaves_the_robot_in_place(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2), (4, 2)]
    world.refuse.add((rid, 2))
    _accepted(uav, rid, "p-refused", path, timeout)
    states = _run_ticks(uav, world, rid, "p-refused", path, 2, timeout)
    assert tuple(states[1].cell) == (3, 2), "after a refused move the robot must report where it really is"
    time.sleep(QUIET_S)
    assert not uav.dones.get(rid), "Done raised while not on the goal"
    uav.tick(3, 3, "p-refused")
    st3 = uav.state_at(rid, 3, timeout)
    assert st3 is not None and tuple(st3.cell) == (4, 2)
    (req3,) = world.requests_for(rid, 3)
    assert tuple(req3.frm) == (3, 2) and tuple(req3.to) == (4, 2), "the next request must start from the real cell"
    assert uav.until(lambda: len(uav.dones.get(rid, [])) == 1, timeout)


def test_moves_are_asked_on_the_key_naming_the_robot(robot, hub, uav, world, rid, timeout):
    """docs/protocol.md, Keys and Security: `P/world/move/<ids>`, not the plain `P/world/move` that
    access control leaves unreachable (an independent robot asking there passed every other test)."""
    path = [(2, 2), (3, 2), (3, 3)]
    _accepted(uav, rid, "p-key", path, timeout)
    _run_ticks(uav, world, rid, "p-key", path, 2, timeout)
    with world.cv:
        keys = [key for key, robots in world.move_keys if rid in robots]
    assert len(keys) == 2 and set(keys) == {hub.keys.move_as([rid])}, \
        f"moves asked on {sorted(set(keys))}, expected {hub.keys.move_as([rid])}"


def _wrong_version(msg) -> bytes:
    return encode(msg).replace(b'"v":1', b'"v":99', 1)


def test_garbage_and_wrong_versions_do_not_crash_it(robot, uav, world, rid, timeout):
    k = uav.keys
    junk = [b"", b"\x00\xff garbage", b"{}", b"[1,2,3]", b'{"type":"Plan","v":1}',
            _wrong_version(Plan(robot=rid, plan_id="p-v99", path=[(1, 1)], goal=(1, 1)))]
    for payload in junk:
        uav.transport.put(k.plan(rid), payload)
    for payload in junk[:4] + [_wrong_version(Tick(k=1, ticks=1, plan_id="p-v99")), encode(Plan(
            robot=rid, plan_id="x", path=[(1, 1)], goal=(1, 1)))]:
        uav.transport.put(k.tick, payload)
    time.sleep(QUIET_S)
    assert robot.poll() is None, "the robot died on garbage"
    assert not world.requests, "garbage on the tick key made the robot move"
    assert not uav.acks.get(rid), f"plans that do not decode were answered: {uav.acks.get(rid)} (no PlanAck, " \
                                  "not even ok: false: the robot cannot trust their robot and plan_id)"
    path = [(2, 2), (2, 3)]
    _accepted(uav, rid, "p-after", path, timeout)
    (st,) = _run_ticks(uav, world, rid, "p-after", path, 1, timeout)
    assert tuple(st.cell) == (2, 3)


def test_duplicate_and_late_ticks_are_ignored(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    _accepted(uav, rid, "p-dup", path, timeout)
    _run_ticks(uav, world, rid, "p-dup", path, 2, timeout)
    uav.tick(2, 2, "p-dup")
    uav.tick(1, 2, "p-dup")
    time.sleep(QUIET_S)
    assert len(world.requests_for(rid, 1)) == 1 and len(world.requests_for(rid, 2)) == 1
    assert [s.tick for s in uav.states[rid]] == [1, 2]


def _exits(proc, seconds):
    try:
        proc.wait(seconds)
        return True
    except Exception:  # noqa: BLE001 - TimeoutExpired
        return False


def test_exits_on_mission_end(robot, uav, rid, timeout):
    _accepted(uav, rid, "p-end", [(2, 2)], timeout)
    uav.end(True, "conformance")
    assert _exits(robot, EXIT_S), f"still running {EXIT_S:g} s after MissionEnd"
    assert robot.returncode == 0
    assert uav.until(lambda: rid not in uav.alive, timeout), "liveliness token left behind"


def test_exits_on_sigterm(robot, uav, rid, timeout):
    robot.send_signal(signal.SIGTERM)
    assert _exits(robot, EXIT_S), f"still running {EXIT_S:g} s after SIGTERM"
    assert robot.returncode == 0, f"exit code {robot.returncode}: a robot exits 0 on SIGTERM, closing its session"


def test_exits_when_the_uav_goes_away(robot, uav, rid):
    uav.leave()
    assert _exits(robot, EXIT_S), f"still running {EXIT_S:g} s after the UAV's liveliness token went away"


def test_restart_gets_a_fresh_token(spawn, uav, rid, timeout):
    """A robot that is killed and restarted comes back alive on the same id."""
    first = spawn()
    assert uav.until(lambda: rid in uav.alive, timeout)
    signal_group(first, signal.SIGKILL)
    first.wait(5)
    assert uav.until(lambda: rid not in uav.alive, timeout), "the dead robot's token did not go away"
    spawn()
    assert uav.until(lambda: rid in uav.alive, timeout)


def test_a_repair_plan_starts_at_its_tick_and_is_switched_to_at_once(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks / Faults and recovery: path[i] is the cell at tick start_tick + i;
    a repair plan (start_tick > 0) names where the robot stands, whatever the robot believed."""
    first = [(2, 2), (3, 2), (4, 2), (5, 2), (6, 2)]
    _accepted(uav, rid, "p-first", first, timeout)
    _run_ticks(uav, world, rid, "p-first", first, 2, timeout)          # now at (4, 2) after tick 2
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
        want = (_path_at(repair, k - 3), _path_at(repair, k - 2))
        assert (tuple(req.frm), tuple(req.to)) == want, f"tick {k}: asked {req.frm} -> {req.to}, expected {want}"
        assert st.plan_id == "p-repair"


def test_a_repair_plan_for_a_past_tick_is_refused(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    _accepted(uav, rid, "p-now", path, timeout)
    _run_ticks(uav, world, rid, "p-now", path, 3, timeout)
    uav.plan(rid, "p-past", [(4, 2), (4, 3)], start_tick=1)
    ack = uav.ack_for(rid, "p-past", timeout)
    assert ack is not None and not ack.ok, "a plan starting before the last executed tick was accepted"


# ---------------------------------------------------------------- plans: ids, starts, connectivity
def test_messages_name_the_robot_of_their_key(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2)]
    _accepted(uav, rid, "p-keys", path, timeout)
    _run_ticks(uav, world, rid, "p-keys", path, 2, timeout)
    uav.until(lambda: bool(uav.dones.get(rid)), timeout)
    time.sleep(QUIET_S)
    assert not uav.garbage, f"messages on robot {rid}'s keys that name another robot or do not decode: {uav.garbage[:3]}"
    for msg in uav.acks[rid] + uav.states[rid] + uav.dones.get(rid, []):
        assert msg.robot == rid, f"{type(msg).__name__} on robot {rid}'s key names robot {msg.robot}"


def test_a_plan_not_starting_where_the_robot_stands_is_refused(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    _accepted(uav, rid, "p-first", path, timeout)
    _run_ticks(uav, world, rid, "p-first", path, 1, timeout)         # it stands on (3, 2)
    uav.plan(rid, "p-elsewhere", [(6, 6), (6, 7)])
    ack = uav.ack_for(rid, "p-elsewhere", timeout)
    assert ack is not None, "no PlanAck for a plan that starts elsewhere"
    assert not ack.ok, "a plan that does not start where the robot stands was accepted"
    _accepted(uav, rid, "p-from-here", [(3, 2), (3, 3)], timeout)   # a replan from here is fine
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
    states = _run_ticks(uav, world, rid, "p-diagonal", path, 2, timeout)
    for k, st in enumerate(states, 1):
        (req,) = world.requests_for(rid, k)
        assert (tuple(req.frm), tuple(req.to)) == (path[k - 1], path[k]), f"tick {k}: asked {req.frm} -> {req.to}"
        assert tuple(st.cell) == path[k]


def test_a_resent_plan_is_acknowledged_again(robot, uav, rid, timeout):
    path = [(2, 2), (3, 2)]
    _accepted(uav, rid, "p-resent", path, timeout)
    uav.plan(rid, "p-resent", path)      # the UAV heard no ack within 2 s and puts it again
    acks = uav.acks_for(rid, "p-resent", 2, timeout)
    assert len(acks) == 2, "a plan resent with the same plan_id was not acknowledged again"
    assert acks[1].ok, f"a resent plan was refused: {acks[1].error}"


def test_another_path_under_the_same_plan_id_is_refused(robot, uav, world, rid, timeout):
    first = [(2, 2), (3, 2)]
    _accepted(uav, rid, "p-same", first, timeout)
    uav.plan(rid, "p-same", [(2, 2), (2, 3)])
    acks = uav.acks_for(rid, "p-same", 2, timeout)
    assert len(acks) == 2, "no PlanAck for another path under a plan_id already held"
    assert not acks[1].ok and acks[1].error, "another path under the same plan_id was accepted"
    _run_ticks(uav, world, rid, "p-same", first, 1, timeout)
    (req,) = world.requests_for(rid, 1)
    assert tuple(req.to) == (3, 2), "the robot left the plan it had acknowledged"


# ---------------------------------------------------------------- states
def test_states_only_for_executed_ticks(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2), (5, 2)]
    _accepted(uav, rid, "p-states", path, timeout)
    time.sleep(QUIET_S)
    assert not uav.states.get(rid), f"states before the first tick: {uav.states.get(rid)}"
    _run_ticks(uav, world, rid, "p-states", path, 2, timeout)
    time.sleep(QUIET_S)
    states = uav.states[rid]
    assert [s.tick for s in states] == [1, 2], f"states for ticks {[s.tick for s in states]}, expected [1, 2]"
    assert [s.status for s in states] == ["stepping", "stepping"], [s.status for s in states]


def test_states_name_the_plan_held(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    _accepted(uav, rid, "p-named", path, timeout)
    states = _run_ticks(uav, world, rid, "p-named", path, 1, timeout)
    _accepted(uav, rid, "p-renamed", [(3, 2), (3, 3)], timeout)
    uav.tick(2, 2, "p-renamed")
    st2 = uav.state_at(rid, 2, timeout)
    assert st2 is not None, "no RobotState for tick 2"
    assert [s.plan_id for s in states + [st2]] == ["p-named", "p-renamed"], \
        f"states name plans {[s.plan_id for s in states + [st2]]!r}"


@pytest.mark.parametrize("answer", ["none", "garbage"])
def test_no_answer_from_the_world_is_an_error_state(robot, uav, world, rid, timeout, answer):
    """docs/protocol.md: a robot treats a garbage move result as no answer."""
    world.answer, world.garbage = answer != "none", answer == "garbage"
    path = [(2, 2), (3, 2)]
    _accepted(uav, rid, "p-silent-world", path, timeout)
    uav.tick(1, 1, "p-silent-world")
    st = uav.state_at(rid, 1, max(timeout, MOVE_TIMEOUT_S + 1.0))   # the robot may wait its move timeout
    assert st is not None, "no RobotState when the world did not answer the move"
    assert st.status == "error" and st.error, f"status {st.status!r} error {st.error!r}"
    assert tuple(st.cell) == (2, 2), f"an error state must name the last known cell (2, 2), not {st.cell}"
    time.sleep(QUIET_S)
    asked = len(world.requests_for(rid, 1))
    assert asked == 1, f"the robot asked {asked} times for tick 1: a robot does not ask twice for a tick"


# ---------------------------------------------------------------- ticks
def test_a_tick_for_another_plan_makes_the_robot_stay(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (4, 2)]
    _accepted(uav, rid, "p-mine", path, timeout)
    _run_ticks(uav, world, rid, "p-mine", path, 1, timeout)
    uav.tick(2, 2, "p-someone-elses")
    st = uav.state_at(rid, 2, timeout)
    assert st is not None, "no RobotState for a tick naming another plan"
    (req,) = world.requests_for(rid, 2)
    assert tuple(req.frm) == tuple(req.to) == (3, 2), f"a tick for another plan must make it stay: {req.frm} -> {req.to}"
    assert tuple(st.cell) == (3, 2)


def test_a_tick_gap_is_executed_from_where_the_robot_stands(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (3, 2), (4, 2), (4, 3)]
    _accepted(uav, rid, "p-gap", path, timeout)
    _run_ticks(uav, world, rid, "p-gap", path, 1, timeout)
    uav.tick(3, 4, "p-gap")               # tick 2 was lost
    st = uav.state_at(rid, 3, timeout)
    assert st is not None, "no RobotState for the tick after a gap"
    assert not world.requests_for(rid, 2)
    (req,) = world.requests_for(rid, 3)
    assert (tuple(req.frm), tuple(req.to)) == ((3, 2), (4, 2)), f"tick 3 after a gap: asked {req.frm} -> {req.to}"
    assert tuple(st.cell) == (4, 2)


def test_sequence_numbers_count_by_one_from_1(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (3, 3)]
    _accepted(uav, rid, "p-seq", path, timeout)
    _run_ticks(uav, world, rid, "p-seq", path, 3, timeout)
    assert uav.until(lambda: bool(uav.dones.get(rid)), timeout), "no Done at the goal"
    time.sleep(QUIET_S)
    per_key = {"PlanAck": [m.seq for m in uav.acks[rid]], "RobotState": [m.seq for m in uav.states[rid]],
               "Done": [m.seq for m in uav.dones[rid]], "MoveRequest": [q for r, q in world.request_seqs if r == rid]}
    for kind, seqs in per_key.items():
        assert all(a < b for a, b in zip(seqs, seqs[1:])), f"{kind} seq not increasing: {seqs}"
    mine = sorted(s for seqs in per_key.values() for s in seqs)
    assert mine == list(range(1, len(mine) + 1)), \
        f"a robot numbers its messages 1, 2, 3, ... with one counter; got {per_key}"
    batches = list(world.batch_seqs)
    assert batches == list(range(1, len(batches) + 1)), f"MoveBatch seq {batches}, expected 1, 2, 3, ..."


# ---------------------------------------------------------------- pools
def _pool_with_plans(spawn, cmd: str, uav, timeout: float, plans: dict[int, str], paths: dict[int, list]) -> list[int]:
    """A pool hosting the robots of `plans` (robot -> plan id), each of which has acknowledged its plan."""
    ids = sorted(plans)
    proc = spawn(cmd, ids)
    assert uav.until(lambda: set(ids) <= uav.alive or proc.poll() is not None, timeout), \
        f"the pool declared tokens {sorted(uav.alive)}, expected {ids}"
    for r in ids:
        _accepted(uav, r, plans[r], paths[r], timeout)
    return ids


POOL_PATHS = {0: [(2, 2), (3, 2), (3, 3)], 1: [(6, 6), (6, 5), (6, 5)]}   # by offset from --robot-id


def test_a_pool_keeps_each_robots_contract(spawn, pool_cmd, uav, world, rid, timeout):
    """A process hosting several robots: each acks, moves once a tick and reports on its own keys and counter."""
    paths = {rid + i: p for i, p in POOL_PATHS.items()}
    # one plan_id for the fleet, as the UAV sends
    ids = _pool_with_plans(spawn, pool_cmd, uav, timeout, dict.fromkeys(paths, "p-pool"), paths)
    for k in (1, 2):
        uav.tick(k, 2, "p-pool")
        for r in ids:
            assert uav.state_at(r, k, timeout) is not None, f"robot {r}: no RobotState for tick {k}"
    with world.cv:
        queries = [(k, robots) for _key, k, robots, _p in world.queries if set(robots) & set(ids)]
    for k in (1, 2):
        mine = [robots for kk, robots in queries if kk == k]
        assert len(mine) == 1, f"tick {k}: the pool asked {len(mine)} queries ({mine}), expected one for all its " \
                               "robots (docs/protocol.md, Plans and ticks)"
    for r in ids:
        for k in (1, 2):
            reqs = world.requests_for(r, k)
            assert len(reqs) == 1, f"robot {r}, tick {k}: {len(reqs)} moves asked, expected one"
            assert (tuple(reqs[0].frm), tuple(reqs[0].to)) == (paths[r][k - 1], paths[r][k]), \
                f"robot {r}, tick {k}: asked {reqs[0].frm} -> {reqs[0].to}"
            assert tuple(uav.state_at(r, k, timeout).cell) == paths[r][k]
    time.sleep(QUIET_S)
    assert not uav.garbage, uav.garbage[:3]
    for r in ids:
        mine = sorted([m.seq for m in uav.acks[r] + uav.states[r]] + [q for x, q in world.request_seqs if x == r])
        assert mine == list(range(1, len(mine) + 1)), f"robot {r} in a pool numbers its own messages: {mine}"
    batches = list(world.batch_seqs)
    assert batches == list(range(1, len(batches) + 1)), f"the pool's MoveBatch seq {batches}, expected 1, 2, 3, ..."


def test_a_pool_told_to_batch_reports_each_robots_state_of_the_tick(spawn, pool_cmd, hub, uav, world, rid, timeout):
    """docs/protocol.md, State batches: a `Tick` with `batch_states` lets a pool put one `StateBatch` on
    `P/robots/<ids>/states` (its own ids, canonical) instead of a `RobotState` per robot. Optional, but
    what it puts must be each robot's state of the tick, once."""
    paths = {rid + i: p for i, p in POOL_PATHS.items()}
    ids = _pool_with_plans(spawn, pool_cmd, uav, timeout, dict.fromkeys(paths, "p-batch"), paths)
    for k in (1, 2):
        uav.tick(k, 2, "p-batch", batch_states=True)
        for r in ids:
            st = uav.state_at(r, k, timeout)
            assert st is not None, f"robot {r}: no state of tick {k} (a RobotState or a StateBatch entry)"
            assert tuple(st.cell) == paths[r][k] and st.plan_id == "p-batch", f"robot {r}, tick {k}: {st}"
    time.sleep(QUIET_S)
    assert not uav.garbage, uav.garbage[:3]
    with uav.cv:
        batches = list(uav.batches)
        counts = {(r, k): sum(s.tick == k for s in uav.states[r]) for r in ids for k in (1, 2)}
    assert all(key == hub.keys.states_as(ids) for key, _ in batches), f"StateBatch keys {batches}"
    assert all(n == 1 for n in counts.values()), f"states per robot and tick {counts}, expected one each"
    seqs = list(uav.batch_seqs)
    assert seqs == list(range(1, len(seqs) + 1)), f"StateBatch seq {seqs}: a pool numbers them 1, 2, 3, ..."


# ---------------------------------------------------------------- moving ahead
def _at(order: list, item: tuple, timeout: float) -> int:
    """Where `item` is in `order` (the router's arrival order), waiting for it up to `timeout`."""
    deadline = time.monotonic() + timeout
    while item not in order:
        assert time.monotonic() < deadline, f"{item} never came; the robot put {order}"
        time.sleep(0.01)
    return order.index(item)


def test_a_robot_moving_ahead_puts_each_move_before_what_the_uav_waits_for(spawn, ahead_cmd, hub, uav, world, rid,
                                                                           timeout):
    """docs/protocol.md, Moving ahead: the move of a plan's first tick before the PlanAck, the move of
    k+1 before the state of k, each on P/world/ahead/<id> naming the plan; the world's MovesJudged,
    not a query, gives the robot its cell; a replan between ticks puts a new move for the next tick."""
    keys = hub.keys
    order: list[tuple[str, int]] = []   # (key, tick or -1) of the robot's puts, as the router got them

    def seen(key: str, payload: bytes) -> None:
        tick = -1
        if "/ahead/" in key or key.endswith("/state"):
            try:
                tick = json.loads(payload)["tick"]
            except (ValueError, KeyError, TypeError):
                pass
        order.append((key, tick))
    h = hub.transport.subscribe(f"{keys.prefix}/**", seen, inline=True)
    try:
        proc = spawn(ahead_cmd)
        assert uav.until(lambda: rid in uav.alive or proc.poll() is not None, timeout), "no liveliness token"
        path = [(2, 2), (3, 2), (3, 3)]
        _accepted(uav, rid, "pa", path, timeout)
        first = world.ahead_for(rid, 1, timeout)
        assert first, "no MoveAhead for tick 1 after the plan was accepted"
        key, msg = first[-1]
        assert key == keys.ahead_as([rid]) and msg.plan_id == "pa", f"MoveAhead on {key} naming {msg.plan_id!r}"
        assert [tuple(map(tuple, m[1:])) for m in msg.moves if m[0] == rid] == [((2, 2), (3, 2))], msg.moves
        assert _at(order, (key, 1), timeout) < _at(order, (keys.ack(rid), -1), timeout), \
            f"the move came after the PlanAck: {order}"
        uav.tick(1, 2, "pa")
        st = uav.state_at(rid, 1, timeout)
        assert st is not None and tuple(st.cell) == (3, 2), f"state of tick 1: {st}"
        second = world.ahead_for(rid, 2, timeout)
        assert second and [tuple(map(tuple, m[1:])) for m in second[-1][1].moves] == [((3, 2), (3, 3))], second
        assert _at(order, (key, 2), timeout) < _at(order, (keys.state(rid), 1), timeout), f"the move of tick 2 came after the " \
            f"state of tick 1: {order}"
        world.refuse.add((rid, 2))
        uav.tick(2, 2, "pa")
        st = uav.state_at(rid, 2, timeout)
        assert st is not None and tuple(st.cell) == (3, 2), f"a refused move: the robot is where the world says: {st}"
        assert world.ahead_for(rid, 3, timeout), "no MoveAhead for tick 3"
        # A replan between ticks: its move for tick 3 replaces the one already put, before its ack.
        uav.plan(rid, "pb", [(3, 2), (2, 2)], start_tick=2)
        ack = uav.ack_for(rid, "pb", timeout)
        assert ack is not None and ack.ok, f"the replan was not accepted: {ack}"
        third = [m for _k, m in world.ahead_for(rid, 3, timeout) if m.plan_id == "pb"]
        assert third and [tuple(map(tuple, m[1:])) for m in third[-1].moves] == [((3, 2), (2, 2))], third
        uav.tick(3, 3, "pb")
        st = uav.state_at(rid, 3, timeout)
        assert st is not None and tuple(st.cell) == (2, 2) and st.plan_id == "pb", f"state of tick 3: {st}"
        assert not world.request_seqs and not world.batch_seqs, "a robot moving ahead asked the world too"
        with world.cv:
            seqs = [m.seq for _k, m in world.aheads]
        assert seqs == list(range(1, len(seqs) + 1)), f"MoveAhead seq {seqs}: numbered 1, 2, 3, ... by one counter"
    finally:
        h.close()


def test_a_pool_moving_ahead_puts_one_move_per_plan_it_holds(spawn, pool_ahead_cmd, hub, uav, world, rid, timeout):
    """docs/protocol.md, Moving ahead, 3: a pool whose robots hold different plans puts one `MoveAhead`
    per `plan_id`, on `P/world/ahead/<ids>` (its own ids, canonical), and takes each robot's cell from the
    `MovesJudged`: on a tick naming one plan, the robot holding the other stays."""
    paths = {rid: [(2, 2), (3, 2), (3, 3)], rid + 1: [(6, 6), (6, 5), (6, 4)]}
    plans = {rid: "pa", rid + 1: "pb"}
    ids = _pool_with_plans(spawn, pool_ahead_cmd, uav, timeout, plans, paths)

    def moves_of(k: int) -> None:
        for r in ids:
            got = world.ahead_for(r, k, timeout)
            assert got, f"robot {r}: no MoveAhead for tick {k}"
            key, msg = got[-1]
            assert key == hub.keys.ahead_as(ids), f"robot {r}: its MoveAhead for tick {k} came on {key}"
            assert msg.plan_id == plans[r], f"robot {r} holds plan {plans[r]}: its move for tick {k} came " \
                                            f"under {msg.plan_id!r} ({msg.moves})"
    moves_of(1)
    uav.tick(1, 2, "pa")
    states = {r: uav.state_at(r, 1, timeout) for r in ids}
    assert states[rid] is not None and tuple(states[rid].cell) == paths[rid][1], f"robot {rid}: {states[rid]}"
    assert states[rid + 1] is not None and tuple(states[rid + 1].cell) == paths[rid + 1][0], \
        f"robot {rid + 1} holds another plan than the tick's: it stays ({states[rid + 1]})"
    moves_of(2)   # put together, after the one MovesJudged of tick 1
    with world.cv:
        asked = [key for key, robots in world.move_keys if set(robots) & set(ids)]
    assert not asked, f"a pool moving ahead asks no query: it asked on {asked}"


# ---------------------------------------------------------------- what it sends, and how
ROBOT_PUTS = {"/ack": "PlanAck", "/state": "RobotState", "/done": "Done", "/states": "StateBatch"}


def _type_of_put(key: str) -> str:
    if "/world/ahead/" in key:
        return "MoveAhead"
    return next(t for suffix, t in ROBOT_PUTS.items() if key.endswith(suffix))


def _unique_keys(pairs):
    keys = [k for k, _v in pairs]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    assert not twice, f"a key written twice: {twice}"
    return dict(pairs)


def _check_well_formed(what: str, payload: bytes, expected: str) -> None:
    assert not payload.startswith(b"\xef\xbb\xbf"), f"{what}: a byte-order mark"
    try:
        body = json.loads(payload.decode("utf-8"), object_pairs_hook=_unique_keys)
    except (UnicodeDecodeError, ValueError) as exc:
        raise AssertionError(f"{what}: not one JSON object in UTF-8: {exc}") from None
    except AssertionError as exc:
        raise AssertionError(f"{what}: {exc}: {payload[:200]!r}") from None
    assert isinstance(body, dict) and body.get("type") == expected, f"{what}: expected a {expected}: {payload[:200]!r}"
    assert type(body.get("v")) is int and body["v"] == 1, f"{what}: `v` must be the integer 1: {payload[:200]!r}"
    decode(payload, MESSAGE_TYPES[expected])   # raises naming the field


def _a_run_to_done(uav, world, rid, timeout, plan_id="p-run") -> None:
    """A refused plan, a plan acknowledged, two ticks, its Done: a bit of everything a robot puts."""
    uav.plan(rid, f"{plan_id}-bad", [(2, 2), (4, 2)])
    assert uav.ack_for(rid, f"{plan_id}-bad", timeout) is not None, "no PlanAck for a malformed plan"
    path = [(2, 2), (3, 2)]
    _accepted(uav, rid, plan_id, path, timeout)
    _run_ticks(uav, world, rid, plan_id, path, 2, timeout)
    assert uav.until(lambda: bool(uav.dones.get(rid)), timeout), "no Done at the goal"
    time.sleep(QUIET_S)


def test_everything_it_sends_is_one_well_formed_message(robot, hub, uav, world, rid, timeout):
    """docs/protocol.md, Messages: one JSON object in UTF-8 without a byte-order mark, `v` the integer 1,
    each key once (another reader may refuse a key written twice), and it decodes."""
    wire = Wire(hub)
    try:
        _a_run_to_done(uav, world, rid, timeout)
        with wire.cv:
            puts = list(wire.puts)
    finally:
        wire.close()
    assert puts, "nothing put"
    for key, payload, _cc in puts:
        _check_well_formed(f"put on {key}", payload, _type_of_put(key))
    with world.cv:
        queries = list(world.queries)
    for key, _k, robots, payload in queries:
        _check_well_formed(f"query on {key}", payload, "MoveBatch" if len(robots) > 1 or b'"MoveBatch"' in payload
                           else "MoveRequest")


def test_every_put_uses_congestion_control_block(robot, hub, uav, world, rid, timeout):
    """docs/protocol.md, QoS: congestion control BLOCK on every put (DROP loses bursts); it travels with each put."""
    wire = Wire(hub)
    try:
        _a_run_to_done(uav, world, rid, timeout)
        with wire.cv:
            puts = [(key, cc) for key, _p, cc in wire.puts]
    finally:
        wire.close()
    assert puts, "nothing put"
    dropped = sorted({key for key, cc in puts if cc != "BLOCK"})
    assert not dropped, f"puts without congestion control BLOCK on {dropped}: {[cc for _k, cc in puts]}"


def test_a_late_answer_within_the_move_timeout_is_taken(robot, uav, world, rid, timeout):
    """docs/protocol.md, QoS: a robot waits 5 s for the world's answer to a move (the world may take its 2 s
    batch timeout and more): an answer after 3 s is an answer, not an error."""
    world.delay_s = 3.0
    path = [(2, 2), (3, 2)]
    _accepted(uav, rid, "p-late", path, timeout)
    uav.tick(1, 1, "p-late")
    st = uav.state_at(rid, 1, max(timeout, MOVE_TIMEOUT_S + 2.0))
    assert st is not None, "no RobotState for tick 1"
    assert st.status != "error" and tuple(st.cell) == (3, 2), \
        f"the world answered after 3 s, within the 5 s move timeout, but the robot reported {st}"


def test_a_query_that_ends_without_a_reply_is_no_answer_at_once(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: a query that ends without a reply (no world serves the key) is no
    answer at once, without waiting out the move timeout."""
    world.answer = False   # the fake world finishes the query at once, without a reply
    _accepted(uav, rid, "p-ended", [(2, 2), (3, 2)], timeout)
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
    _accepted(uav, rid, f"p-other-{other}", [(2, 2), (3, 2)], timeout)
    uav.tick(1, 1, f"p-other-{other}")
    st = uav.state_at(rid, 1, max(timeout, MOVE_TIMEOUT_S + 1.0))
    assert st is not None, "no RobotState when the only reply was for another " + other
    assert st.status == "error" and tuple(st.cell) == (2, 2), \
        f"the only reply named another {other}: no answer, an error state at (2, 2); got {st}"


def test_a_batch_answer_missing_or_adding_robots(spawn, pool_cmd, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: for a pool's MoveBatch, a robot the reply has no entry for gets
    no answer (an error state); the others take theirs; an entry for a robot it did not ask for is ignored."""
    ids = [rid, rid + 1, rid + 2]       # rid + 2 holds no plan: it asks nothing
    proc = spawn(pool_cmd, ids)
    assert uav.until(lambda: set(ids) <= uav.alive or proc.poll() is not None, timeout), "no tokens"
    paths = {rid: [(2, 2), (3, 2)], rid + 1: [(6, 6), (6, 5)]}
    for r, path in paths.items():
        _accepted(uav, r, "p-entries", path, timeout)
    world.batch_with = lambda entries: [e for e in entries if e[0] != rid + 1] + [(rid + 2, True, (9, 9), "")]
    uav.tick(1, 1, "p-entries")
    first = uav.state_at(rid, 1, timeout)
    second = uav.state_at(rid + 1, 1, max(timeout, MOVE_TIMEOUT_S + 1.0))
    time.sleep(QUIET_S)
    assert first is not None and first.status != "error" and tuple(first.cell) == (3, 2), \
        f"robot {rid} had its entry: {first}"
    assert second is not None and second.status == "error" and tuple(second.cell) == (6, 6), \
        f"robot {rid + 1} had no entry in the answer: an error state at (6, 6), got {second}"
    assert not uav.states.get(rid + 2), f"robot {rid + 2} asked nothing, yet reported {uav.states.get(rid + 2)}"


# ---------------------------------------------------------------- what it takes, and what it drops
def _raw(body: dict) -> bytes:
    return json.dumps(body, separators=(",", ":")).encode()


def test_unknown_fields_are_ignored_and_defaults_may_be_left_out(robot, uav, world, rid, timeout):
    """docs/protocol.md, Messages: a receiver ignores fields it does not know, whatever their value; the
    fields with a default (`seq`, `start_tick`, `connectivity`, `batch_states`) may be left out."""
    k = uav.keys
    uav.transport.put(k.plan(rid), _raw({"type": "Plan", "v": 1, "robot": rid, "plan_id": "p-future",
                                         "path": [[2, 2], [3, 2]], "goal": [3, 2],
                                         "priority": {"lane": [1, {"x": None}], "why": "a later version"}}))
    ack = uav.ack_for(rid, "p-future", timeout)
    assert ack is not None and ack.ok, f"a plan with a field the robot does not know was not taken: {ack}"
    uav.transport.put(k.tick, _raw({"type": "Tick", "v": 1, "k": 1, "ticks": 1, "plan_id": "p-future",
                                    "deadline_s": 2.5, "lanes": [[1, 2], [3]]}))
    st = uav.state_at(rid, 1, timeout)
    assert st is not None and tuple(st.cell) == (3, 2), f"a tick with a field the robot does not know: {st}"


def _plan_body(rid: int, plan_id: str, **change) -> dict:
    return {"type": "Plan", "v": 1, "seq": 1, "robot": rid, "plan_id": plan_id, "path": [[2, 2], [3, 2]],
            "goal": [3, 2], **change}


def _dropped(robot, uav, world, rid, timeout, plans: dict[str, bytes], ticks: dict[str, bytes]) -> None:
    """Each of `plans` gets no ack, each of `ticks` no move; then the robot still takes a plan and a tick."""
    k = uav.keys
    for payload in plans.values():
        uav.transport.put(k.plan(rid), payload)
    time.sleep(QUIET_S)
    answered = [(a.plan_id[:40], a.ok) for a in uav.acks.get(rid, [])]
    assert not answered, f"plans that do not decode were answered: {answered} (a PlanAck only for a plan that decodes)"
    assert robot.poll() is None, "the robot died on a payload that does not decode"
    _accepted(uav, rid, "p-good", [(2, 2), (3, 2), (4, 2)], timeout)
    for payload in ticks.values():
        uav.transport.put(k.tick, payload)
    time.sleep(QUIET_S)
    assert not world.requests, f"a tick that does not decode made it move: {world.requests}"
    uav.tick(1, 2, "p-good")
    st = uav.state_at(rid, 1, timeout)
    assert st is not None and tuple(st.cell) == (3, 2), f"tick 1 after the dropped ones: {st}"


def test_a_message_breaking_the_types_is_dropped(robot, uav, world, rid, timeout):
    """docs/protocol.md, Types: a bool is true/false, an int no 2.0 nor true, no NaN anywhere, no lone surrogate."""
    plans = {"p-robot-true": _raw(_plan_body(True, "p-robot-true")),
             "p-float-cell": _raw(_plan_body(rid, "p-float-cell", path=[[2.0, 2], [3, 2]])),
             "p-v-float": _raw(_plan_body(rid, "p-v-float", v=1.0)),
             "p-start-true": _raw(_plan_body(rid, "p-start-true", start_tick=True)),
             "p-nan": _raw(_plan_body(rid, "p-nan")).replace(b'"seq":1', b'"seq":1,"x":NaN'),
             "p-surrogate": _raw(_plan_body(rid, "p-surrogate")).replace(b'"p-surrogate"', b'"p-surrogate\\ud800"')}
    tick = {"type": "Tick", "v": 1, "seq": 9, "k": 1, "ticks": 2, "plan_id": "p-good"}
    ticks = {"k-float": _raw({**tick, "k": 1.0}), "flag-int": _raw({**tick, "batch_states": 1}),
             "ticks-true": _raw({**tick, "ticks": True})}
    _dropped(robot, uav, world, rid, timeout, plans, ticks)


def test_a_message_breaking_a_limit_is_dropped(robot, uav, world, rid, timeout):
    """docs/protocol.md, Limits and value ranges: decode checks them; a message beyond one is dropped whole."""
    deep = [[]]
    for _ in range(33):
        deep = [deep]
    plans = {"p-far-cell": _raw(_plan_body(rid, "p-far-cell", path=[[16383, 2], [16384, 2]], goal=[16384, 2])),
             "p-long-path": _raw(_plan_body(rid, "p-long-path", path=[[2, 2]] * 100_002, goal=[2, 2])),
             "p-deep": _raw(_plan_body(rid, "p-deep", extra=deep)),
             "p-big": _raw(_plan_body(rid, "p-big", extra="x" * (8 * 2**20))),
             "p-robot-id": _raw(_plan_body(10_000_000, "p-robot-id")),
             "p-connectivity": _raw(_plan_body(rid, "p-connectivity", connectivity=6)),
             "p-start-tick": _raw(_plan_body(rid, "p-start-tick", start_tick=100_001)),
             "p-seq": _raw(_plan_body(rid, "p-seq", seq=-1))}
    long_id = "p" * 4097
    plans[long_id] = _raw(_plan_body(rid, long_id))
    tick = {"type": "Tick", "v": 1, "seq": 9, "k": 1, "ticks": 2, "plan_id": "p-good"}
    ticks = {"k-0": _raw({**tick, "k": 0}), "k-over": _raw({**tick, "k": 100_001}),
             "ticks-over": _raw({**tick, "ticks": 100_001})}
    _dropped(robot, uav, world, rid, timeout, plans, ticks)


# ---------------------------------------------------------------- plans: base tick, start cell, ids
def test_a_plan_counts_from_the_highest_tick_seen(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: without `start_tick`, `path[i]` is the cell at tick b + i, b the
    highest tick the robot has seen, ticks heard while it held no plan included."""
    for k in (1, 2, 3):
        uav.tick(k, 3, "p-before-it")
    time.sleep(QUIET_S)
    path = [(2, 2), (3, 2), (4, 2)]
    _accepted(uav, rid, "p-late-join", path, timeout)
    uav.tick(4, 5, "p-late-join")
    assert uav.state_at(rid, 4, timeout) is not None, "no RobotState for tick 4"
    (req,) = world.requests_for(rid, 4)
    assert (tuple(req.frm), tuple(req.to)) == ((2, 2), (3, 2)), \
        f"tick 4, the first after a plan taken at tick 3: asked {req.frm} -> {req.to}, expected path[0] -> path[1]"


def test_a_robot_without_a_plan_asks_nothing(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: a robot that holds no plan does not know its cell: it asks nothing and
    publishes no state for that tick."""
    uav.tick(1, 2, "p-not-yours")
    uav.tick(2, 2, "p-not-yours")
    time.sleep(QUIET_S)
    assert not world.requests_for(rid, 1) and not world.requests_for(rid, 2), "a robot without a plan asked a move"
    assert not uav.states.get(rid), f"a robot without a plan reported {uav.states.get(rid)}"
    assert robot.poll() is None


def test_a_second_plan_before_tick_1_may_start_anywhere(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: until the world's first answer the robot does not know where it
    stands, so it accepts any path[0], a second plan before tick 1 included."""
    _accepted(uav, rid, "p-one", [(2, 2), (3, 2)], timeout)
    uav.plan(rid, "p-two", [(5, 5), (5, 6)])
    ack = uav.ack_for(rid, "p-two", timeout)
    assert ack is not None and ack.ok, f"a second plan before tick 1, starting elsewhere, was refused: {ack}"
    uav.tick(1, 1, "p-two")
    assert uav.state_at(rid, 1, timeout) is not None, "no RobotState for tick 1"
    (req,) = world.requests_for(rid, 1)
    assert (tuple(req.frm), tuple(req.to)) == ((5, 5), (5, 6)), f"tick 1: asked {req.frm} -> {req.to}"


def test_a_plan_id_held_before_is_a_new_plan(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: an id the robot held before is not remembered."""
    _accepted(uav, rid, "p-a", [(2, 2), (3, 2)], timeout)
    _run_ticks(uav, world, rid, "p-a", [(2, 2), (3, 2)], 1, timeout)            # at (3, 2)
    _accepted(uav, rid, "p-b", [(3, 2), (3, 3)], timeout)
    uav.tick(2, 2, "p-b")
    assert uav.state_at(rid, 2, timeout) is not None, "no RobotState for tick 2"   # at (3, 3)
    uav.plan(rid, "p-a", [(3, 3), (4, 3)])
    acks = uav.acks_for(rid, "p-a", 2, timeout)
    assert len(acks) == 2 and acks[1].ok, f"p-a again, from where the robot stands, is a new plan: {acks[1:]}"
    uav.tick(3, 3, "p-a")
    assert uav.state_at(rid, 3, timeout) is not None, "no RobotState for tick 3"
    (req,) = world.requests_for(rid, 3)
    assert (tuple(req.frm), tuple(req.to)) == ((3, 3), (4, 3)), f"tick 3: asked {req.frm} -> {req.to}"


# ---------------------------------------------------------------- statuses
def test_a_tick_for_another_plan_keeps_the_status(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: a robot that stayed on a tick for another plan keeps the status it had
    (`ready` if it has executed no tick of its plan, `done` on its goal)."""
    _accepted(uav, rid, "p-kept", [(2, 2), (3, 2)], timeout)
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
    _accepted(uav, rid, "p-why", path, timeout)
    states = _run_ticks(uav, world, rid, "p-why", path, 4, timeout)   # refused at 2, arrives at 3, refused at 4
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
    _accepted(uav, rid, "p-err", path, timeout)
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
    _accepted(uav, rid, "p-push", path, timeout)
    _run_ticks(uav, world, rid, "p-push", path, 1, timeout)
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


# ---------------------------------------------------------------- Done
def test_done_follows_the_state_of_its_tick(robot, hub, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: Done once, right after the state of the first tick at which the plan
    is over and the robot stands on its goal, naming that tick."""
    wire = Wire(hub)
    try:
        path = [(2, 2), (3, 2)]
        _accepted(uav, rid, "p-order", path, timeout)
        _run_ticks(uav, world, rid, "p-order", path, 1, timeout)
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
    _accepted(uav, rid, "p-here", [(2, 2)], timeout)
    time.sleep(QUIET_S)
    assert not uav.dones.get(rid), f"Done at the acknowledgement: {uav.dones.get(rid)}"
    uav.tick(1, 0, "p-here")
    st = uav.state_at(rid, 1, timeout)
    assert st is not None and st.status == "done", f"tick 1 of a one-cell plan: {st}"
    assert uav.until(lambda: bool(uav.dones.get(rid)), timeout), "no Done at tick 1"
    assert uav.dones[rid][0].tick == 1, f"Done names tick {uav.dones[rid][0].tick}, expected 1"


def test_no_done_on_a_tick_naming_another_plan(robot, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: never a Done on a tick that names another plan."""
    _accepted(uav, rid, "p-mine", [(2, 2)], timeout)
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
    _accepted(uav, rid, "p-once", path, timeout)
    _run_ticks(uav, world, rid, "p-once", path, 1, timeout)
    assert uav.until(lambda: len(uav.dones.get(rid, [])) == 1, timeout), "no Done at the goal"
    uav.plan(rid, "p-once", path)
    assert len(uav.acks_for(rid, "p-once", 2, timeout)) == 2, "the resent plan was not acknowledged again"
    uav.tick(2, 2, "p-once")
    assert uav.state_at(rid, 2, timeout) is not None
    time.sleep(QUIET_S)
    assert len(uav.dones[rid]) == 1, f"a resent plan raised another Done: {uav.dones[rid]}"
    _accepted(uav, rid, "p-again", [(3, 2)], timeout)
    uav.tick(3, 3, "p-again")
    assert uav.until(lambda: len(uav.dones.get(rid, [])) == 2, timeout), "no Done for a plan with a new id"
    assert uav.dones[rid][1].tick == 3


# ---------------------------------------------------------------- keys
def _noncanonical_plan_is_dropped(uav, rid, timeout) -> None:
    k = uav.keys
    uav.transport.put(f"{k.prefix}/robot/00{rid}/plan", encode(Plan(robot=rid, plan_id="p-zeros", path=[(2, 2)],
                                                                     goal=(2, 2))))
    time.sleep(QUIET_S)
    assert not any(a.plan_id == "p-zeros" for a in uav.acks.get(rid, [])), \
        f"a plan on robot/00{rid}/plan was taken: that key names no robot"
    _accepted(uav, rid, "p-canonical", [(2, 2)], timeout)


def test_a_plan_on_a_non_canonical_id_key_is_dropped(robot, uav, rid, timeout):
    """docs/protocol.md, Keys: a single id is decimal without leading zeros; another spelling names no robot."""
    _noncanonical_plan_is_dropped(uav, rid, timeout)


def test_a_pool_drops_a_plan_on_a_non_canonical_id_key(spawn, pool_cmd, uav, rid, timeout):
    proc = spawn(pool_cmd, [rid, rid + 1])
    assert uav.until(lambda: {rid, rid + 1} <= uav.alive or proc.poll() is not None, timeout), "no tokens"
    _noncanonical_plan_is_dropped(uav, rid, timeout)


def test_a_pool_asks_on_the_key_naming_its_robots(spawn, pool_cmd, hub, uav, world, rid, timeout):
    """docs/protocol.md, Keys: `<ids>` in keys in canonical form (`7-8`), however `--ids` spelled them (`7,8`)."""
    paths = {rid + i: p for i, p in POOL_PATHS.items()}
    ids = _pool_with_plans(spawn, pool_cmd, uav, timeout, dict.fromkeys(paths, "p-pool-key"), paths)
    uav.tick(1, 2, "p-pool-key")
    for r in ids:
        assert uav.state_at(r, 1, timeout) is not None, f"robot {r}: no RobotState for tick 1"
    with world.cv:
        keys = sorted({key for key, robots in world.move_keys if set(robots) & set(ids)})
    assert keys == [hub.keys.move_as(ids)], f"the pool asked on {keys}, expected {hub.keys.move_as(ids)}"


def test_a_pool_not_told_to_batch_puts_each_robots_state(spawn, pool_cmd, uav, world, rid, timeout):
    """docs/protocol.md, State batches: without `batch_states` (an older UAV) a pool puts one RobotState per robot."""
    paths = {rid + i: p for i, p in POOL_PATHS.items()}
    ids = _pool_with_plans(spawn, pool_cmd, uav, timeout, dict.fromkeys(paths, "p-unbatched"), paths)
    uav.tick(1, 2, "p-unbatched")
    for r in ids:
        assert uav.state_at(r, 1, timeout) is not None, f"robot {r}: no state of tick 1"
    time.sleep(QUIET_S)
    assert not uav.batches, f"StateBatches to a UAV that did not ask for them: {uav.batches}"


# ---------------------------------------------------------------- moving ahead
def _ahead_robot(spawn, ahead_cmd, uav, rid, timeout, plan_id, path):
    proc = spawn(ahead_cmd)
    assert uav.until(lambda: rid in uav.alive or proc.poll() is not None, timeout), "no liveliness token"
    _accepted(uav, rid, plan_id, path, timeout)
    return proc


def test_a_robot_moving_ahead_puts_its_move_again_for_a_resent_plan(spawn, ahead_cmd, hub, uav, world, rid, timeout):
    """docs/protocol.md, Moving ahead, 1: a plan resent under the id it holds: the MoveAhead again, then the ack."""
    wire = Wire(hub)
    try:
        _ahead_robot(spawn, ahead_cmd, uav, rid, timeout, "pr", [(2, 2), (3, 2)])
        assert world.ahead_for(rid, 1, timeout), "no MoveAhead for tick 1"
        uav.plan(rid, "pr", [(2, 2), (3, 2)])
        assert len(uav.acks_for(rid, "pr", 2, timeout)) == 2, "the resent plan was not acknowledged again"
        wire.until(lambda: wire.count(hub.keys.ack(rid)) >= 2, timeout)
        order = wire.order()
    finally:
        wire.close()
    move, ack = (hub.keys.ahead_as([rid]), 1), (hub.keys.ack(rid), -1)
    moves = [i for i, item in enumerate(order) if item == move]
    acks = [i for i, item in enumerate(order) if item == ack]
    assert len(moves) == 2 and moves[1] < acks[1], f"the resent plan's MoveAhead must come again before its ack: {order}"


def test_a_robot_moving_ahead_ignores_a_judgement_it_took(spawn, ahead_cmd, hub, uav, world, rid, timeout):
    """docs/protocol.md, Moving ahead, 2: entries for a tick it already took are ignored."""
    _ahead_robot(spawn, ahead_cmd, uav, rid, timeout, "pj", [(2, 2), (3, 2), (4, 2)])
    uav.tick(1, 2, "pj")
    assert uav.state_at(rid, 1, timeout) is not None, "no state of tick 1"
    assert world.ahead_for(rid, 2, timeout), "no MoveAhead for tick 2"
    hub.transport.put(hub.keys.judged_as([rid]), encode(MovesJudged(tick=1, plan_id="pj",
                                                                    results=[(rid, True, (3, 2), "")])))
    time.sleep(QUIET_S)
    assert [s.tick for s in uav.states[rid]] == [1], f"states {[s.tick for s in uav.states[rid]]}: tick 1 was taken"
    assert len(world.ahead_for(rid, 2, 0)) == 1, "a judgement taken again put another MoveAhead for tick 2"


def test_a_pool_moving_ahead_puts_no_move_for_a_robot_without_a_plan(spawn, pool_ahead_cmd, uav, world, rid, timeout):
    """docs/protocol.md, Messages (MoveAhead): a robot without a plan knows no cell and puts no move."""
    proc = spawn(pool_ahead_cmd, [rid, rid + 1])
    assert uav.until(lambda: {rid, rid + 1} <= uav.alive or proc.poll() is not None, timeout), "no tokens"
    _accepted(uav, rid, "pn", [(2, 2), (3, 2), (4, 2)], timeout)
    assert world.ahead_for(rid, 1, timeout), "no MoveAhead for tick 1"
    uav.tick(1, 2, "pn")
    assert uav.state_at(rid, 1, timeout) is not None, "no state of tick 1"
    assert world.ahead_for(rid, 2, timeout), "no MoveAhead for tick 2"
    time.sleep(QUIET_S)
    with world.cv:
        named = [m for _k, m in world.aheads if any(x[0] == rid + 1 for x in m.moves)]
    assert not named, f"robot {rid + 1} holds no plan, yet moves were put for it: {named}"


# ---------------------------------------------------------------- life and death
def test_exits_on_sigint(robot, uav, rid, timeout):
    robot.send_signal(signal.SIGINT)
    assert _exits(robot, EXIT_S), f"still running {EXIT_S:g} s after SIGINT"
    assert robot.returncode == 0, f"exit code {robot.returncode}: a robot exits 0 on SIGINT, closing its session"


def test_serves_before_it_has_seen_the_uav(spawn, hub, world, rid, timeout):
    """docs/protocol.md, End of mission: a robot exits when `alive/uav` disappears *after having been seen*;
    started before any UAV, it waits and serves."""
    quiet = FakeUav(hub.transport, hub.keys, announce=False)
    try:
        proc = spawn()
        assert quiet.until(lambda: rid in quiet.alive or proc.poll() is not None, timeout), "no liveliness token"
        time.sleep(1.0)
        assert proc.poll() is None, f"the robot exited ({proc.returncode}) though no UAV had come and gone"
        _accepted(quiet, rid, "p-early", [(2, 2), (3, 2)], timeout)
    finally:
        quiet.close()


def test_exits_with_a_move_query_pending(robot, uav, world, rid, timeout):
    """docs/protocol.md, End of mission: within 5 s, a move query still waiting for its answer abandoned."""
    world.hold = True
    _accepted(uav, rid, "p-pending", [(2, 2), (3, 2)], timeout)
    uav.tick(1, 1, "p-pending")
    assert world.until(lambda: bool(world.requests_for(rid, 1)), timeout), "no move asked for tick 1"
    uav.end(True, "conformance")
    assert _exits(robot, EXIT_S), f"still running {EXIT_S:g} s after MissionEnd, its move query pending"
    assert not uav.states.get(rid), f"a state for the abandoned tick: {uav.states.get(rid)}"


def test_an_undecodable_mission_end_is_dropped(robot, uav, world, rid, timeout):
    """docs/protocol.md, End of mission: a MissionEnd that does not decode is dropped like any other message."""
    k = uav.keys
    for payload in (b"", b"{}", b"end", _wrong_version(MissionEnd(completed=True)),
                    b'{"type":"MissionEnd","v":1,"completed":"yes"}', encode(Tick(k=1, ticks=1, plan_id="x"))):
        uav.transport.put(k.mission_end, payload)
    time.sleep(1.0)
    assert robot.poll() is None, f"the robot exited ({robot.returncode}) on a mission end that does not decode"
    _accepted(uav, rid, "p-still-here", [(2, 2)], timeout)


def test_waits_for_a_router_at_start(robot_cmd, rid, timeout, tmp_path):
    """docs/protocol.md, Timeouts and waits: a robot waits up to 20 s for a router at start."""
    endpoint, fleet = free_endpoint(), new_fleet_name()
    proc = start_robot(robot_cmd, rid, fleet, endpoint, tmp_path / "robot-early.log")
    try:
        time.sleep(2.0)
        assert proc.poll() is None, f"the robot exited ({proc.returncode}) 2 s after it started without a router"
        with Hub(fleet, endpoint=endpoint) as hub:
            uav = FakeUav(hub.transport, hub.keys)
            try:
                assert uav.until(lambda: rid in uav.alive or proc.poll() is not None, timeout + 5.0), \
                    "no liveliness token after the router came up"
                assert proc.poll() is None, f"the robot exited ({proc.returncode})"
            finally:
                uav.close()
    finally:
        stop_process(proc)


def test_every_plan_ack_states_the_protocol_it_keeps(robot, uav, robot_protocol, rid, timeout):
    """docs/protocol.md, Versioning: every PlanAck states `protocol`, the version of this document's rules the
    robot keeps (2; none stated means 1)."""
    uav.plan(rid, "p-version-bad", [(2, 2), (4, 2)])
    assert uav.ack_for(rid, "p-version-bad", timeout) is not None, "no PlanAck for a malformed plan"
    _accepted(uav, rid, "p-version", [(2, 2), (3, 2)], timeout)
    stated = sorted({a.protocol for a in uav.acks[rid]})
    assert stated == [robot_protocol], f"its PlanAcks state protocol {stated}, expected {robot_protocol} in every one"


def test_a_mission_end_put_as_the_token_appears_is_received(robot, uav, rid):
    """docs/protocol.md, Startup order: `mission/end` is subscribed before the token is declared."""
    uav.end(True, "conformance")
    assert _exits(robot, EXIT_S), f"still running {EXIT_S:g} s after a MissionEnd put as its token appeared"


def test_a_robot_moving_ahead_reports_nothing_without_a_judgement(spawn, ahead_cmd, uav, world, rid, timeout):
    """docs/protocol.md, Moving ahead: a robot moving ahead that gets no MovesJudged reports nothing for that tick."""
    _ahead_robot(spawn, ahead_cmd, uav, rid, timeout, "pq", [(2, 2), (3, 2)])
    world.judge_ahead = False
    uav.tick(1, 1, "pq")
    time.sleep(MOVE_TIMEOUT_S + 1.0)
    assert not uav.states.get(rid), f"states without a MovesJudged: {uav.states.get(rid)}"


def test_dropped_messages_cost_one_warning_line_a_second(robot, uav, rid, timeout, tmp_path):
    """docs/protocol.md, Refused messages: at most one warning line a second, what the sender chose escaped."""
    log = tmp_path / "robot-0.log"
    time.sleep(QUIET_S)
    before = log.read_bytes().count(b"\n")
    k = uav.keys
    for i in range(100):
        uav.transport.put(k.plan(rid), b'{"type":"Plan","v":1,"robot":"line\\nbreak %d"}' % i)
        uav.transport.put(k.tick, b"\x1b[2J garbage\n\n%d" % i)
    time.sleep(1.5)
    _accepted(uav, rid, "p-after-flood", [(2, 2)], timeout)   # it got through the flood
    lines = log.read_bytes().count(b"\n") - before
    assert lines <= 4, f"{lines} lines for 200 dropped messages in about a second:\n" + \
        log.read_text(errors="replace")[-1500:]


def test_seq_is_not_acted_on(robot, uav, world, rid, timeout):
    """docs/protocol.md, Sequence numbers: no receiver acts on `seq` (a UAV restarted counts from 1 again)."""
    k = uav.keys
    path = [(2, 2), (3, 2), (4, 2)]
    uav.transport.put(k.plan(rid), encode(Plan(robot=rid, plan_id="p-seq-1", path=path, goal=path[-1], seq=50)))
    assert uav.ack_for(rid, "p-seq-1", timeout) is not None, "no PlanAck"
    uav.transport.put(k.tick, encode(Tick(k=1, ticks=2, plan_id="p-seq-1", seq=7)))
    assert uav.state_at(rid, 1, timeout) is not None, "a tick with a lower seq than the plan's was not executed"
    uav.transport.put(k.tick, encode(Tick(k=2, ticks=2, plan_id="p-seq-1", seq=7)))
    assert uav.state_at(rid, 2, timeout) is not None, "a tick repeating the last tick's seq was not executed"
    uav.transport.put(k.plan(rid), encode(Plan(robot=rid, plan_id="p-seq-2", path=[(4, 2), (4, 3)], goal=(4, 3),
                                               seq=1)))
    ack = uav.ack_for(rid, "p-seq-2", timeout)
    assert ack is not None and ack.ok, f"a plan with seq 1 after one with seq 50: {ack}"
