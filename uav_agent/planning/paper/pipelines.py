"""The paper's two multi-robot pipelines: one single-robot path each, then priority waits.

`paper_astar`: A* per robot (Section 3.2.1), `paper_prm`: a probabilistic
roadmap shared by all robots; both followed by the priority-wait collision
avoidance (Section 3.2.2), which raises IncompleteError where waiting cannot help.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from protocol.errors import PlanningError

from .astar import astar, check_cell, padded
from .priority_waits import priority_waits
from .prm import Roadmap
from ..types import Limits, Path, Problem

# one roadmap sample per this many free cells: in a warehouse with 2-wide aisles
# sparser roadmaps fall apart into pieces that cannot see each other
PRM_CELLS_PER_SAMPLE = 8


def prm_samples(free: np.ndarray) -> int:
    return max(64, int(np.count_nonzero(free)) // PRM_CELLS_PER_SAMPLE)


def _check_problem(problem: Problem) -> np.ndarray:
    free = np.asarray(problem.free, dtype=bool)
    if len(problem.goals) != problem.n:
        raise PlanningError(f"{problem.n} robots but {len(problem.goals)} goals")
    for i in range(problem.n):
        check_cell(free, problem.starts[i], f"robot {i}'s start")
        check_cell(free, problem.goals[i], f"robot {i}'s goal")
    return free


def paper_astar(problem: Problem, limits: Limits) -> list[Path]:
    free = _check_problem(problem)
    grid = padded(free)
    paths = []
    for s, g in zip(problem.starts, problem.goals):
        limits.check("paper A*")
        paths.append(astar(free, s, g, problem.connectivity, limits, grid=grid))
    return priority_waits(problem, paths, limits)


def paper_prm(problem: Problem, limits: Limits) -> list[Path]:
    """PRM paths; robots the roadmap cannot serve get a denser roadmap (twice the samples) until it can."""
    free = _check_problem(problem)
    labels, _ = ndimage.label(free)
    for s, g in zip(problem.starts, problem.goals):
        if labels[s[1], s[0]] != labels[g[1], g[0]]:
            raise PlanningError(f"no path from ({s[0]}, {s[1]}) to ({g[0]}, {g[1]})")
    cells = int(np.count_nonzero(free))
    samples = prm_samples(free)
    paths: list[Path | None] = [None] * problem.n
    pending = list(range(problem.n))
    while pending:
        limits.check("paper PRM")
        roadmap = Roadmap.build(free, samples, problem.seed, connectivity=problem.connectivity, limits=limits)
        failed: list[tuple[int, PlanningError]] = []
        for i in pending:
            limits.check("paper PRM")
            try:
                paths[i] = roadmap.query(problem.starts[i], problem.goals[i])
            except PlanningError as exc:
                failed.append((i, exc))
        if failed and samples >= cells:
            raise failed[0][1]      # every free cell is a node: the roadmap is the grid itself
        pending = [i for i, _ in failed]
        samples = min(cells, 2 * samples)
    return priority_waits(problem, paths, limits)
