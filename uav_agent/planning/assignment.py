"""Which robot goes to which goal: the paper's brute force, the optimal and the bottleneck assignment.

A cost matrix has one row per robot and one column per goal (`cost[i, j]` =
robot i to goal j), `np.inf` where robot i cannot reach goal j. Every function
returns the goal index of each robot. There may be more goals than robots;
never fewer.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import chain, permutations
from typing import Callable

import numpy as np

from protocol.errors import PlanningError

from .types import Cell


def euclidean_costs(starts: list[Cell], goals: list[Cell]) -> np.ndarray:
    """The paper's Table 1: straight-line distance from every robot (row) to every goal (column)."""
    s = np.asarray(starts, dtype=float).reshape(-1, 2)
    g = np.asarray(goals, dtype=float).reshape(-1, 2)
    from scipy.spatial.distance import cdist   # imported on use: scipy's import costs a plan command ~0.5 s
    return cdist(s, g)


def _checked(cost) -> np.ndarray:
    c = np.asarray(cost, dtype=float)
    if c.ndim != 2:
        raise PlanningError(f"a cost matrix must be 2-D (robots x goals), got shape {c.shape}")
    n, m = c.shape
    if n > m:
        raise PlanningError(f"{n} robots but only {m} goals: every robot needs its own goal")
    if np.isnan(c).any() or (c == -np.inf).any():
        raise PlanningError("the cost matrix holds NaN or -inf entries")
    return c


def _matching(reach: np.ndarray) -> np.ndarray:
    """Maximum bipartite matching robots -> goals over the True entries; -1 = unmatched robot."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import maximum_bipartite_matching
    return maximum_bipartite_matching(csr_matrix(reach.astype(np.int8)), perm_type="column")


def _infeasible(cost: np.ndarray) -> PlanningError:
    """Explain why no complete assignment exists by naming a robot left without a goal."""
    reach = np.isfinite(cost)
    for i in range(cost.shape[0]):
        if not reach[i].any():
            return PlanningError(f"no complete assignment: robot {i} can reach no goal")
    match = _matching(reach)
    i = int(np.flatnonzero(match < 0)[0])
    goals = np.flatnonzero(reach[i])
    shown = ", ".join(str(int(j)) for j in goals[:5]) + (", ..." if goals.size > 5 else "")
    return PlanningError(f"no complete assignment: robot {i} can reach no remaining goal "
                         f"(the goals it can reach, {shown}, are all needed by other robots)")


def _complete(cost: np.ndarray) -> bool:
    reach = np.isfinite(cost)
    return bool(reach.any(axis=1).all()) and bool((_matching(reach) >= 0).all())


def assign_bruteforce(cost, max_n: int = 9) -> list[int]:
    """The paper's Section 3.1: try every permutation, keep the least total cost (first one on ties)."""
    c = _checked(cost)
    n, m = c.shape
    if m > max_n:
        what = f"{n} robots" if n == m else f"{n} robots and {m} goals"
        raise PlanningError(f"brute-force assignment tries every permutation: refused for {what} "
                            f"(at most {max_n}); use the optimal assignment instead")
    if n == 0:
        return []
    perms = np.fromiter(chain.from_iterable(permutations(range(m), n)), dtype=np.int16).reshape(-1, n)
    totals = c[np.arange(n), perms].sum(axis=1)
    best = int(np.argmin(totals))
    if not np.isfinite(totals[best]):
        raise _infeasible(c)
    return [int(j) for j in perms[best]]


def assign_optimal(cost) -> list[int]:
    """Least total cost (Hungarian method via scipy's linear_sum_assignment)."""
    c = _checked(cost)
    if c.shape[0] == 0:
        return []
    from scipy.optimize import linear_sum_assignment   # on use: `--assign none` never pays its import
    try:
        rows, cols = linear_sum_assignment(c)
    except ValueError:
        raise _infeasible(c) from None
    out = [0] * c.shape[0]
    for r, j in zip(rows, cols):
        out[int(r)] = int(j)
    return out


def assign_bottleneck(cost) -> list[int]:
    """Least maximum cost first (the last robot arrives as early as possible), then least total.

    Binary search over the distinct costs for the smallest threshold under which
    every robot still gets a goal (a complete bipartite matching), then the
    optimal assignment restricted to pairs within the threshold.
    """
    c = _checked(cost)
    if c.shape[0] == 0:
        return []
    if not _complete(c):
        raise _infeasible(c)
    levels = np.unique(c[np.isfinite(c)])
    lo, hi = 0, levels.size - 1          # levels[hi] always admits a complete matching
    while lo < hi:
        mid = (lo + hi) // 2
        if (_matching(c <= levels[mid]) >= 0).all():
            hi = mid
        else:
            lo = mid + 1
    return assign_optimal(np.where(c <= levels[lo], c, np.inf))


# --------------------------------------------------------------------------- the modes
def _keep(cost: np.ndarray, starts: list[Cell], goals: list[Cell]) -> list[int]:
    for i in range(len(starts)):
        if not np.isfinite(cost[i, i]):
            raise PlanningError(f"robot {i} at {starts[i]} cannot reach its goal {goals[i]}")
    return list(range(len(starts)))


def _paper(cost: np.ndarray, starts: list[Cell], goals: list[Cell]) -> list[int]:
    # The paper ranks combinations by straight-line distance; a pair with no path at all
    # must still never be chosen.
    euclid = np.asarray(euclidean_costs(starts, goals), dtype=float).copy()
    euclid[~np.isfinite(cost)] = np.inf
    return assign_bruteforce(euclid)


@dataclass(frozen=True)
class Assigner:
    help: str
    assign: Callable[[np.ndarray, list[Cell], list[Cell]], list[int]]   # (true costs, starts, goals)


# The one list of assignment modes: the CLI's choices and help, the pipeline and the bench read it.
ASSIGNERS: dict[str, Assigner] = {
    "optimal": Assigner("minimum total shortest-path distance (scipy's linear_sum_assignment)",
                        lambda cost, s, g: assign_optimal(cost)),
    "bottleneck": Assigner("minimum longest path first, then minimum total",
                           lambda cost, s, g: assign_bottleneck(cost)),
    "bruteforce": Assigner("the paper's search over all permutations on Euclidean distance (at most 9 robots)",
                           _paper),
    "none": Assigner("robot i keeps goal i", _keep),
}
DEFAULT_ASSIGNMENT = "optimal"


def check_mode(mode: str) -> str:
    if mode not in ASSIGNERS:
        raise PlanningError(f"unknown assignment {mode!r}: choose one of {', '.join(ASSIGNERS)}")
    return mode


def assign(mode: str, cost: np.ndarray, starts: list[Cell], goals: list[Cell]) -> list[int]:
    """Robot i's goal index under `mode`; `cost` holds true shortest-path distances (inf: unreachable)."""
    return [int(j) for j in ASSIGNERS[check_mode(mode)].assign(cost, starts, goals)]
