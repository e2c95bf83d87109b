"""Repairing a mission from what the camera sees: who is on a goal, and a new plan for the robots still working.

Pure functions: the mission hands in the true cells from a fresh look and the
cells of the robots that can no longer move (lost, stalled, faulty), which become
obstacles; the remaining goals are assigned optimally among the working robots.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from protocol.errors import PlanningError
from protocol.grid import Cell

from .planning.pipeline import PlanResult, plan_mission


@dataclass
class Replan:
    ids: list[int]                     # the robots in the new plan, in the order of result.paths
    result: PlanResult
    unserved: list[Cell] = field(default_factory=list)   # goals no working robot can take


def on_goal(seen: dict[int, Cell], goals: dict[int, Cell]) -> dict[int, bool]:
    """Per robot with a goal: does the camera see it standing on that goal?"""
    return {r: seen.get(r) == tuple(g) for r, g in goals.items()}


def replan(free: np.ndarray, goals: list[Cell], working: dict[int, Cell], blocked: dict[int, Cell], *,
           planner: str, connectivity: int, time_limit: float, seed: int = 0,
           plan: Callable[..., PlanResult] = plan_mission) -> Replan:
    """Plan the `working` robots (id -> true cell) to the goals left, around the `blocked` robots' cells,
    with `plan` (`plan_mission`'s signature)."""
    if not working:
        raise PlanningError("no robot is left working")
    free = free.copy()
    for x, y in blocked.values():
        free[y, x] = False
    stuck = set(blocked.values())
    open_goals = [tuple(g) for g in goals if tuple(g) not in stuck]
    ids = sorted(working)
    if len(open_goals) < len(ids):
        # More working robots than goals to serve (goals lost under stopped robots): robots already
        # on an open goal keep it first, the others are planned to stay where they are.
        raise PlanningError(f"{len(ids)} working robots but only {len(open_goals)} goals they can reach")
    result = plan(free, [working[r] for r in ids], open_goals, planner=planner, assign="optimal",
                  connectivity=connectivity, time_limit=time_limit, seed=seed)
    taken = set(result.goals)
    return Replan(ids, result, [g for g in goals if tuple(g) not in taken])
