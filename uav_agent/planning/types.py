"""Types shared by every planner: a problem, a solution, and the planner signature.

A multi-robot planner is a pure function
    planner(problem: Problem, limits: Limits) -> list[list[Cell]]
returning one path per robot, paths[i][t] = the cell of robot i at step t,
paths[i][0] == problem.starts[i], ending on problem.goals[i]. Paths may have
different lengths: a robot whose path has ended stays on its goal (and still
blocks it). It raises PlanningError (one line: which robots, where, why) when
it cannot find a plan within `limits`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from protocol.errors import PlanningTimeout
from protocol.grid import Cell

Path = list[Cell]


@dataclass(frozen=True)
class Problem:
    free: np.ndarray            # bool [height, width], True = traversable
    starts: list[Cell]          # robot i starts at starts[i]
    goals: list[Cell]           # robot i must end at goals[i] (assignment already done)
    connectivity: int = 4       # 4, or 8 (diagonals, no corner cutting)
    seed: int = 0

    @property
    def n(self) -> int:
        return len(self.starts)


@dataclass
class Limits:
    """A wall-clock budget; planners call `check()` in their loops so they never hang."""
    seconds: float = 60.0
    started: float = field(default_factory=time.perf_counter)

    def remaining(self) -> float:
        return self.seconds - (time.perf_counter() - self.started)

    def expired(self) -> bool:
        return self.remaining() <= 0.0

    def check(self, what: str) -> None:
        if self.expired():
            raise PlanningTimeout(f"{what}: time limit of {self.seconds:g} s reached without a plan")


Planner = Callable[[Problem, Limits], list[Path]]


def arrival(path: Path, goal: Cell) -> int:
    """The step at which a robot last arrives at its goal: its cost in the MAPF convention."""
    t = len(path) - 1
    while t > 0 and path[t - 1] == goal:
        t -= 1
    return t


def sum_of_costs(paths: list[Path], goals: list[Cell]) -> int:
    return sum(arrival(p, g) for p, g in zip(paths, goals))


def makespan(paths: list[Path], goals: list[Cell]) -> int:
    return max((arrival(p, g) for p, g in zip(paths, goals)), default=0)
