"""Robot conformance: a pool hosting several robots keeps each one's contract (docs/protocol.md, Keys; State batches).

The suite plays hub, UAV and world around the robot under test, started from
`--robot-cmd` (conftest.py). See docs/protocol.md, "Conformance".
"""
from __future__ import annotations

import time

from conformance.robot_steps import (MOVE_TIMEOUT_S, POOL_PATHS, QUIET_S, accepted, noncanonical_plan_is_dropped,
                                     pool_with_plans)


def test_a_pool_keeps_each_robots_contract(spawn, pool_cmd, uav, world, rid, timeout):
    """A process hosting several robots: each acks, moves once a tick and reports on its own keys and counter."""
    paths = {rid + i: p for i, p in POOL_PATHS.items()}
    # one plan_id for the fleet, as the UAV sends
    ids = pool_with_plans(spawn, pool_cmd, uav, timeout, dict.fromkeys(paths, "p-pool"), paths)
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
    ids = pool_with_plans(spawn, pool_cmd, uav, timeout, dict.fromkeys(paths, "p-batch"), paths)
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


def test_a_pool_not_told_to_batch_puts_each_robots_state(spawn, pool_cmd, uav, world, rid, timeout):
    """docs/protocol.md, State batches: without `batch_states` (an older UAV) a pool puts one RobotState per robot."""
    paths = {rid + i: p for i, p in POOL_PATHS.items()}
    ids = pool_with_plans(spawn, pool_cmd, uav, timeout, dict.fromkeys(paths, "p-unbatched"), paths)
    uav.tick(1, 2, "p-unbatched")
    for r in ids:
        assert uav.state_at(r, 1, timeout) is not None, f"robot {r}: no state of tick 1"
    time.sleep(QUIET_S)
    assert not uav.batches, f"StateBatches to a UAV that did not ask for them: {uav.batches}"


def test_a_pool_asks_on_the_key_naming_its_robots(spawn, pool_cmd, hub, uav, world, rid, timeout):
    """docs/protocol.md, Keys: `<ids>` in keys in canonical form (`7-8`), however `--ids` spelled them (`7,8`)."""
    paths = {rid + i: p for i, p in POOL_PATHS.items()}
    ids = pool_with_plans(spawn, pool_cmd, uav, timeout, dict.fromkeys(paths, "p-pool-key"), paths)
    uav.tick(1, 2, "p-pool-key")
    for r in ids:
        assert uav.state_at(r, 1, timeout) is not None, f"robot {r}: no RobotState for tick 1"
    with world.cv:
        keys = sorted({key for key, robots in world.move_keys if set(robots) & set(ids)})
    assert keys == [hub.keys.move_as(ids)], f"the pool asked on {keys}, expected {hub.keys.move_as(ids)}"


def test_a_batch_answer_missing_or_adding_robots(spawn, pool_cmd, uav, world, rid, timeout):
    """docs/protocol.md, Plans and ticks: for a pool's MoveBatch, a robot the reply has no entry for gets
    no answer (an error state); the others take theirs; an entry for a robot it did not ask for is ignored."""
    ids = [rid, rid + 1, rid + 2]       # rid + 2 holds no plan: it asks nothing
    proc = spawn(pool_cmd, ids)
    assert uav.until(lambda: set(ids) <= uav.alive or proc.poll() is not None, timeout), "no tokens"
    paths = {rid: [(2, 2), (3, 2)], rid + 1: [(6, 6), (6, 5)]}
    for r, path in paths.items():
        accepted(uav, r, "p-entries", path, timeout)
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


def test_a_pool_drops_a_plan_on_a_non_canonical_id_key(spawn, pool_cmd, uav, rid, timeout):
    proc = spawn(pool_cmd, [rid, rid + 1])
    assert uav.until(lambda: {rid, rid + 1} <= uav.alive or proc.poll() is not None, timeout), "no tokens"
    noncanonical_plan_is_dropped(uav, rid, timeout)
