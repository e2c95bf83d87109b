"""Robot conformance: does a robot implementation keep the uav-robots protocol?

The suite is hub, UAV and world at once (a Zenoh router on a free loopback
port, a fake UAV, a fake move service) and starts the robot under test from
`--robot-cmd`. See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import json
import signal
import time

import pytest

from conformance import signal_group
from protocol.messages import Plan, Tick, encode

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
    assert not any(a.plan_id == "p-v99" for a in uav.acks.get(rid, [])), "a wrong-version plan was acted on"
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
    assert robot.returncode in (0, -signal.SIGTERM)


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
