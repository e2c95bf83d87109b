"""`uav-robots bench ticks`: lockstep ticks per second of the execution loop, beside the bare barrier
(`lockstep.py` says what one measured tick is).

    uav-robots bench ticks --robots 50,500,1000 --ticks 300
"""
from __future__ import annotations

import argparse
import math
import os
import tempfile
from pathlib import Path

from protocol.errors import MissionError, UavRobotsError

from ..common.robot_groups import robot_groups
from .common import markdown_table, parse_sizes, print_now, save_results
from .lockstep import MOVES, WARMUP_TICKS, run_barrier, run_mission


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
    groups = len(robot_groups(n, per_process))
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
    sizes = parse_sizes(args.robots)
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
                procs = len(robot_groups(n, per))
                missions = {}
                for mode in modes:
                    print_now(f"{n} robots, {_hosting_text(n, per)}, moves {mode}: mission ...")
                    try:
                        missions[mode] = run_mission(n, per, args.ticks, tmp, mode)
                    except MissionError as exc:
                        raise UavRobotsError(f"bench ticks, {n} robots in {procs} process(es), moves {mode}: "
                                             f"{exc}") from None
                    print_now(f"  {missions[mode].rate:.1f} ticks/s")
                print_now(f"  bare barrier with {procs} process(es) ...")
                try:
                    b = run_barrier(procs, args.ticks, tmp)
                except MissionError as exc:
                    raise UavRobotsError(f"bench ticks, barrier of {procs}: {exc}") from None
                print_now(f"  {b.rate:.1f} ticks/s")
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
    text = markdown_table(header, rows) + "\n\n" + "\n".join(f"- {n}" for n in notes) + "\n"
    save_results(args.out, "ticks", "# Lockstep ticks per second\n\n" + text, summary, summary)
    print_now(text)
    return 0


def add_parser(sub) -> argparse.ArgumentParser:
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
    return p
