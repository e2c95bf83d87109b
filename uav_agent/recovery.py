"""Repairing a mission from what the camera sees: who is on a goal, and a new plan for the robots still working.

Pure functions: the mission hands in the true cells from a fresh look and the
cells of the robots that can no longer move (lost, stalled, faulty), which become
obstacles; the remaining goals are assigned optimally among the working robots.
Robots the camera has verified on their goals stay there (pinned), so a repair
never undoes an arrival; robots that no open goal can be reached from are held
where they stand (stranded), so one walled-in robot does not sink the others.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np
from scipy import ndimage

from protocol.errors import PlanningError
from protocol.grid import Cell

from .planning.pipeline import PlanResult, plan_mission


@dataclass
class Replan:
    paths: dict[int, list[Cell]]       # every robot of the new plan: movers, pinned ones (one cell)
    goals: dict[int, Cell]
    result: PlanResult | None          # the movers' plan (None: nobody had to move)
    unserved: list[Cell] = field(default_factory=list)   # goals no working robot can take
    stranded: dict[int, str] = field(default_factory=dict)   # robot -> why no goal is open to it
    pinned: list[int] = field(default_factory=list)      # kept on the goal the camera verified them on

    @property
    def ids(self) -> list[int]:
        return sorted(self.paths)

    @property
    def lower_bound(self) -> float:
        """The movers' total shortest distance to their goals: what is left to do."""
        return float(self.result.metrics.get("lower_bound", 0.0)) if self.result is not None else 0.0


def on_goal(seen: dict[int, Cell], goals: dict[int, Cell]) -> dict[int, bool]:
    """Per robot with a goal: does the camera see it standing on that goal?"""
    return {r: seen.get(r) == tuple(g) for r, g in goals.items()}


def strand(free: np.ndarray, movers: Mapping[int, Cell], goals: list[Cell]) -> dict[int, str]:
    """The movers no open goal is left for: in a region of the floor (4-connected: a diagonal move
    needs both orthogonal cells free, so 8-connected regions are the same) with no goal, or with
    fewer goals than robots (the farthest robots are held). Held robots block their cells, which
    may cut a region again, so this repeats until nothing changes."""
    free = free.copy()
    out: dict[int, str] = {}
    left = dict(movers)
    while True:
        labels, _ = ndimage.label(free)
        by_region: dict[int, list[int]] = {}
        for r, (x, y) in left.items():
            by_region.setdefault(int(labels[y, x]), []).append(r)
        goal_cells: dict[int, list[Cell]] = {}
        for g in goals:
            goal_cells.setdefault(int(labels[g[1], g[0]]), []).append(tuple(g))
        held: dict[int, str] = {}
        for region, robots in by_region.items():
            mine = goal_cells.get(region, [])
            if len(robots) <= len(mine):
                continue
            # Manhattan distance to the nearest goal: a cheap, fair order for who is held.
            near = sorted(robots, key=lambda r: min((abs(left[r][0] - g[0]) + abs(left[r][1] - g[1]) for g in mine),
                                                    default=0))
            for r in near[len(mine):]:
                held[r] = (f"no open goal is reachable from {left[r]}" if not mine else
                           f"{len(robots)} robots but {len(mine)} open goal(s) reachable from {left[r]}")
        if not held:
            return out
        for r, why in held.items():
            x, y = left.pop(r)
            free[y, x] = False
            out[r] = why


def replan(free: np.ndarray, goals: list[Cell], working: dict[int, Cell], blocked: dict[int, Cell], *,
           planner: str, connectivity: int, time_limit: float, seed: int = 0,
           plan: Callable[..., PlanResult] = plan_mission, pinned: Mapping[int, Cell] | None = None) -> Replan:
    """Plan the `working` robots (id -> true cell) to the goals left, around the `blocked` robots' cells,
    with `plan` (`plan_mission`'s signature). `pinned`: working robots verified on their goal (id -> that
    goal), which stay there: planned around, unless the others cannot be planned so (then they move too)."""
    if not working:
        raise PlanningError("no robot is left working")
    pinned = {r: tuple(g) for r, g in (pinned or {}).items() if r in working and tuple(working[r]) == tuple(g)}
    try:
        return _replan(free, goals, working, blocked, pinned, planner, connectivity, time_limit, seed, plan)
    except PlanningError:
        if not pinned:
            raise
        return _replan(free, goals, working, blocked, {}, planner, connectivity, time_limit, seed, plan)


def _replan(free, goals, working, blocked, pinned, planner, connectivity, time_limit, seed, plan) -> Replan:
    free = free.copy()
    for x, y in [*blocked.values(), *pinned.values()]:
        free[y, x] = False
    stuck = set(blocked.values()) | set(pinned.values())
    open_goals = [tuple(g) for g in goals if tuple(g) not in stuck]
    movers = {r: tuple(c) for r, c in working.items() if r not in pinned}
    stranded = strand(free, movers, open_goals)
    for r in stranded:
        x, y = movers.pop(r)
        free[y, x] = False
    paths: dict[int, list[Cell]] = {r: [g] for r, g in pinned.items()}
    goal_of: dict[int, Cell] = dict(pinned)
    result = None
    if movers:
        ids = sorted(movers)
        reachable = [g for g in open_goals if free[g[1], g[0]]]
        result = plan(free, [movers[r] for r in ids], reachable, planner=planner, assign="optimal",
                      connectivity=connectivity, time_limit=time_limit, seed=seed)
        paths.update((r, [tuple(c) for c in p]) for r, p in zip(ids, result.paths))
        goal_of.update((r, tuple(g)) for r, g in zip(ids, result.goals))
    elif not pinned:
        raise PlanningError(f"no working robot can reach an open goal: {next(iter(stranded.values()))}")
    taken = set(goal_of.values())
    return Replan(paths, goal_of, result, [tuple(g) for g in goals if tuple(g) not in taken], stranded,
                  sorted(pinned))
