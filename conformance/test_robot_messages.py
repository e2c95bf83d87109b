"""Robot conformance: what a robot puts and how, what it takes and what it drops (docs/protocol.md, Keys, Messages).

The suite plays hub, UAV and world around the robot under test, started from
`--robot-cmd` (conftest.py). See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import json
import time

from conformance import Wire
from conformance.robot_steps import QUIET_S, accepted, noncanonical_plan_is_dropped, run_ticks, wrong_version
from protocol.messages import MESSAGE_TYPES, Plan, Tick
from protocol.codec import decode, encode


def test_messages_name_the_robot_of_their_key(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2)]
    accepted(uav, rid, "p-keys", path, timeout)
    run_ticks(uav, world, rid, "p-keys", path, 2, timeout)
    uav.until(lambda: bool(uav.dones.get(rid)), timeout)
    time.sleep(QUIET_S)
    assert not uav.garbage, f"messages on robot {rid}'s keys that name another robot or do not decode: {uav.garbage[:3]}"
    for msg in uav.acks[rid] + uav.states[rid] + uav.dones.get(rid, []):
        assert msg.robot == rid, f"{type(msg).__name__} on robot {rid}'s key names robot {msg.robot}"


def test_sequence_numbers_count_by_one_from_1(robot, uav, world, rid, timeout):
    path = [(2, 2), (3, 2), (3, 3)]
    accepted(uav, rid, "p-seq", path, timeout)
    run_ticks(uav, world, rid, "p-seq", path, 3, timeout)
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
    accepted(uav, rid, plan_id, path, timeout)
    run_ticks(uav, world, rid, plan_id, path, 2, timeout)
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


def test_garbage_and_wrong_versions_do_not_crash_it(robot, uav, world, rid, timeout):
    k = uav.keys
    junk = [b"", b"\x00\xff garbage", b"{}", b"[1,2,3]", b'{"type":"Plan","v":1}',
            wrong_version(Plan(robot=rid, plan_id="p-v99", path=[(1, 1)], goal=(1, 1)))]
    for payload in junk:
        uav.transport.put(k.plan(rid), payload)
    for payload in junk[:4] + [wrong_version(Tick(k=1, ticks=1, plan_id="p-v99")), encode(Plan(
            robot=rid, plan_id="x", path=[(1, 1)], goal=(1, 1)))]:
        uav.transport.put(k.tick, payload)
    time.sleep(QUIET_S)
    assert robot.poll() is None, "the robot died on garbage"
    assert not world.requests, "garbage on the tick key made the robot move"
    assert not uav.acks.get(rid), f"plans that do not decode were answered: {uav.acks.get(rid)} (no PlanAck, " \
                                  "not even ok: false: the robot cannot trust their robot and plan_id)"
    path = [(2, 2), (2, 3)]
    accepted(uav, rid, "p-after", path, timeout)
    (st,) = run_ticks(uav, world, rid, "p-after", path, 1, timeout)
    assert tuple(st.cell) == (2, 3)


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
    accepted(uav, rid, "p-good", [(2, 2), (3, 2), (4, 2)], timeout)
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


def test_a_plan_on_a_non_canonical_id_key_is_dropped(robot, uav, rid, timeout):
    """docs/protocol.md, Keys: a single id is decimal without leading zeros; another spelling names no robot."""
    noncanonical_plan_is_dropped(uav, rid, timeout)


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
    accepted(uav, rid, "p-after-flood", [(2, 2)], timeout)   # it got through the flood
    lines = log.read_bytes().count(b"\n") - before
    assert lines <= 4, f"{lines} lines for 200 dropped messages in about a second:\n" + \
        log.read_text(errors="replace")[-1500:]
