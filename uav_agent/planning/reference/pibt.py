"""PIBT, Priority Inheritance with Backtracking (Okumura, Machida, Défago & Tamura, IJCAI 2019),
as a plain-Python reading copy of `mapf/pibt.py` (after pypibt), without the kernel's swap
technique: slow, and in 1-wide corridors it can livelock where the kernel does not.

Each step, robots in priority order pick the free neighbour (or their own cell) closest to
their goal. A robot that wants a cell someone stands on lends that robot its priority: the
occupant must move away first (recursively), or the wish is dropped and the next cell tried
(backtracking). A robot's priority grows by one each step it is away from its goal, and
falls back to its fractional start value once there, so that everyone gets its turn.
"""
from __future__ import annotations

import numpy as np

from ..types import Cell, Path, Problem
from .grid import configurations_to_paths, crosses, distances_to, neighbours


class PIBT:
    """The configuration generator: one step of every robot, some of them fixed beforehand (LaCAM)."""

    def __init__(self, problem: Problem, seed: int = 0):
        self.free = np.asarray(problem.free, dtype=bool)
        self.goals = [tuple(g) for g in problem.goals]
        self.connectivity = problem.connectivity
        self.dist = [distances_to(self.free, g, problem.connectivity) for g in self.goals]
        self.rng = np.random.default_rng(seed)

    def initial_priorities(self, starts: list[Cell]) -> list[float]:
        # below one, so that any robot still away from its goal outranks every robot at its goal
        return [self.dist[i][s] / self.free.size for i, s in enumerate(starts)]

    def next_priorities(self, prio: list[float], q: tuple[Cell, ...]) -> list[float]:
        return [p - np.floor(p) if q[i] == self.goals[i] else p + 1 for i, p in enumerate(prio)]

    def step(self, q_from: tuple[Cell, ...], prio: list[float],
             fixed: dict[int, Cell] | None = None) -> tuple[Cell, ...] | None:
        """The next configuration, with robot i at fixed[i]; None when none obeys `fixed` without a conflict."""
        n = len(q_from)
        q_to: list[Cell | None] = [None] * n
        now = {c: i for i, c in enumerate(q_from)}
        nxt: dict[Cell, int] = {}
        for i, v in (fixed or {}).items():
            if v in nxt:
                return None
            q_to[i], nxt[v] = v, i
        for i in sorted(range(n), key=lambda k: prio[k], reverse=True):
            if q_to[i] is None:
                self._push(i, q_from, q_to, now, nxt)
        q = tuple(q_to)
        return q if _valid_step(q_from, q) else None

    def _push(self, i: int, q_from, q_to, now: dict, nxt: dict) -> bool:
        """Robot i picks its next cell, pushing an occupant away first; False when it has to stay."""
        u = q_from[i]
        candidates = [u] + neighbours(self.free, u, self.connectivity)
        self.rng.shuffle(candidates)           # ties between equally close cells: at random
        candidates.sort(key=lambda c: self.dist[i][c])
        for v in candidates:
            if v in nxt:
                continue
            j = now.get(v)
            if j is not None and j != i and q_to[j] == u:
                continue                        # a swap
            if self._crossed(u, v, q_from, q_to, now):
                continue
            q_to[i], nxt[v] = v, i
            if j is not None and j != i and q_to[j] is None and not self._push(j, q_from, q_to, now, nxt):
                continue                        # the occupant cannot make way: try the next cell
            return True
        q_to[i], nxt[u] = u, i
        return False

    @staticmethod
    def _crossed(u: Cell, v: Cell, q_from, q_to, now: dict) -> bool:
        # a crossing robot starts on one of the square's two other corners
        for corner in ((v[0], u[1]), (u[0], v[1])):
            j = now.get(corner)
            if j is not None and q_to[j] is not None and crosses(u, v, q_from[j], q_to[j]):
                return True
        return False


def _valid_step(q_from: tuple[Cell, ...], q_to: tuple[Cell | None, ...]) -> bool:
    if None in q_to or len(set(q_to)) != len(q_to):
        return False
    where = {c: i for i, c in enumerate(q_from)}
    for i, (u, v) in enumerate(zip(q_from, q_to)):
        j = where.get(v)
        if j is not None and j != i and q_to[j] == u:
            return False
        for corner in ((v[0], u[1]), (u[0], v[1])):
            k = where.get(corner)
            if k is not None and k != i and crosses(u, v, q_from[k], q_to[k]):
                return False
    return True


def pibt(problem: Problem, max_steps: int = 1000, seed: int = 0) -> list[Path] | None:
    """Steps every robot with PIBT until all stand on their goals: their paths, or None after `max_steps`."""
    planner = PIBT(problem, seed)
    q = tuple(tuple(s) for s in problem.starts)
    goals = tuple(planner.goals)
    prio = planner.initial_priorities(list(q))
    history = [q]
    while q != goals:
        if len(history) > max_steps:
            return None
        q = planner.step(q, prio)
        if q is None:            # unconstrained, PIBT always finds a step; kept for the type
            return None
        prio = planner.next_priorities(prio, q)
        history.append(q)
    return configurations_to_paths(history, list(goals))
