"""`uav-robots bench movers`: robots among people, forklifts and pallets; no contact, and how much
slower than the same instance on an empty floor?

Issue 32's measure, in two boundaries that are never mixed in one row:

* **in-process** (`loop` rows): the planner's plan run tick by tick by the world's own referee
  (`sim_world.moves.MoveJudge`, with `sim_world.traffic` stepping the movers and counting every
  contact) against the UAV's tracker, forecast and rolling-horizon repair
  (`uav_agent.planning.mover_loop`); the camera is idealised: a look every L ticks shows every
  mover where it stands. No processes, no network. This is where the 100 seeded runs of the
  target are made, and the repair's time is measured.
* **whole mission** (`mission` rows, `--missions`): `uav-robots run --movers N` end to end: the
  world's camera renders the movers, the UAV perceives them in its own images, dispatches the
  repaired plans over Zenoh; its report.json gives the same columns.

Per run: robot-mover collisions (the world's count: must be 0), robot-robot collisions, near
misses, makespan and sum of costs against the same instance's plan without movers (what the
fleet does on an empty floor), robot-ticks held, repairs and their time, images, and the reaction
time: ticks from a mover stepping onto one of the next REACTION_CELLS cells of a robot's plan to
that robot's plan being changed (a mover that leaves before the robot gets near changes nothing:
counted as passed by).

    uav-robots bench movers --missions 3 --out bench-results/movers          # the targets, the sweep, 6 missions
    uav-robots bench movers --only none --missions 1 --mission-map warehouse-450 --out DIR   # 450 missions alone
    uav-robots bench movers --quick --out bench-out                          # a few seeds of each row
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from protocol.errors import UavRobotsError

from .common import fmt, markdown_table, print_now, save_results

REACTION_CELLS = 5
PAPER_MAP = "warehouse-450"
MOVINGAI_MAP = "warehouse-20-40-10-2-1"


@dataclass(frozen=True)
class Case:
    name: str
    map: str
    robots: int
    people: int
    forklifts: int
    look_every: int
    seeds: int


def cases(quick: bool) -> list[Case]:
    """The targets (100 people runs, 20 forklift runs on the 450 floor at one look per 2 ticks), then the
    sweep on the 450 floor and a MovingAI warehouse: each speed at 10 movers looked at every 1, 2, 4
    ticks, and 50 movers every 2."""
    q = (lambda n: min(n, 3)) if quick else (lambda n: n)
    out = [Case("target-people", PAPER_MAP, 50, 10, 0, 2, q(100)),
           Case("target-forklifts", PAPER_MAP, 50, 0, 10, 2, q(20))]
    for m, tag in ((PAPER_MAP, "450"), (MOVINGAI_MAP, "movingai")):
        for kind in ("people", "forklifts"):
            for movers, look in ((10, 1), (10, 2), (10, 4), (50, 2)):
                people, forklifts = (movers, 0) if kind == "people" else (0, movers)
                out.append(Case(f"{tag}-{movers}{kind}-L{look}", m, 50, people, forklifts, look, q(10)))
    return out


class WorldFloor:
    """`mover_loop.Floor` over the world's own referee: the judge moves the robots, the traffic the
    movers, and every contact is the world's count, as in a mission."""

    def __init__(self, free: np.ndarray, starts: dict[int, tuple[int, int]], traffic) -> None:
        from sim_world.moves import MoveJudge

        self.judge = MoveJudge(free.copy(), dict(starts), 4, traffic=traffic)

    def look(self) -> list[tuple[str, tuple[int, int]]]:
        return [(m.kind, m.cell) for m in self.judge.traffic.on_floor()]

    def step(self, tick: int, before, after) -> list[Any]:
        seen = len(self.judge.traffic.touched)
        self.judge.resolve(tick, {r: (before[r], after[r]) for r in before})
        return self.judge.traffic.touched[seen:]


class Reaction:
    """Ticks from a mover stepping onto a robot's way (its next REACTION_CELLS planned cells) to the
    robot's plan being changed."""

    def __init__(self, floor: WorldFloor) -> None:
        self.floor, self.prev = floor, None
        self.pending: dict[tuple[int, int], int] = {}
        self.ticks: list[int] = []
        self.passed = 0

    def __call__(self, tick: int, plan, rep) -> None:
        changed = set(rep.replanned) | set(rep.held) | (set(plan) if rep.frozen else set())
        if self.prev is not None:
            ahead = {r: set(map(tuple, p[1:1 + REACTION_CELLS])) for r, p in self.prev.items()}
            movers = {m.id: m.cell for m in self.floor.judge.traffic.on_floor()}
            on_way = {(r, mid) for r, cells in ahead.items() for mid, c in movers.items() if c in cells}
            for key in on_way:
                self.pending.setdefault(key, tick)
            for key in [k for k in self.pending if k not in on_way or k[0] in changed]:
                t0 = self.pending.pop(key)
                if key[0] in changed:
                    self.ticks.append(tick - t0)
                else:
                    self.passed += 1
        self.prev = {r: p[1:] if len(p) > 1 else p for r, p in plan.items()}


def loop_run(case: Case, seed: int, free: np.ndarray, name: str) -> dict[str, Any]:
    """One seeded run in-process: the plan of the instance, then run among the movers."""
    from protocol.run_spec import SceneSpec
    from scenarios.maps import place
    from sim_world.traffic import build_traffic
    from uav_agent.planning.mover_loop import run_among_movers
    from uav_agent.planning.pipeline import plan_mission

    pl = place(free, case.robots, seed)
    planned = plan_mission(free, list(pl.starts), list(pl.goals), seed=seed)
    scene = SceneSpec(landmark_spacing=0, goal_pads=False, people=case.people, forklifts=case.forklifts)
    traffic = build_traffic(scene, free, list(pl.starts), list(planned.goals), seed)
    floor = WorldFloor(free, dict(enumerate(planned.paths[r][0] for r in range(case.robots))), traffic)
    reaction = Reaction(floor)
    t = time.perf_counter()
    rep = run_among_movers(free, dict(enumerate(planned.paths)), floor, look_every=case.look_every, window=1,
                           on_tick=reaction)
    judge = floor.judge
    ms = sorted(rep.repair_ms) or [0.0]
    return {"case": case.name, "boundary": "in-process", "map": name, "seed": seed, "robots": case.robots,
            "people": case.people, "forklifts": case.forklifts, "look_every": case.look_every,
            "mover_collisions": judge.mover_collisions, "robot_collisions": judge.collisions - judge.mover_collisions,
            "refused": len(judge.refused), "near_misses": traffic.near_misses,
            "makespan": rep.makespan, "makespan_empty": rep.planned_makespan,
            "makespan_ratio": None if rep.ratio is None else round(rep.ratio, 4),
            "soc": rep.sum_of_costs, "soc_empty": rep.planned_sum_of_costs,
            "soc_ratio": None if rep.sum_of_costs is None else round(rep.sum_of_costs / max(rep.planned_sum_of_costs, 1), 4),
            "held": rep.held, "repairs": rep.replans, "replanned": rep.replanned, "frozen": rep.frozen,
            "repair_ms_median": round(statistics.median(ms), 3), "repair_ms_p95": round(ms[int(0.95 * (len(ms) - 1))], 3),
            "repair_ms_max": round(ms[-1], 3), "looks": rep.looks,
            "reaction_median": statistics.median(reaction.ticks) if reaction.ticks else None,
            "reaction_max": max(reaction.ticks) if reaction.ticks else None,
            "reactions": len(reaction.ticks), "passed_by": reaction.passed,
            "seconds": round(time.perf_counter() - t, 2)}


def mission_run(map_spec: str, seed: int, robots: int, movers: int, speed: int, tmp: Path) -> dict[str, Any]:
    """One whole `uav-robots run --movers` (the UAV's own look rate), read from its report.json."""
    out = tmp / f"m-{seed}-{speed}"
    cmd = [sys.executable, "-m", "uav_robots", "run", "--map", map_spec, "--robots", str(robots), "--seed", str(seed),
           "--movers", str(movers), "--mover-speed", str(speed), "--out", str(out)]
    t = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    try:
        r = json.loads((out / "report.json").read_text())
    except (OSError, ValueError):
        raise UavRobotsError(f"bench movers: `{' '.join(cmd[2:])}` left no report (exit {proc.returncode}): "
                             f"{proc.stderr.strip()[-200:]}") from None
    w, plan = r.get("mover_watch") or {}, (r.get("plan") or {}).get("metrics") or {}
    return {"case": f"mission-{map_spec}-{'people' if speed == 1 else 'forklifts'}", "boundary": "whole mission",
            "map": map_spec, "seed": seed, "robots": robots, "people": movers if speed == 1 else 0,
            "forklifts": movers if speed == 2 else 0, "look_every": w.get("look_every"), "exit": proc.returncode,
            "outcome": r.get("outcome"), "mover_collisions": r.get("mover_collisions"),
            "robot_collisions": (r.get("collisions") or 0) - (r.get("mover_collisions") or 0),
            "near_misses": r.get("near_misses"), "makespan": r.get("ticks"), "makespan_empty": plan.get("makespan"),
            "makespan_ratio": round(r["ticks"] / plan["makespan"], 4) if plan.get("makespan") else None,
            "held": w.get("held_robot_ticks"), "repairs": w.get("repairs"), "looks": w.get("looks"),
            "repair_ms_median": w.get("repair_ms_median"), "repair_ms_max": w.get("repair_ms_max"),
            "look_s_median": w.get("look_s_median"), "tour_poses": w.get("tour_poses"),
            "seconds": round(time.perf_counter() - t, 1)}


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    def vals(k):
        return [r[k] for r in rows if r.get(k) is not None]

    def med(k):
        v = vals(k)
        return statistics.median(v) if v else None

    first = rows[0]
    ratios = vals("makespan_ratio")
    return {"case": first["case"], "boundary": first["boundary"], "map": first["map"], "robots": first["robots"],
            "people": first["people"], "forklifts": first["forklifts"], "look_every": first["look_every"],
            "runs": len(rows),
            "completed": sum(r["makespan"] is not None and r.get("outcome", "completed") == "completed" for r in rows),
            "mover_collisions": sum(vals("mover_collisions")), "robot_collisions": sum(vals("robot_collisions")),
            "near_misses_median": med("near_misses"), "makespan_ratio_median": med("makespan_ratio"),
            "makespan_ratio_max": max(ratios) if ratios else None, "soc_ratio_median": med("soc_ratio"),
            "held_median": med("held"), "repairs_median": med("repairs"), "looks_median": med("looks"),
            "repair_ms_median": med("repair_ms_median"), "repair_ms_max": max(vals("repair_ms_max") or [0]),
            "reaction_median": med("reaction_median"), "reaction_max": max(vals("reaction_max") or [0]) if vals("reaction_max") else None}


def _table(summary: list[dict[str, Any]]) -> str:
    header = ["case", "boundary", "map", "robots", "people", "forklifts", "look every", "runs", "done",
              "robot-mover coll.", "robot-robot coll.", "near misses (med.)", "makespan / empty (med. / max)",
              "SoC / empty (med.)", "held robot-ticks (med.)", "repairs (med.)", "images (med.)",
              "repair ms (med. / max)", "reaction ticks (med. / max)"]
    rows = [[s["case"], s["boundary"], s["map"], str(s["robots"]), str(s["people"]), str(s["forklifts"]),
             str(s["look_every"]), str(s["runs"]), str(s["completed"]), str(s["mover_collisions"]),
             str(s["robot_collisions"]), fmt(s["near_misses_median"], 0),
             f"{fmt(s['makespan_ratio_median'])} / {fmt(s['makespan_ratio_max'])}", fmt(s["soc_ratio_median"]),
             fmt(s["held_median"], 0), fmt(s["repairs_median"], 0), fmt(s["looks_median"], 0),
             f"{fmt(s['repair_ms_median'], 2)} / {fmt(s['repair_ms_max'], 1)}",
             f"{fmt(s['reaction_median'], 1)} / {fmt(s['reaction_max'], 0)}"] for s in summary]
    return markdown_table(header, rows)


def _provenance() -> str:
    """When, at which commit, under what load: what bench-results/README.md asks of a result."""
    try:
        commit = subprocess.run(["git", "describe", "--always", "--dirty"], capture_output=True, text=True,
                                timeout=10, cwd=Path(__file__).resolve().parent).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        commit = "unknown"
    load = " / ".join(f"{v:.2f}" for v in os.getloadavg())
    return f"Measured {time.strftime('%Y-%m-%d %H:%M %Z')} at commit {commit}, {os.cpu_count()} cores, load average {load}"


def run(args: argparse.Namespace) -> int:
    from scenarios.maps import resolve_map
    from uav_agent.planning.avoid import warm_up

    began = _provenance()
    warm_up()
    chosen = [c for c in cases(args.quick) if not args.only or c.name.startswith(args.only)]
    if args.only == "none":
        chosen = []
    if not chosen and not args.missions:
        raise UavRobotsError(f"--only {args.only!r}: no case starts so (cases: {', '.join(c.name for c in cases(False))})")
    runs: list[dict[str, Any]] = []
    summary: list[dict[str, Any]] = []
    floors: dict[str, tuple[str, np.ndarray]] = {}
    for case in chosen:
        if case.map not in floors:
            floors[case.map] = resolve_map(case.map)
        name, free = floors[case.map]
        rows = []
        for seed in range(case.seeds):
            rows.append(loop_run(case, seed, free, name))
            r = rows[-1]
            print_now(f"{case.name} seed {seed}: contacts {r['mover_collisions']}, robot collisions "
                      f"{r['robot_collisions']}, makespan {r['makespan']}/{r['makespan_empty']}, held {r['held']}, "
                      f"repair max {r['repair_ms_max']} ms, {r['seconds']} s")
        runs += rows
        summary.append(_summary(rows))
    if args.missions:
        robots, movers = (16, 6) if args.mission_map == "warehouse-small" else (50, 10)
        with tempfile.TemporaryDirectory(prefix="uavr-bench-movers-") as tmp:
            for speed in (1, 2):
                rows = [mission_run(args.mission_map, seed, robots, movers, speed, Path(tmp))
                        for seed in range(args.missions)]
                for r in rows:
                    print_now(f"{r['case']} seed {r['seed']}: exit {r['exit']}, {r['outcome']}, contacts "
                              f"{r['mover_collisions']}, ticks {r['makespan']}/{r['makespan_empty']}, {r['seconds']} s")
                runs += rows
                summary.append(_summary(rows))
    bad = sum(s["mover_collisions"] or 0 for s in summary) + sum(s["robot_collisions"] or 0 for s in summary)
    md = "\n".join([
        "# Robots among movers (`uav-robots bench movers`)", "",
        f"{began} (at the start; {_provenance().split(', load average ')[1]} at the end).", "",
        "In-process rows: the plan run by the world's own referee among its movers, the UAV's tracker, forecast "
        "and repair before every tick, a look every L ticks showing every mover (no processes, no camera). "
        "Whole-mission rows: `uav-robots run --movers` end to end (camera, perception, Zenoh). "
        "`empty`: the same instance's plan on a floor without movers. Reaction: ticks from a mover stepping onto a "
        f"robot's next {REACTION_CELLS} planned cells to that robot's plan changing.", "",
        _table(summary), "",
        f"robot-mover and robot-robot collisions in all: {bad}", ""])
    save_results(args.out, "movers", md, summary, runs)
    return 0 if bad == 0 and all(s["completed"] == s["runs"] for s in summary) else 1


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("movers", help="robots among people, forklifts and pallets: contacts, makespan, repairs",
                       description="Seeded runs of 50 robots among 10 movers on the 450x450 warehouse and a MovingAI "
                                   "warehouse, in-process (the world's referee, the UAV's repair); optionally whole "
                                   "missions too.")
    p.add_argument("--quick", action="store_true", help="3 seeds per row instead of 100/20/10")
    p.add_argument("--only", default="", metavar="PREFIX", help="only the in-process cases whose name starts so "
                                                                  "(target, 450, movingai; none: only --missions)")
    p.add_argument("--missions", type=int, default=0, metavar="N",
                   help="also N whole missions per mover speed: 16 robots and 6 movers on warehouse-small, "
                        "50 and 10 on any other --mission-map")
    p.add_argument("--mission-map", default="warehouse-small", metavar="MAP",
                   help="the whole missions' floor (default warehouse-small; warehouse-450: about 4 minutes each)")
    p.add_argument("--out", default="bench-out", help="directory for movers.md, movers.csv, movers-runs.csv")
    return p

