"""Robot conformance: moving ahead, a robot's moves put before the tick (optional; docs/protocol.md, Moving ahead).

The suite plays hub, UAV and world around the robot under test, started from
`--robot-cmd` (conftest.py). See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import json
import time

from conformance import Wire
from conformance.robot_steps import MOVE_TIMEOUT_S, QUIET_S, accepted, pool_with_plans
from protocol.messages import MovesJudged
from protocol.codec import encode


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
        accepted(uav, rid, "pa", path, timeout)
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
    ids = pool_with_plans(spawn, pool_ahead_cmd, uav, timeout, plans, paths)

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


def _ahead_robot(spawn, ahead_cmd, uav, rid, timeout, plan_id, path):
    proc = spawn(ahead_cmd)
    assert uav.until(lambda: rid in uav.alive or proc.poll() is not None, timeout), "no liveliness token"
    accepted(uav, rid, plan_id, path, timeout)
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
    accepted(uav, rid, "pn", [(2, 2), (3, 2), (4, 2)], timeout)
    assert world.ahead_for(rid, 1, timeout), "no MoveAhead for tick 1"
    uav.tick(1, 2, "pn")
    assert uav.state_at(rid, 1, timeout) is not None, "no state of tick 1"
    assert world.ahead_for(rid, 2, timeout), "no MoveAhead for tick 2"
    time.sleep(QUIET_S)
    with world.cv:
        named = [m for _k, m in world.aheads if any(x[0] == rid + 1 for x in m.moves)]
    assert not named, f"robot {rid + 1} holds no plan, yet moves were put for it: {named}"


def test_a_robot_moving_ahead_reports_nothing_without_a_judgement(spawn, ahead_cmd, uav, world, rid, timeout):
    """docs/protocol.md, Moving ahead: a robot moving ahead that gets no MovesJudged reports nothing for that tick."""
    _ahead_robot(spawn, ahead_cmd, uav, rid, timeout, "pq", [(2, 2), (3, 2)])
    world.judge_ahead = False
    uav.tick(1, 1, "pq")
    time.sleep(MOVE_TIMEOUT_S + 1.0)
    assert not uav.states.get(rid), f"states without a MovesJudged: {uav.states.get(rid)}"
