"""Robots: the state machine alone, a pool with the real world in memory, and processes over Zenoh."""
from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import pytest

from conformance import FakeUav, Hub, stop_process
from protocol.errors import UavRobotsError
from protocol.keys import Keys
from protocol.messages import MoveResult, Plan, Tick
from protocol.transport import MemoryBus, MemoryTransport
from robot_agents.agent import format_ids, parse_ids, run_robots
from robot_agents.robot import RobotMachine
from sim_world.config import WorldConfig
from sim_world.service import World
from scenes import open_map, robot_process

REPO = Path(__file__).resolve().parents[2]
T = 5.0


def plan(path, pid="p1", robot=0, goal=None):
    return Plan(robot=robot, plan_id=pid, path=list(path), goal=goal if goal is not None else path[-1])


def res(tick, cell, ok=True, robot=0):
    return MoveResult(robot=robot, tick=tick, accepted=ok, cell=cell, reason="" if ok else "blocked")


# ------------------------------------------------------------ the machine
@pytest.mark.parametrize("p,conn,words", [
    (plan([], goal=(0, 0)), 4, "empty path"),
    (plan([(0, 0), (1, 1)]), 4, "not a 4-connected"),
    (plan([(0, 0), (2, 0)]), 8, "not a 8-connected"),
    (plan([(0, 0), (1, 0)], goal=(3, 3)), 4, "not at the goal"),
    (plan([(0, 0)], robot=3), 4, "for robot 3"),
    (plan([(0, -1)]), 4, "negative"),
])
def test_malformed_plans_are_refused(p, conn, words):
    m = RobotMachine(0, conn)
    ack = m.on_plan(p)
    assert not ack.ok and words in ack.error and ack.robot == 0 and m.state == "idle"


def test_the_plan_states_its_connectivity():
    diagonal = [(0, 0), (1, 1)]
    assert RobotMachine(0, 4).on_plan(Plan(robot=0, plan_id="p8", path=diagonal, goal=(1, 1), connectivity=8)).ok
    refused = RobotMachine(0, 8).on_plan(Plan(robot=0, plan_id="p4", path=diagonal, goal=(1, 1), connectivity=4))
    assert not refused.ok and "not a 4-connected" in refused.error
    assert RobotMachine(0, 8).on_plan(plan(diagonal)).ok   # not stated: the robot's own setting


def test_a_plan_is_walked_and_done_is_raised_once():
    m = RobotMachine(0)
    assert m.on_plan(plan([(0, 0), (1, 0), (1, 1)])).ok and m.state == "ready"
    assert m.on_plan(plan([(0, 0), (1, 0), (1, 1)])).ok  # the same plan resent: acknowledged again
    assert not m.on_plan(plan([(0, 0), (0, 1)])).ok      # another path under the same id
    dones = []
    for k, cell in enumerate([(1, 0), (1, 1), (1, 1), (1, 1)], 1):
        assert m.classify(Tick(k=k, ticks=2, plan_id="p1")) == "run"
        step = m.target(k, "p1")
        assert step.to == cell and m.state in ("stepping", "done")
        state, done = m.on_move_result(res(k, cell))
        assert state.cell == cell and state.tick == k
        dones += [done] if done else []
    assert m.state == "done" and len(dones) == 1 and dones[0].tick == 2 and dones[0].cell == (1, 1)
    assert m.classify(Tick(k=3, ticks=2, plan_id="p1")) == "old"
    assert m.classify(Tick(k=9, ticks=2, plan_id="p1")) == "gap"


def test_a_refused_move_keeps_the_real_cell():
    m = RobotMachine(0)
    m.on_plan(plan([(0, 0), (1, 0), (2, 0)]))
    m.classify(Tick(k=1, ticks=2, plan_id="p1"))
    m.target(1)
    state, done = m.on_move_result(res(1, (0, 0), ok=False))
    assert state.cell == (0, 0) and state.error == "blocked" and done is None and state.status == "stepping"
    m.classify(Tick(k=2, ticks=2, plan_id="p1"))
    step = m.target(2)
    assert (step.frm, step.to) == ((0, 0), (2, 0))  # it asks for its plan cell; the world will judge


def test_replans_ticks_of_other_plans_and_no_answer():
    m = RobotMachine(0)
    m.on_plan(plan([(0, 0), (1, 0), (2, 0)]))
    m.classify(Tick(k=1, ticks=2, plan_id="p1"))
    m.target(1, "p1")
    m.on_move_result(res(1, (1, 0)))
    assert not m.on_plan(plan([(0, 0), (0, 1)], pid="p2")).ok  # not where the robot stands
    assert m.on_plan(plan([(1, 0), (1, 1)], pid="p2")).ok      # a replan from here: path[1] at tick 2
    m.classify(Tick(k=2, ticks=2, plan_id="p2"))
    assert m.target(2, "p2").to == (1, 1)
    m.on_move_result(res(2, (1, 1)))
    m.classify(Tick(k=3, ticks=3, plan_id="stale"))
    step = m.target(3, "stale")
    assert step.frm == step.to == (1, 1)  # a tick for a plan it does not hold: stay
    state = m.on_no_result(step, "no answer")
    assert state.status == "error" and state.cell == (1, 1) and state.tick == 3


def test_id_ranges():
    assert parse_ids("0-3,7,10-11") == [0, 1, 2, 3, 7, 10, 11]
    assert format_ids([0, 1, 2, 3, 7, 10, 11]) == "0-3,7,10-11"
    for bad in ("", "a", "3-1", "-2"):
        with pytest.raises(UavRobotsError):
            parse_ids(bad)


# ------------------------------------------------- the pool and the world


ROWS = 4  # robot r walks row r from x = 0 to x = 5: plans without conflicts
PATHS = {r: [(x, r) for x in range(6)] for r in range(ROWS)}


def mission(uav: FakeUav, paths: dict[int, list], pid: str = "m1") -> int:
    """The UAV's side in lockstep: plans, acks, ticks with a barrier. Returns the makespan."""
    assert uav.until(lambda: set(paths) <= uav.alive, T), f"alive: {uav.alive}"
    for r, p in paths.items():
        uav.plan(r, pid, p)
    for r in paths:
        ack = uav.ack_for(r, pid, T)
        assert ack is not None and ack.ok, ack
    ticks = max(len(p) for p in paths.values()) - 1
    for k in range(1, ticks + 1):
        uav.tick(k, ticks, pid)
        for r in paths:
            assert uav.state_at(r, k, T) is not None, f"robot {r} missed tick {k}"
    return ticks


def test_pool_and_world_in_memory(tmp_path):
    m, s = open_map(tmp_path, [p[0] for p in PATHS.values()], [p[-1] for p in PATHS.values()])
    bus = MemoryBus()
    world = World(WorldConfig(fleet="mem", map=m, scen=s, robots=ROWS, mavlink=None), MemoryTransport(bus))
    world.start()
    uav = FakeUav(MemoryTransport(bus), Keys("mem"))
    codes: list[int] = []
    pool_thread = threading.Thread(target=lambda: codes.append(run_robots(range(ROWS), MemoryTransport(bus), "mem")))
    pool_thread.start()
    try:
        ticks = mission(uav, PATHS)
        assert uav.until(lambda: len(uav.dones) == ROWS, T)
        rec = world.record()
        assert rec.ticks == ticks and rec.collisions == 0
        assert {int(r): cells for r, cells in rec.executed.items()} == PATHS
        assert all(len(d) == 1 for d in uav.dones.values())
        uav.end(True)
        pool_thread.join(T)
        assert not pool_thread.is_alive() and codes == [0]
    finally:
        uav.close()
        world.close()
        pool_thread.join(T)


def test_pool_leaves_when_the_uav_goes_away(capsys):
    bus = MemoryBus()
    uav = FakeUav(MemoryTransport(bus), Keys("gone"))
    stop = threading.Event()
    t = threading.Thread(target=run_robots, args=([0, 1], MemoryTransport(bus), "gone"), kwargs={"stop": stop})
    t.start()
    try:
        assert uav.until(lambda: uav.alive == {0, 1}, T)
        uav.tick(1, 1, "nothing")  # no plan, no known cell: nothing to do, no crash
        uav.transport.put(uav.keys.plan(0), b"junk")
        uav.until(lambda: False, 0.3)
        uav.leave()
        t.join(T)
        assert not t.is_alive()
        err = capsys.readouterr().err
        assert "robots 0-1: ignored plan: Plan: payload is not JSON" in err and "Traceback" not in err
        assert not uav.states, "a robot without a plan or a known cell must not invent a state"
    finally:
        stop.set()
        t.join(T)
        uav.close()


@pytest.mark.process
def test_pool_process_over_zenoh_with_a_conflict(tmp_path):
    """A pool of 4 robot processes' worth in one process; robots 2 and 3 are sent head-on into each other."""
    paths = dict(PATHS)
    paths[2] = [(1, 2), (2, 2), (3, 2)]
    paths[3] = [(4, 2), (3, 2), (2, 2)]  # at tick 2, robots 2 and 3 try to swap cells
    m, s = open_map(tmp_path, [p[0] for p in paths.values()], [p[-1] for p in paths.values()])
    with Hub() as hub:
        world = World(WorldConfig(fleet=hub.fleet, map=m, scen=s, robots=4, mavlink=None, connect=[hub.endpoint]))
        world.start()
        uav = FakeUav(hub.transport, hub.keys)
        proc = robot_process(hub, "0-3")
        try:
            ticks = mission(uav, paths)
            rec = world.record()
            assert rec.collisions >= 2 and rec.ticks == ticks
            assert any("swap" in e["reason"] for e in rec.refused)
            for r in (2, 3):
                last = uav.states[r][-1]
                assert last.cell == tuple(rec.executed[str(r)][-1]), "a robot must report where the world put it"
                assert last.cell != paths[r][-1] and not uav.dones.get(r)
            # A robot publishes Done right after its last state: wait for it, as the UAV does.
            assert uav.until(lambda: set(uav.dones) == {0, 1}, T), f"dones: {set(uav.dones)}"
            uav.end(False, "test over")
            assert proc.wait(15) == 0
            assert "mission ended: test over" in proc.stdout.read()
        finally:
            stop_process(proc)
            uav.close()
            world.close()


@pytest.mark.process
def test_robot_cli_errors_are_one_line():
    for args in (["--fleet", "f"], ["--fleet", "f", "--ids", "x-y"], ["--fleet", "no good", "--id", "1"]):
        run = subprocess.run([sys.executable, "-m", "robot_agents", *args], cwd=REPO, capture_output=True,
                             text=True, timeout=30)
        assert run.returncode == 2 and run.stderr.startswith("error:") and len(run.stderr.strip().splitlines()) == 1


def _zenoh_threads(pid: int) -> set[str]:
    """Names of the process's Zenoh runtime threads (Tokio names them app-0, rx-1, ...)."""
    names = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
        except OSError:
            continue   # a thread that just ended
        if name.split("-")[0] in ("app", "acc", "tx", "rx", "net"):
            names.add(name.split("-")[0])
    return names


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="reads thread names from /proc")
@pytest.mark.parametrize("ids, env, lean", [
    ("0", {}, True),                           # one robot: one runtime of one worker
    ("0-1", {}, False),                        # a pool keeps Zenoh's runtimes
    ("0", {"ZENOH_RUNTIME": "()"}, False),     # the user's setting wins
])
@pytest.mark.process
def test_a_lone_robot_runs_one_zenoh_runtime(ids, env, lean):
    import os

    with Hub() as hub:
        proc = subprocess.Popen([sys.executable, "-m", "robot_agents", "--ids", ids, "--fleet", hub.fleet,
                                 "--connect", hub.endpoint], cwd=REPO, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, start_new_session=True,
                                env={**{k: v for k, v in os.environ.items() if k != "ZENOH_RUNTIME"}, **env})
        try:
            assert "ready" in proc.stdout.readline()
            threads = _zenoh_threads(proc.pid)
            # a client has no acceptor; Zenoh's own runtimes include rx, tx and net beside app
            assert (threads == {"app"}) if lean else ({"app", "tx", "rx", "net"} <= threads), threads
        finally:
            stop_process(proc)
