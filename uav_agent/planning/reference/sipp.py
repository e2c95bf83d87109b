"""SIPP, safe interval path planning (Phillips & Likhachev, ICRA 2011), as a plain-Python reading
copy of `mapf/sipp.py`: one robot's earliest arrival among robots whose paths are known.

Every cell's time line splits into safe intervals, the maximal stretches of steps no other
robot holds it (a robot that has arrived holds its goal for good, which ends the cell's
last interval). A search state is a cell and one of its safe intervals, reached at the
earliest step: waiting is implicit, since a robot may stay in a cell until its interval
ends. Moving to a neighbour, the robot enters the first of the neighbour's intervals it
can reach before its own ends, at the earliest step that swaps with nobody and crosses
nobody's diagonal. It can only finish in its goal's last, endless interval. A* on the
arrival step, with the exact distance to the goal as heuristic, makes the arrival optimal.
"""
from __future__ import annotations

import heapq
import math

import numpy as np

from ..types import Cell, Path
from .grid import crosses, distances_to, neighbours

INF = math.inf


class Obstacles:
    """Other robots' paths; each stays on its last cell after its path ends."""

    def __init__(self, paths: list[Path]):
        self.paths = [[tuple(c) for c in p] for p in paths]
        self.horizon = max((len(p) for p in self.paths), default=1)

    def at(self, k: int, t: int) -> Cell:
        p = self.paths[k]
        return p[min(t, len(p) - 1)]

    def occupant(self, cell: Cell, t: int) -> int | None:
        return next((k for k in range(len(self.paths)) if self.at(k, t) == cell), None)

    def safe_intervals(self, cell: Cell) -> list[tuple[int, float]]:
        """[(first step, last step)] nobody holds `cell`, in order; the last may be endless."""
        busy = {t for t in range(self.horizon) if self.occupant(cell, t) is not None}
        parked = any(p[-1] == cell for p in self.paths)
        out, begin = [], 0
        for t in range(self.horizon):
            if t in busy:
                if begin < t:
                    out.append((begin, t - 1))
                begin = t + 1
        if not parked:
            out.append((begin, INF))
        elif begin < self.horizon:
            out.append((begin, self.horizon - 1))   # parked at the very end: the cell is taken for good after
        return out

    def blocks_move(self, u: Cell, v: Cell, t: int) -> bool:
        """True when moving u -> v between steps t and t + 1 swaps with a robot or crosses its diagonal."""
        for k in range(len(self.paths)):
            a, b = self.at(k, t), self.at(k, t + 1)
            if (a == v and b == u) or crosses(u, v, a, b):
                return True
        return False


def sipp(free: np.ndarray, start: Cell, goal: Cell, connectivity: int, others: list[Path]) -> Path | None:
    """The path on which one robot arrives at `goal` earliest and can stay there, or None."""
    free = np.asarray(free, dtype=bool)
    obstacles = Obstacles(others)
    dist = distances_to(free, goal, connectivity)
    if start not in dist:
        return None
    intervals: dict[Cell, list[tuple[int, float]]] = {}

    def safe(c: Cell) -> list[tuple[int, float]]:
        if c not in intervals:
            intervals[c] = obstacles.safe_intervals(c)
        return intervals[c]

    first = next((i for i, (s, e) in enumerate(safe(start)) if s <= 0 <= e), None)
    if first is None:
        return None
    best = {(start, first): 0}
    parent: dict[tuple[Cell, int], tuple[Cell, int] | None] = {(start, first): None}
    heap = [(dist[start], 0, start, first)]
    while heap:
        _, t, u, iu = heapq.heappop(heap)
        if t > best[(u, iu)]:
            continue
        end_u = safe(u)[iu][1]
        if u == goal and end_u == INF:
            return _path((u, iu), parent, best)
        for v in neighbours(free, u, connectivity):
            for iv, (begin_v, end_v) in enumerate(safe(v)):
                arrive = max(t + 1, begin_v)
                last = min(end_u + 1, end_v)      # leave u within its interval, arrive within v's
                while arrive <= last and obstacles.blocks_move(u, v, arrive - 1):
                    arrive += 1
                if arrive > last or arrive >= best.get((v, iv), INF):
                    continue
                best[(v, iv)] = arrive
                parent[(v, iv)] = (u, iu)
                heapq.heappush(heap, (arrive + dist.get(v, INF), arrive, v, iv))
    return None


def _path(state, parent, best) -> Path:
    """The cells step by step, with the waits the states leave implicit."""
    chain = []
    while state is not None:
        chain.append((state[0], best[state]))
        state = parent[state]
    chain.reverse()
    path = [chain[0][0]]
    for cell, t in chain[1:]:
        path.extend([path[-1]] * (t - len(path)))   # wait until the step before the move
        path.append(cell)
    return path
