"""The runs `uav-robots bench ticks` measures (`ticks.py` is the command): the lockstep execution loop,
and the bare barrier beside it.

What one measured tick is: the driver (standing in for the UAV, with the UAV's own FleetLink)
puts Tick k and waits until every robot reported its RobotState for k; in between each
robot asks the real world process whether its move is possible, the world judges the whole
tick and answers. Real processes, real Zenoh on loopback, the driver as the hub, as in
`uav-robots run`. The plan is fixed and collision-free: every robot paces its own lane back
and forth, so every tick moves every robot and the world checks every move.

The ceiling is measured in the same run: a bare Zenoh barrier with the same number of
processes (the hub puts a tick, each process answers it with one put, the hub waits for all),
nothing decoded, nothing judged.

    python -m uav_robots.bench.lockstep --echo --fleet F --connect tcp/127.0.0.1:PORT --name 3
"""
from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from protocol.errors import MissionError
from protocol.keys import Keys, format_ids, new_fleet_name
from protocol.process import die_with_parent

from ..common.robot_groups import robot_groups

MOVES = ("ahead", "query")   # robot_agents --moves
SPAN = 8                 # cells of a robot's lane: it walks SPAN steps one way, then back
WARMUP_TICKS = 10        # not timed: the first ticks open publishers and fill caches
READY_TIMEOUT_S = 120.0  # 1,000 robots in a few processes on 2 busy cores take a while to declare
TICK_TIMEOUT_S = 30.0


@dataclass(frozen=True)
class Lanes:
    """A fixed collision-free plan: robot i paces the lane that starts at starts[i]."""
    width: int
    height: int
    starts: list[tuple[int, int]]

    def cell(self, robot: int, k: int) -> tuple[int, int]:
        x, y = self.starts[robot]
        phase = k % (2 * SPAN)
        return (x + (phase if phase <= SPAN else 2 * SPAN - phase), y)

    def path(self, robot: int, ticks: int) -> list[tuple[int, int]]:
        return [self.cell(robot, k) for k in range(ticks + 1)]


def lanes(n: int) -> Lanes:
    """Lanes of SPAN+1 cells, a free cell between lanes and a free row between rows of lanes."""
    per_row = max(1, min(n, 20))
    rows = math.ceil(n / per_row)
    starts = [((i % per_row) * (SPAN + 2), 2 * (i // per_row)) for i in range(n)]
    return Lanes(per_row * (SPAN + 2), max(2 * rows, 2), starts)


def write_scen(lane: Lanes, ticks: int, path: Path) -> None:
    lines = ["version 1"]
    for r, (x, y) in enumerate(lane.starts):
        gx, gy = lane.cell(r, ticks)
        lines.append(f"0\tlanes\t{lane.width}\t{lane.height}\t{x}\t{y}\t{gx}\t{gy}\t0")
    path.write_text("\n".join(lines) + "\n")


# ----------------------------------------------------------------- processes
class Children:
    def __init__(self) -> None:
        self.procs: list[subprocess.Popen] = []

    def spawn(self, module: str, argv: list[str], log: Path) -> None:
        with open(log, "wb") as out:
            self.procs.append(subprocess.Popen([sys.executable, "-m", module, *argv], stdout=out,
                                               stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                               preexec_fn=die_with_parent))

    def cpu_s(self) -> float | None:
        """CPU seconds used so far by this process and the children (None where /proc is not there)."""
        total = sum(os.times()[:2])
        for p in self.procs:
            try:
                fields = Path(f"/proc/{p.pid}/stat").read_text().rsplit(")", 1)[1].split()
            except (OSError, IndexError):
                return None
            total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
        return total

    def dead(self) -> str:
        for p in self.procs:
            if p.poll() not in (None, 0):
                return f"{' '.join(p.args[2:4])} exited with code {p.returncode}"
        return ""

    def stop(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + 5.0
        for p in self.procs:
            try:
                p.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(5)


def open_hub(endpoint: str):
    from protocol.transport import open_session
    return open_session("bench", listen=[endpoint])


def local_endpoint() -> str:
    from ..common.ports import free_port
    return f"tcp/127.0.0.1:{free_port()}"


@dataclass
class Measured:
    ticks: int
    seconds: float
    cpu_s: float | None = None     # CPU of every process of the run over the timed ticks
    collisions: int = 0
    refused: int = 0

    @property
    def cpu_ms_per_tick(self) -> float | None:
        return None if self.cpu_s is None else 1000 * self.cpu_s / self.ticks

    @property
    def rate(self) -> float:
        return self.ticks / self.seconds if self.seconds > 0 else 0.0


def run_mission(n: int, per_process: int, ticks: int, tmp: Path, moves: str = "ahead") -> Measured:
    """Real world and robot processes execute the lane plan; ticks/s over the timed ticks."""
    from protocol.codec import decode, encode
    from protocol.messages import MissionEnd, Plan, Record, RecordRequest, Tick
    from uav_agent.fleet import FleetLink

    lane = lanes(n)
    scen = tmp / f"lanes-{n}.scen"
    write_scen(lane, ticks, scen)
    fleet, endpoint = new_fleet_name(), local_endpoint()
    keys = Keys(fleet)
    kids = Children()
    with open_hub(endpoint) as hub:
        fl = FleetLink(hub, keys)
        try:
            common = ["--fleet", fleet, "--connect", endpoint]
            kids.spawn("sim_world", [*common, "--map", f"random:width={lane.width},height={lane.height},density=0",
                                     "--robots", str(n), "--scen", str(scen), "--mavlink", "none",
                                     "--camera", "ideal,width=64,height=48"], tmp / f"world-{n}.log")
            for g in robot_groups(n, per_process):
                kids.spawn("robot_agents", [*common, "--ids", format_ids(g), "--moves", moves], tmp / f"robots-{n}-{g[0]}.log")
            ids = list(range(n))
            fl.wait_until(lambda: fl.world_alive and len(fl.alive) == n, READY_TIMEOUT_S,
                          lambda: f"{len(fl.alive)}/{n} robots and {'a' if fl.world_alive else 'no'} world ready "
                                  f"within {READY_TIMEOUT_S:g} s", kids.dead)
            for r in ids:
                hub.put(keys.plan(r), encode(Plan(robot=r, plan_id="lanes", path=lane.path(r, ticks),
                                                  goal=lane.cell(r, ticks), connectivity=4)))
            fl.wait_until(lambda: len(fl.acks) == n, READY_TIMEOUT_S,
                          lambda: f"{len(fl.acks)}/{n} robots acknowledged the plan", kids.dead)
            refused = [r for r, a in fl.acks.items() if not a.ok]
            if refused:
                raise MissionError(f"robot {refused[0]} refused the lane plan: {fl.acks[refused[0]].error}")
            t0, cpu0 = 0.0, None
            for k in range(1, ticks + 1):
                if k == WARMUP_TICKS + 1:
                    t0, cpu0 = time.perf_counter(), kids.cpu_s()
                hub.put(keys.tick, encode(Tick(k=k, ticks=ticks, plan_id="lanes", batch_states=True)))
                faults = fl.wait_tick(ids, k, TICK_TIMEOUT_S, interrupt=lambda: False)
                if faults:
                    raise MissionError(f"tick {k}: {faults}")
                # As the UAV does after every tick: a robot off its plan would need a repair, not a figure.
                with fl.cv:
                    off = [r for r in ids if fl.cells.get(r) != lane.cell(r, k)]
                if off:
                    raise MissionError(f"tick {k}: robot(s) {off[:5]} off the plan (the world's answer: "
                                       f"{fl.cells.get(off[0])}; a robot process late past the world's move "
                                       "timeout is made to stay)")
            seconds, cpu1 = time.perf_counter() - t0, kids.cpu_s()
            replies = hub.request(keys.record, encode(RecordRequest()), 30.0)
            if not replies:
                raise MissionError("the world did not answer the record request")
            rec = decode(replies[0], Record)
            hub.put(keys.mission_end, encode(MissionEnd(completed=True)))
            if rec.ticks != ticks:
                raise MissionError(f"the world judged {rec.ticks} ticks, not {ticks}")
            # The plan is collision-free: any refusal is a fault of the loop, not a figure to print.
            if rec.collisions or rec.refused:
                raise MissionError(f"the world counted {rec.collisions} collision(s) and {len(rec.refused)} refused "
                                   f"move(s), first: {rec.refused[0] if rec.refused else '-'}")
            cpu = cpu1 - cpu0 if cpu0 is not None and cpu1 is not None else None
            return Measured(ticks - WARMUP_TICKS, seconds, cpu, rec.collisions, len(rec.refused))
        finally:
            fl.close()
            kids.stop()


def run_barrier(processes: int, ticks: int, tmp: Path) -> Measured:
    """The ceiling: `processes` echo processes, one put each per tick, nothing decoded."""
    fleet, endpoint = new_fleet_name(), local_endpoint()
    keys = Keys(fleet)
    kids = Children()
    cv = threading.Condition()
    got: dict[int, int] = {}
    alive: set[str] = set()

    def on_ack(_key: str, payload: bytes) -> None:
        k = int(payload)
        with cv:
            got[k] = got.get(k, 0) + 1
            if got[k] == processes:
                cv.notify_all()

    def on_alive(key: str, up: bool) -> None:
        with cv:
            (alive.add if up else alive.discard)(key)
            cv.notify_all()

    def wait(ready, what: str, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        with cv:
            while not ready():
                left = deadline - time.monotonic()
                if left <= 0 or kids.dead():
                    raise MissionError(kids.dead() or f"bare barrier: {what} within {timeout:g} s")
                cv.wait(min(left, 0.5))

    with open_hub(endpoint) as hub:
        hub.subscribe(f"{keys.prefix}/bench/ack/*", on_ack)
        hub.watch_alive(f"{keys.prefix}/bench/alive/*", on_alive)
        try:
            for i in range(processes):
                kids.spawn("uav_robots.bench.lockstep", ["--echo", "--fleet", fleet, "--connect", endpoint,
                                                      "--name", str(i)], tmp / f"echo-{i}.log")
            wait(lambda: len(alive) == processes, f"{len(alive)}/{processes} echo processes ready", READY_TIMEOUT_S)
            t0, cpu0 = 0.0, None
            for k in range(1, ticks + 1):
                if k == WARMUP_TICKS + 1:
                    t0, cpu0 = time.perf_counter(), kids.cpu_s()
                hub.put(f"{keys.prefix}/bench/tick", str(k).encode())
                wait(lambda: got.get(k, 0) >= processes, f"tick {k} answered", TICK_TIMEOUT_S)
            seconds, cpu1 = time.perf_counter() - t0, kids.cpu_s()
            cpu = cpu1 - cpu0 if cpu0 is not None and cpu1 is not None else None
            return Measured(ticks - WARMUP_TICKS, seconds, cpu)
        finally:
            kids.stop()


def echo_main(argv: list[str]) -> int:
    """One process of the bare barrier: answer every tick with one put."""
    from protocol.transport import lean_runtime, open_session

    p = argparse.ArgumentParser(prog="python -m uav_robots.bench.lockstep --echo")
    p.add_argument("--echo", action="store_true")
    p.add_argument("--fleet", required=True)
    p.add_argument("--connect", required=True)
    p.add_argument("--name", required=True)
    a = p.parse_args(argv)
    prefix = Keys(a.fleet).prefix
    stop = threading.Event()
    lean_runtime()   # as a robot process hosting one robot
    with open_session(f"echo {a.name}", connect=[a.connect]) as t:
        ack = f"{prefix}/bench/ack/{a.name}"
        t.subscribe(f"{prefix}/bench/tick", lambda _k, payload: t.put(ack, payload))
        t.announce(f"{prefix}/bench/alive/{a.name}")
        # The hub's token going away would be the natural end; the bench terminates its echoes instead.
        stop.wait()
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] == ["--echo"]:
        sys.exit(echo_main(sys.argv[1:]))
    sys.stderr.write("usage: python -m uav_robots.bench.lockstep --echo ... (run the benchmark with "
                     "`uav-robots bench ticks`)\n")
    sys.exit(2)
