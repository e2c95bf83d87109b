"""`uav-robots bench ticks`: lockstep ticks per second of the execution loop, beside the bare barrier.

What one measured tick is: the driver (standing in for the UAV, with the UAV's own FleetLink)
puts Tick k and waits until every robot reported its RobotState for k; in between each
robot asks the real world process whether its move is possible, the world judges the whole
tick and answers. Real processes, real Zenoh on loopback, the driver as the hub, as in
`uav-robots run`. The plan is fixed and collision-free: every robot paces its own lane back
and forth, so every tick moves every robot and the world checks every move.

The ceiling is measured in the same run: a bare Zenoh barrier with the same number of
processes (the hub puts a tick, each process answers it with one put, the hub waits for all),
nothing decoded, nothing judged.

    uav-robots bench ticks --robots 50,500,1000 --ticks 300
    python -m uav_robots.bench_ticks --echo --fleet F --connect tcp/127.0.0.1:PORT --name 3
"""
from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from protocol.errors import MissionError, UavRobotsError
from protocol.keys import Keys, format_ids, new_fleet_name
from protocol.process import die_with_parent

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


def hosting(n: int, per_process: int) -> list[list[int]]:
    return [list(range(i, min(n, i + per_process))) for i in range(0, n, per_process)]


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


def _hub(endpoint: str):
    from protocol.transport import open_session
    return open_session("bench", listen=[endpoint])


def _endpoint() -> str:
    from .launcher import free_port
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
    fleet, endpoint = new_fleet_name(), _endpoint()
    keys = Keys(fleet)
    kids = Children()
    with _hub(endpoint) as hub:
        fl = FleetLink(hub, keys)
        try:
            common = ["--fleet", fleet, "--connect", endpoint]
            kids.spawn("sim_world", [*common, "--map", f"random:width={lane.width},height={lane.height},density=0",
                                     "--robots", str(n), "--scen", str(scen), "--mavlink", "none",
                                     "--camera", "ideal,width=64,height=48"], tmp / f"world-{n}.log")
            for g in hosting(n, per_process):
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
    fleet, endpoint = new_fleet_name(), _endpoint()
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

    with _hub(endpoint) as hub:
        hub.subscribe(f"{keys.prefix}/bench/ack/*", on_ack)
        hub.watch_alive(f"{keys.prefix}/bench/alive/*", on_alive)
        try:
            for i in range(processes):
                kids.spawn("uav_robots.bench_ticks", ["--echo", "--fleet", fleet, "--connect", endpoint,
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

    p = argparse.ArgumentParser(prog="python -m uav_robots.bench_ticks --echo")
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


# ----------------------------------------------------------------- the command
def _ms(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}"


def _round(v: float | None) -> float | None:
    return None if v is None else round(v, 2)


def _load() -> str:
    try:
        return " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "unknown"


def _hosting_text(n: int, per_process: int) -> str:
    groups = len(hosting(n, per_process))
    return "one process per robot" if per_process == 1 else f"{groups} pool(s) of up to {per_process}"


def hostings_for(n: int, max_processes: int, pools: int) -> list[int]:
    """Robots per process to measure: one process per robot up to `max_processes` robots, and `pools`
    processes sharing the fleet (both where both apply)."""
    out = [1] if n <= max_processes else []
    per = math.ceil(n / pools)
    if per > 1:
        out.append(per)
    return out


def run(args: argparse.Namespace) -> int:
    from .bench import _markdown, _print, _save, _sizes

    sizes = _sizes(args.robots)
    if args.ticks <= WARMUP_TICKS:
        raise UavRobotsError(f"--ticks must be more than the {WARMUP_TICKS} warm-up ticks, got {args.ticks}")
    if args.max_processes < 1 or args.pools < 1:
        raise UavRobotsError("--max-processes and --pools must be at least 1")
    modes = [m.strip() for m in args.moves.split(",") if m.strip()]
    if not modes or any(m not in MOVES for m in modes) or len(set(modes)) != len(modes):
        raise UavRobotsError(f"--moves {args.moves!r}: give ahead, query or both (ahead,query)")
    load_before = _load()
    rows, summary = [], []
    with tempfile.TemporaryDirectory(prefix="uavr-bench-ticks-") as tmp_s:
        tmp = Path(tmp_s)
        for n in sizes:
            for per in hostings_for(n, args.max_processes, args.pools):
                procs = len(hosting(n, per))
                missions = {}
                for mode in modes:
                    _print(f"{n} robots, {_hosting_text(n, per)}, moves {mode}: mission ...")
                    try:
                        missions[mode] = run_mission(n, per, args.ticks, tmp, mode)
                    except MissionError as exc:
                        raise UavRobotsError(f"bench ticks, {n} robots in {procs} process(es), moves {mode}: "
                                             f"{exc}") from None
                    _print(f"  {missions[mode].rate:.1f} ticks/s")
                _print(f"  bare barrier with {procs} process(es) ...")
                try:
                    b = run_barrier(procs, args.ticks, tmp)
                except MissionError as exc:
                    raise UavRobotsError(f"bench ticks, barrier of {procs}: {exc}") from None
                _print(f"  {b.rate:.1f} ticks/s")
                for mode, m in missions.items():
                    rows.append([str(n), _hosting_text(n, per), str(procs), mode, f"{m.rate:.1f}",
                                 _ms(m.cpu_ms_per_tick), f"{b.rate:.1f}", _ms(b.cpu_ms_per_tick),
                                 f"{m.rate / b.rate:.2f}", f"{m.collisions}", f"{m.refused}"])
                    summary.append({"robots": n, "processes": procs, "per_process": per, "moves": mode,
                                    "ticks": m.ticks, "mission_s": round(m.seconds, 4), "ticks_per_s": round(m.rate, 2),
                                    "cpu_ms_per_tick": _round(m.cpu_ms_per_tick),
                                    "barrier_ticks_per_s": round(b.rate, 2),
                                    "barrier_cpu_ms_per_tick": _round(b.cpu_ms_per_tick), "collisions": m.collisions,
                                    "refused": m.refused})
    load_after = _load()
    header = ["robots", "hosting", "processes", "moves", "ticks/s", "CPU ms/tick", "bare barrier ticks/s",
              "barrier CPU ms/tick", "ticks/s / barrier", "collisions", "refused moves"]
    notes = [
        f"Boundary: in-process ticks/s of the lockstep loop, {args.ticks - WARMUP_TICKS} timed ticks after "
        f"{WARMUP_TICKS} warm-up ticks; from the hub's put of Tick k to every robot's RobotState of tick k, "
        "through real robot and world processes over Zenoh on loopback (start-up, plans and shut-down not timed).",
        "Moves: ahead = every robot puts its move one tick ahead and is paced by the world's answers (one wake "
        "a tick); query = every robot asks the world on each Tick (docs/protocol.md, Plans and ticks). Each mode "
        "is its own mission, one after the other, then the barrier, all in this run.",
        "Plan: every robot paces its own lane (8 cells, back and forth), so every tick moves every robot and the "
        "world judges every move; collisions and refused moves are the world's record (any makes the run fail), "
        "and every robot must end where the plan puts it.",
        f"Hosting: one process per robot up to {args.max_processes} robots, and {args.pools} pools (robot processes "
        "hosting many robots) at every count.",
        "CPU ms/tick: CPU time of every process of the run (hub, world, robots; or hub and echoes) over the timed "
        "ticks, per tick: on a loaded machine the rate falls with the share of the cores the run gets, this less so.",
        "Bare barrier: the same number of processes, each answering every tick with one put; nothing decoded or "
        "judged: the transport's ceiling for this process count, measured in the same run.",
        ("Zenoh's runtimes: one (`protocol.transport.lean_runtime`) in each process hosting one robot and "
         "each process of the bare barrier, Zenoh's own in the hub, the world and the pools."
         if "ZENOH_RUNTIME" not in os.environ else
         f"Zenoh's runtimes: ZENOH_RUNTIME=`{os.environ['ZENOH_RUNTIME']}` in every process of the run."),
        f"Machine: {os.cpu_count()} cores; load average (1/5/15 min) {load_before} before, {load_after} after.",
    ]
    text = _markdown(header, rows) + "\n\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    _save(args.out, "ticks", "# Lockstep ticks per second\n\n" + text, summary, summary)
    _print(text)
    return 0


def add_parser(sub) -> None:
    p = sub.add_parser("ticks", help="lockstep ticks/s of the execution loop beside the bare Zenoh barrier",
                       description="Ticks per second of the lockstep execution loop (real world and robot "
                                   "processes over Zenoh, a fixed collision-free plan), beside a bare Zenoh "
                                   "barrier with the same process count measured in the same run.")
    p.add_argument("--robots", default="50,500,1000", help="robot counts (comma-separated; default 50,500,1000)")
    p.add_argument("--ticks", type=int, default=300, help="ticks per run, the first 10 untimed (default 300)")
    p.add_argument("--max-processes", type=int, default=64,
                   help="one process per robot is measured up to this many robots (default 64, as `uav-robots run`)")
    p.add_argument("--pools", type=int, default=4,
                   help="robot processes when robots share them, measured at every count (default 4)")
    p.add_argument("--moves", default="ahead", metavar="MODES",
                   help="how the robots move: ahead (one wake a tick, default), query (ask on each Tick), or "
                        "ahead,query to measure both side by side")
    p.add_argument("--out", default="bench-out", help="directory for the markdown and CSV (default bench-out/)")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--echo"]:
        sys.exit(echo_main(sys.argv[1:]))
    sys.stderr.write("usage: python -m uav_robots.bench_ticks --echo ... (run the benchmark with "
                     "`uav-robots bench ticks`)\n")
    sys.exit(2)
