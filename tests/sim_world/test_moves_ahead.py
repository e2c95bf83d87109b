"""Moving ahead (docs/protocol.md): robots put each move one tick early and are paced by the world's
answers, side by side with robots that ask on each Tick, in one fleet."""
from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from protocol.codec import decode, encode
from protocol.keys import Keys, format_ids, new_fleet_name
from protocol.messages import MoveAhead, MovesJudged, Plan, Record, RecordRequest, Tick
from protocol.transport import MemoryBus, MemoryTransport
from scenes import open_map
from sim_world.config import WorldConfig
from sim_world.service import World
from uav_agent.fleet import FleetLink
from uav_robots.bench.lockstep import Children, lanes, local_endpoint, open_hub, write_scen

T = 20.0


def _start(n: int, groups: list[tuple[list[int], str]], ticks: int, tmp: Path):
    lane = lanes(n)
    scen = tmp / "lanes.scen"
    write_scen(lane, ticks, scen)
    fleet, endpoint = new_fleet_name(), local_endpoint()
    kids = Children()
    common = ["--fleet", fleet, "--connect", endpoint]
    kids.spawn("sim_world", [*common, "--map", f"random:width={lane.width},height={lane.height},density=0",
                             "--robots", str(n), "--scen", str(scen), "--mavlink", "none",
                             "--camera", "ideal,width=64,height=48"], tmp / "world.log")
    for ids, moves in groups:
        kids.spawn("robot_agents", [*common, "--ids", format_ids(ids), "--moves", moves], tmp / f"robots-{ids[0]}.log")
    return lane, Keys(fleet), endpoint, kids


def _logs(tmp: Path) -> str:
    return "\n".join(f"{p.name}: {p.read_text(errors='replace')[-800:]}" for p in sorted(tmp.glob("*.log")))


@pytest.mark.parametrize("batch_states", [False, True])
@pytest.mark.process
def test_a_mixed_fleet_with_a_replan_between_ticks(tmp_path, batch_states):
    """Lone robots and a pool moving ahead, a lone robot and a pool asking: one world judges them all;
    a new plan that arrives between ticks replaces the move a robot already put ahead."""
    n, ticks, switch = 8, 12, 5
    groups = [([0], "ahead"), ([1], "ahead"), ([2], "query"), ([3, 4, 5], "ahead"), ([6, 7], "query")]
    lane, keys, endpoint, kids = _start(n, groups, ticks, tmp_path)
    ids = list(range(n))
    # After the switch every robot walks back the way it came: a plan its old moves contradict.
    back = {r: [lane.cell(r, switch - i) for i in range(switch + 1)] for r in ids}
    with open_hub(endpoint) as hub:
        fl = FleetLink(hub, keys)
        try:
            fl.wait_until(lambda: fl.world_alive and len(fl.alive) == n, T,
                          lambda: f"{len(fl.alive)} robots up; logs:\n{_logs(tmp_path)}", kids.dead)
            for r in ids:
                hub.put(keys.plan(r), encode(Plan(robot=r, plan_id="a", path=lane.path(r, ticks),
                                                  goal=lane.cell(r, ticks), connectivity=4)))
            fl.wait_until(lambda: len(fl.acks) == n, T, lambda: f"acks {fl.acks}", kids.dead)
            for k in range(1, switch + 1):
                hub.put(keys.tick, encode(Tick(k=k, ticks=ticks, plan_id="a", batch_states=batch_states)))
                assert fl.wait_tick(ids, k, T, interrupt=lambda: False) == {}, _logs(tmp_path)
                assert {r: fl.cells.get(r) for r in ids} == {r: lane.cell(r, k) for r in ids}
            fl.acks.clear()
            for r in ids:
                hub.put(keys.plan(r), encode(Plan(robot=r, plan_id="b", path=back[r], goal=back[r][-1],
                                                  start_tick=switch, connectivity=4)))
            fl.wait_until(lambda: len(fl.acks) == n and all(a.ok for a in fl.acks.values()), T,
                          lambda: f"acks of the replan {fl.acks}", kids.dead)
            for k in range(switch + 1, 2 * switch + 3):
                hub.put(keys.tick, encode(Tick(k=k, ticks=2 * switch, plan_id="b", batch_states=batch_states)))
                assert fl.wait_tick(ids, k, T, interrupt=lambda: False) == {}, _logs(tmp_path)
                want = {r: back[r][min(k - switch, switch)] for r in ids}
                assert {r: fl.cells.get(r) for r in ids} == want, f"tick {k}"
            fl.wait_until(lambda: set(fl.done) >= set(ids), T, lambda: f"done {sorted(fl.done)}", kids.dead)
            rec = decode(hub.request(keys.record, encode(RecordRequest()), T)[0], Record)
            assert rec.ticks == 2 * switch + 2 and rec.collisions == 0 and not rec.refused
        finally:
            fl.close()
            kids.stop()


@pytest.mark.process
def test_a_tick_for_another_plan_makes_an_ahead_robot_stay(tmp_path):
    """A robot that missed the Tick's plan: its move put ahead under its own plan is judged a stay."""
    lane, keys, endpoint, kids = _start(2, [([0], "ahead"), ([1], "ahead")], 6, tmp_path)
    with open_hub(endpoint) as hub:
        fl = FleetLink(hub, keys)
        try:
            fl.wait_until(lambda: fl.world_alive and len(fl.alive) == 2, T, lambda: _logs(tmp_path), kids.dead)
            for r in (0, 1):
                hub.put(keys.plan(r), encode(Plan(robot=r, plan_id="a", path=lane.path(r, 6),
                                                  goal=lane.cell(r, 6), connectivity=4)))
            fl.wait_until(lambda: len(fl.acks) == 2, T, lambda: f"acks {fl.acks}", kids.dead)
            for k in (1, 2):
                hub.put(keys.tick, encode(Tick(k=k, ticks=6, plan_id="a" if k == 1 else "other")))
                assert fl.wait_tick([0, 1], k, T, interrupt=lambda: False) == {}
            assert fl.cells == {0: lane.cell(0, 1), 1: lane.cell(1, 1)}, "tick 2 names another plan: both stay"
        finally:
            fl.close()
            kids.stop()


def _memory_world(tmp_path, n=2):
    cells = [(0, r) for r in range(n)]
    m, s = open_map(tmp_path, cells, cells)
    bus, keys = MemoryBus(), Keys("mem")
    world = World(WorldConfig(fleet="mem", map=m, scen=s, robots=n, mavlink=None, move_batch_timeout_s=0.3),
                  MemoryTransport(bus))
    world.start()
    got: list[tuple[str, MovesJudged]] = []
    probe = MemoryTransport(bus)
    probe.subscribe(f"{keys.prefix}/world/judged/*", lambda k, p: got.append((k, decode(p, MovesJudged))))
    return world, probe, keys, got


def test_the_world_judges_moves_put_ahead_only_for_the_robots_their_key_names(tmp_path, capsys):
    world, probe, keys, got = _memory_world(tmp_path)
    try:
        # Robot 1's key carries a move of robot 0: refused whole, never half-applied.
        probe.put(keys.ahead_as([1]), encode(MoveAhead(tick=1, plan_id="p", moves=[(0, (0, 0), (1, 0))])))
        probe.put(keys.ahead_as([0]), encode(MoveAhead(tick=1, plan_id="p", moves=[(0, (0, 0), (1, 0))])))
        probe.put(keys.ahead_as([0]), b"garbage")
        probe.put(keys.ahead_as([0]), encode(MoveAhead(tick=50, plan_id="p", moves=[(0, (0, 0), (1, 0))])))
        assert got == [], "nothing is judged before the Tick"
        probe.put(keys.tick, encode(Tick(k=1, ticks=3, plan_id="p")))
        # Robot 1 sent nothing: the tick waits for it until the batch timeout makes it stay.
        deadline = time.monotonic() + 5.0
        while not got and time.monotonic() < deadline:
            time.sleep(0.02)
        assert [(k, j.tick, j.plan_id, j.results) for k, j in got] == \
            [(keys.judged_as([0]), 1, "p", [(0, True, (1, 0), "")])]
        # A move for a tick long judged is answered at once, refused.
        probe.put(keys.ahead_as([0]), encode(MoveAhead(tick=1, plan_id="p", moves=[(0, (1, 0), (2, 0))])))
        assert got[-1][1].results[0][1] is False and "over" in got[-1][1].results[0][3]
        # A Tick that jumps (lost Ticks, or not the UAV's) is said, not taken in silence.
        time.sleep(1.1)   # past the warnings' one-line-a-second throttle
        probe.put(keys.tick, encode(Tick(k=9, ticks=12, plan_id="p")))
        assert "Tick 9 follows Tick 1" in capsys.readouterr().err
    finally:
        world.close()


def test_a_robot_that_vanished_after_putting_its_move_does_not_move(tmp_path):
    world, probe, keys, got = _memory_world(tmp_path)
    try:
        token = probe.announce(keys.alive_robot(1))
        probe.put(keys.ahead_as([0]), encode(MoveAhead(tick=1, plan_id="p", moves=[(0, (0, 0), (1, 0))])))
        probe.put(keys.ahead_as([1]), encode(MoveAhead(tick=1, plan_id="p", moves=[(1, (0, 1), (1, 1))])))
        token.close()   # robot 1 dies before the Tick: a querying robot would have asked nothing
        probe.put(keys.tick, encode(Tick(k=1, ticks=3, plan_id="p")))
        assert [j.results for _k, j in got] == [[(0, True, (1, 0), "")]]
        assert world.judge.positions[1] == (0, 1)
    finally:
        world.close()


def test_access_control_lets_a_robot_put_moves_ahead_and_read_answers_only_under_its_own_ids():
    from protocol.security import WORLD, Identity, access_control, robot_identity

    keys = Keys("f")
    acl = access_control("f", [robot_identity([3]), robot_identity([4, 5]), Identity(WORLD)])
    rules = {(r["id"].split("/")[0], tuple(r["messages"]), r["flows"][0]): r["key_exprs"] for r in acl["rules"]}
    puts = [k for (who, m, f), ks in rules.items() if who == "robot-3" and "put" in m and f == "ingress" for k in ks]
    assert keys.ahead_as([3]) in puts and keys.ahead_as([4, 5]) not in puts
    heard = [k for (who, m, f), ks in rules.items() if who == "robot-3" and "put" in m and f == "egress" for k in ks]
    assert keys.judged_as([3]) in heard and keys.judged_as([4, 5]) not in heard
    world = [k for (who, m, f), ks in rules.items() if who == "world" and "put" in m and f == "ingress" for k in ks]
    assert f"{keys.prefix}/world/judged/*" in world


if __name__ == "__main__":
    sys.exit(pytest.main([__file__, "-q"]))
