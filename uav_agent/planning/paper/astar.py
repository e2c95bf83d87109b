"""The paper's single-robot A* on the grid (Section 3.2.1).

8-connected: octile step costs (1 and sqrt 2), the Euclidean distance as the
heuristic (as in the paper), and no corner cutting (a diagonal move needs both
orthogonal neighbours free). 4-connected: unit costs and the Manhattan distance.
A binary heap (heapq, the paper's own choice) over flat cell indices of a grid
padded with one ring of obstacles, so neighbour tests need no bounds checks;
compiled with numba so that 50 robots on a 450x450 map take well under a second.

A single search settles each cell at most once, so it ends after at most
(free cells) expansions; `limits` is checked before and after it.
"""
from __future__ import annotations

import heapq
import math

import numpy as np
from ..compile.jit import njit

from protocol.errors import PlanningError
from protocol.grid import on_grid

from ..types import Cell, Limits


def padded(free: np.ndarray) -> np.ndarray:
    """free[y, x] with a ring of obstacles around it, as one flat bool array of width w + 2."""
    f = np.asarray(free, dtype=bool)
    if f.ndim != 2 or f.size == 0:
        raise PlanningError(f"the map must be a non-empty 2-D grid, got shape {f.shape}")
    out = np.zeros((f.shape[0] + 2, f.shape[1] + 2), dtype=np.bool_)
    out[1:-1, 1:-1] = f
    return out.ravel()


@njit(cache=True)
def _search(grid, width, start, goal, diagonal):
    """A* from flat index `start` to `goal` on the padded grid; the path as flat indices, empty if none."""
    size = grid.size
    g = np.full(size, np.inf)
    parent = np.full(size, -1, dtype=np.int64)
    closed = np.zeros(size, dtype=np.bool_)
    gx, gy = goal % width, goal // width
    sqrt2 = math.sqrt(2.0)
    g[start] = 0.0
    heap = [(0.0, 0.0, start)]
    found = False
    while len(heap) > 0:
        _, neg_g, p = heapq.heappop(heap)
        if closed[p]:
            continue
        closed[p] = True
        if p == goal:
            found = True
            break
        gp = g[p]
        for k in range(8 if diagonal else 4):
            if k == 0:
                q, cost = p + 1, 1.0
            elif k == 1:
                q, cost = p - 1, 1.0
            elif k == 2:
                q, cost = p + width, 1.0
            elif k == 3:
                q, cost = p - width, 1.0
            else:
                dx = 1 if (k == 4 or k == 6) else -1
                dy = width if (k == 4 or k == 5) else -width
                if not (grid[p + dx] and grid[p + dy]):
                    continue            # no corner cutting
                q, cost = p + dx + dy, sqrt2
            if not grid[q] or closed[q]:
                continue
            ng = gp + cost
            if ng < g[q]:
                g[q] = ng
                parent[q] = p
                qx, qy = q % width, q // width
                if diagonal:
                    h = math.sqrt(float((qx - gx) ** 2 + (qy - gy) ** 2))
                else:
                    h = float(abs(qx - gx) + abs(qy - gy))
                # ties on f go to the deeper node: fewer expansions on open floors
                heapq.heappush(heap, (ng + h, -ng, q))
    if not found:
        return np.empty(0, dtype=np.int64)
    return trace_back(parent, start, goal)


@njit(cache=True)
def trace_back(parent, start, goal):
    """The node sequence start..goal read backwards through a search's parent array."""
    n = 1
    p = goal
    while p != start:
        p = parent[p]
        n += 1
    out = np.empty(n, dtype=np.int64)
    p = goal
    for i in range(n - 1, -1, -1):
        out[i] = p
        p = parent[p]
    return out


def check_cell(free: np.ndarray, cell, what: str) -> tuple[int, int]:
    try:
        x, y = int(cell[0]), int(cell[1])
    except (TypeError, ValueError, IndexError):
        raise PlanningError(f"{what} {cell!r} is not an (x, y) cell") from None
    h, w = free.shape
    if not on_grid(x, y, w, h):
        raise PlanningError(f"{what} ({x}, {y}) is off the {w}x{h} grid")
    if not free[y, x]:
        raise PlanningError(f"{what} ({x}, {y}) is an obstacle")
    return x, y


def astar(free: np.ndarray, start: Cell, goal: Cell, connectivity: int = 8,
          limits: Limits | None = None, *, grid: np.ndarray | None = None) -> list[Cell]:
    """Shortest grid path start -> goal (both included). `grid`: a cached `padded(free)`."""
    if connectivity not in (4, 8):
        raise PlanningError(f"connectivity must be 4 or 8, got {connectivity}")
    free = np.asarray(free, dtype=bool)
    if grid is None:
        grid = padded(free)
    sx, sy = check_cell(free, start, "start")
    gx, gy = check_cell(free, goal, "goal")
    if limits is not None:
        limits.check(f"A* from ({sx}, {sy})")
    width = free.shape[1] + 2
    flat = _search(grid, width, (sy + 1) * width + sx + 1, (gy + 1) * width + gx + 1, connectivity == 8)
    if flat.size == 0:
        raise PlanningError(f"no path from ({sx}, {sy}) to ({gx}, {gy})")
    if limits is not None:
        limits.check(f"A* from ({sx}, {sy})")
    return list(zip((flat % width - 1).tolist(), (flat // width - 1).tolist()))
