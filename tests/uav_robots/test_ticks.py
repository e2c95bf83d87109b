"""The lockstep's fast paths: a pool's StateBatch, the UAV's reading of it, and `bench ticks` end to end."""
from __future__ import annotations

import csv
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from protocol.codec import encode
from protocol.keys import Keys
from protocol.messages import Plan, StateBatch, Tick
from protocol.transport import MemoryBus, MemoryTransport
from robot_agents.agent import run_robots
from sim_world.config import WorldConfig
from sim_world.service import World
from scenes import open_map
from uav_agent.fleet import FleetLink
from uav_robots.bench.lockstep import lanes

REPO = Path(__file__).resolve().parents[2]
T = 5.0
ROWS = 3
PATHS = {r: [(x, r) for x in range(5)] for r in range(ROWS)}


def test_a_state_batch_counts_only_for_the_robots_its_key_names():
    bus, keys = MemoryBus(), Keys("t")
    link = FleetLink(MemoryTransport(bus), keys)
    link.clock = 2          # the mission has put Tick(2)
    pool = MemoryTransport(bus)
    try:
        batch = StateBatch(tick=2, states=[(0, (1, 0), "stepping", "p", ""), (1, (1, 1), "stepping", "p", ""),
                                           (7, (9, 9), "stepping", "p", "")])   # 7: not a robot of this pool
        pool.put(keys.states_as([0, 1]), encode(batch))
        pool.put(f"{keys.prefix}/robots/x/states", encode(batch))                 # a key naming no ids
        pool.put(keys.states_as([0, 1]), b"\x00garbage")
        assert link.cells == {0: (1, 0), 1: (1, 1)} and link.last_tick == {0: 2, 1: 2}
        assert link.rejected == 3
        assert link.wait_tick([0, 1], 2, 0.5, interrupt=lambda: False) == {}
        assert link.wait_tick([0, 1, 7], 2, 0.2, interrupt=lambda: False) == {"stalled": [7]}
        link.clock = 3      # Tick(3) is out: before it, a state for tick 3 is nobody's (U23)
        pool.put(keys.states_as([0, 1]), encode(StateBatch(tick=3, states=[(1, (1, 1), "error", "p", "stuck")])))
        assert link.wait_tick([0, 1], 3, 0.5, interrupt=lambda: False) == {"lost": [], "error": [1]}
    finally:
        link.close()


def test_a_pool_batches_its_states_only_when_the_tick_asks(tmp_path):
    m, s = open_map(tmp_path, [p[0] for p in PATHS.values()], [p[-1] for p in PATHS.values()])
    bus, keys = MemoryBus(), Keys("mem")
    world = World(WorldConfig(fleet="mem", map=m, scen=s, robots=ROWS, mavlink=None), MemoryTransport(bus))
    world.start()
    uav = MemoryTransport(bus)
    link = FleetLink(uav, keys)
    singles, batches = [], []
    uav.subscribe(keys.all_states, lambda _k, p: singles.append(p))
    uav.subscribe(keys.all_state_batches, lambda k, p: batches.append(k))
    pool = threading.Thread(target=run_robots, args=(range(ROWS), MemoryTransport(bus), "mem"))
    pool.start()
    try:
        link.wait_until(lambda: len(link.alive) == ROWS, T, lambda: f"alive {link.alive}")
        for r, p in PATHS.items():
            uav.put(keys.plan(r), encode(Plan(robot=r, plan_id="p", path=p, goal=p[-1])))
        link.wait_until(lambda: len(link.acks) == ROWS, T, lambda: f"acks {link.acks}")
        ticks = len(PATHS[0]) - 1
        for k in range(1, ticks + 1):
            uav.put(keys.tick, encode(Tick(k=k, ticks=ticks, plan_id="p", batch_states=k > 1)))
            assert link.wait_tick(list(PATHS), k, T, interrupt=lambda: False) == {}
            assert link.cells == {r: p[k] for r, p in PATHS.items()}
        # Tick 1 without the flag: one RobotState per robot; the later ticks: one batch each, on the pool's key.
        assert len(singles) == ROWS and len(batches) == ticks - 1
        assert set(batches) == {keys.states_as(range(ROWS))}
        rec = world.record()
        assert rec.ticks == ticks and rec.collisions == 0
    finally:
        uav.put(keys.mission_end, b'{"type":"MissionEnd","v":1,"completed":true}')
        pool.join(T)
        link.close()
        world.close()
    assert not pool.is_alive()


def test_lanes_never_meet():
    lane = lanes(45)
    for k in range(3 * 8):
        cells = [lane.cell(r, k) for r in range(45)]
        assert len(set(cells)) == 45
        assert all(0 <= x < lane.width and 0 <= y < lane.height for x, y in cells)
    assert all(abs(a[0] - b[0]) == 1 for a, b in zip(lane.path(3, 20), lane.path(3, 20)[1:]))


@pytest.mark.slow
@pytest.mark.process
def test_bench_ticks_runs_real_processes(tmp_path):
    """A small run of the benchmark: real world, robot and echo processes over Zenoh, both hostings."""
    done = subprocess.run([sys.executable, "-m", "uav_robots", "bench", "ticks", "--robots", "4", "--ticks", "20",
                           "--pools", "2", "--moves", "ahead,query", "--out", str(tmp_path)], cwd=REPO,
                          capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    rows = list(csv.DictReader(open(tmp_path / "ticks.csv")))
    assert [(r["robots"], r["processes"], r["moves"]) for r in rows] == [
        ("4", "4", "ahead"), ("4", "4", "query"), ("4", "2", "ahead"), ("4", "2", "query")]
    for r in rows:
        assert float(r["ticks_per_s"]) > 0 and float(r["barrier_ticks_per_s"]) > 0
        assert r["collisions"] == "0" and r["refused"] == "0"
    assert "bare barrier" in (tmp_path / "ticks.md").read_text()


@pytest.mark.process
def test_bench_ticks_bad_input_is_one_line():
    done = subprocess.run([sys.executable, "-m", "uav_robots", "bench", "ticks", "--ticks", "5"], cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2 and "warm-up" in done.stderr and "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1



def test_the_live_view_and_the_recording_read_a_pools_batch(tmp_path):
    from uav_robots.record.observer import Sample
    from uav_robots.record.recording import read_mcap, write_mcap
    from uav_robots.view.state import FleetView

    keys = Keys("v")
    batch = encode(StateBatch(tick=4, states=[(0, (2, 1), "stepping", "p", ""), (1, (3, 1), "done", "p", "")]))
    view = FleetView()
    view.apply(keys.states_as([0, 1]), batch)
    assert view.robots == {0: (2, 1, "stepping"), 1: (3, 1, "done")} and view.tick == 4
    counts = write_mcap(tmp_path / "m.mcap", [Sample(1, keys.states_as([0, 1]), batch)], keys.prefix,
                        ["....", "...."], 1.0)
    assert counts["/fleet/state"] == 2
    rec = read_mcap(tmp_path / "m.mcap")
    assert rec.cells == {0: {4: (2, 1)}, 1: {4: (3, 1)}} and rec.ticks == 4


def test_access_control_lets_a_pool_put_only_its_own_batch():
    from protocol.security import access_control, robot_identity

    keys = Keys("f")
    acl = access_control("f", [robot_identity([0, 1, 2]), robot_identity([3, 4, 5])])
    puts = {r["id"].split("/")[0]: r["key_exprs"] for r in acl["rules"]
            if r["messages"] == ["put"] and r["flows"] == ["ingress"]}
    assert keys.states_as([0, 1, 2]) in puts["robots-0-2"] and keys.states_as([3, 4, 5]) not in puts["robots-0-2"]
    assert keys.states_as([3, 4, 5]) in puts["robots-3-5"]
