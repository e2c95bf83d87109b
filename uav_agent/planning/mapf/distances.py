"""Grid graphs and breadth-first distance fields, compiled with numba.

Every move costs one step (the MAPF convention), in 4- and in 8-connectivity;
an 8-connected diagonal move needs both orthogonal neighbours free (no corner
cutting). Distances are symmetric, so a field computed from a goal gives the
distance from every cell to that goal.

Memory: a table for many goals stores one row per goal over a compact index of
the free cells only, as uint16 when every distance fits (sentinel 65535 =
unreachable) and int32 otherwise (sentinel 2**31-1); 1000 goals on the 450x450
warehouse (126,784 free cells) take 254 MB. The last table is kept in a
one-entry cache so that the assignment's cost matrix and the planner that
follows share the same breadth-first searches.
"""
from __future__ import annotations

import hashlib
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from ..compile.jit import INTERPRETED, njit

from protocol.errors import PlanningError

from ..types import Cell, Problem

THREADS = max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))
UNREACHABLE_16 = np.iinfo(np.uint16).max
UNREACHABLE_32 = np.iinfo(np.int32).max

# Neighbour order: the 4 orthogonal moves first, then the diagonals.
_DX = np.array([1, 0, -1, 0, 1, -1, -1, 1], dtype=np.int64)
_DY = np.array([0, 1, 0, -1, 1, 1, -1, -1], dtype=np.int64)


def _build_neighbours(free: np.ndarray, index: np.ndarray, cells: np.ndarray, k: int) -> np.ndarray:
    """int32 [n, k]: each free cell's free neighbours' compact ids in _DX/_DY's order, -1 padded
    at the end. NumPy over all cells at once: one call per map."""
    h, w = free.shape
    x, y = cells % w, cells // w
    border = np.zeros((h + 2, w + 2), dtype=bool)
    border[1:-1, 1:-1] = free
    flat = border.ravel()
    at = (y + 1) * (w + 2) + x + 1           # each cell in the bordered grid
    nbr = np.full((cells.shape[0], k), -1, dtype=np.int32)
    filled = np.zeros(cells.shape[0], dtype=np.int64)
    for d in range(k):
        step = int(_DY[d]) * (w + 2) + int(_DX[d])
        ok = flat[at + step]
        if d >= 4:
            ok &= flat[at + int(_DX[d])] & flat[at + int(_DY[d]) * (w + 2)]   # no corner cutting
        rows = np.flatnonzero(ok)
        nbr[rows, filled[rows]] = index[cells[rows] + int(_DY[d]) * w + int(_DX[d])]
        filled[rows] += 1
    return nbr


@dataclass(frozen=True, eq=False)
class GridGraph:
    """The free cells of a grid as a graph on a compact index 0..n-1."""
    free: np.ndarray          # bool [h, w]
    connectivity: int
    index: np.ndarray         # int32 [h*w]: flat cell y*w+x -> compact id, -1 for obstacles
    cells: np.ndarray         # int32 [n]: compact id -> flat cell
    nbr: np.ndarray           # int32 [n, 4 or 8]: compact neighbour ids, -1 padded at the end
    base: np.ndarray          # int32 [(h+2)*(w+2)]: the grid with a wall border, -1 free, -2 wall
    base16: np.ndarray        # the same as uint16: 65535 free, 65534 wall
    padded: np.ndarray        # int32 [n]: compact id -> flat index in the bordered grid

    @property
    def width(self) -> int:
        return int(self.free.shape[1])

    @property
    def n(self) -> int:
        return int(self.cells.shape[0])

    def bfs_rows(self, sources: np.ndarray, out: np.ndarray, sentinel: int) -> int:
        """BFS from every source into out's rows, on all cores; returns the largest distance."""
        sources = np.ascontiguousarray(sources, dtype=np.int32)
        if INTERPRETED:
            return _scipy_rows(self.nbr, sources, out, sentinel)
        base = self.base16 if out.dtype == np.uint16 else self.base
        args = (base, self.width + 2, self.connectivity == 8, self.padded, sources, out, sentinel)
        m = sources.size
        chunks = min(m, THREADS)
        if chunks <= 1:
            return _bfs_rows(*args, 0, m)
        bounds = [(c * m // chunks, (c + 1) * m // chunks) for c in range(chunks)]
        with ThreadPoolExecutor(chunks) as pool:
            return max(pool.map(lambda b: _bfs_rows(*args, *b), bounds))

    def id_of(self, cell: Cell, what: str = "cell") -> int:
        h, w = self.free.shape
        try:
            x, y = int(cell[0]), int(cell[1])
        except (TypeError, ValueError, IndexError):
            raise PlanningError(f"{what} {cell!r} is not an (x, y) cell") from None
        if not (0 <= x < w and 0 <= y < h):
            raise PlanningError(f"{what} ({x}, {y}) is off the {w}x{h} grid")
        i = int(self.index[y * w + x])
        if i < 0:
            raise PlanningError(f"{what} ({x}, {y}) is an obstacle")
        return i

    def ids_of(self, cells: list[Cell], what: str = "cell") -> np.ndarray:
        return np.array([self.id_of(c, f"{what} {k}") for k, c in enumerate(cells)], dtype=np.int32)

    def cell_of(self, i: int) -> Cell:
        f = int(self.cells[i])
        return (f % self.width, f // self.width)

    def xy(self) -> tuple[np.ndarray, np.ndarray]:
        """Column and row of every compact id."""
        return self.cells % self.width, self.cells // self.width


def _free_key(free: np.ndarray) -> tuple:
    return (free.shape, hashlib.blake2b(np.ascontiguousarray(free, dtype=bool).tobytes(), digest_size=16).digest())


_GRAPH_CACHE: dict[tuple, GridGraph] = {}


def grid_graph(free: np.ndarray, connectivity: int = 4) -> GridGraph:
    if connectivity not in (4, 8):
        raise PlanningError(f"connectivity must be 4 or 8, got {connectivity!r}")
    free = np.asarray(free)
    if free.ndim != 2 or free.size == 0:
        raise PlanningError(f"the grid must be a non-empty 2-D array, got shape {free.shape}")
    free = np.ascontiguousarray(free, dtype=bool)
    key = (_free_key(free), connectivity)
    g = _GRAPH_CACHE.get(key)
    if g is None:
        flat = free.ravel()
        cells = np.flatnonzero(flat).astype(np.int32)
        index = np.full(flat.size, -1, dtype=np.int32)
        index[cells] = np.arange(cells.size, dtype=np.int32)
        nbr = _build_neighbours(free, index, cells, connectivity)
        h, w = free.shape
        border = np.zeros((h + 2, w + 2), dtype=bool)
        border[1:-1, 1:-1] = free
        base = np.where(border.ravel(), -1, -2).astype(np.int32)
        base16 = np.where(border.ravel(), 65535, 65534).astype(np.uint16)
        padded = ((cells // w + 1) * (w + 2) + cells % w + 1).astype(np.int32)
        g = GridGraph(free, connectivity, index, cells, nbr, base, base16, padded)
        _GRAPH_CACHE.clear()  # one map at a time: the graph of a large map is tens of MB
        _GRAPH_CACHE[key] = g
    return g


@njit(cache=True)
def _bfs(base: np.ndarray, pitch: int, diagonal: bool, source: int, dist: np.ndarray, queue: np.ndarray,
         unseen: int, wall: int, limit: int) -> int:
    """BFS on the padded grid: base holds `unseen` on free cells and `wall` on walls; fills dist.

    The one-cell wall border removes every bounds check from the inner loop; the uint16
    variant (unseen 65535, wall 65534) halves the memory traffic. Returns the largest
    distance reached, or limit + 1 as soon as a distance would exceed `limit` (the search
    stops there: the caller must use a wider type).
    """
    for i in range(base.shape[0]):
        dist[i] = base[i]
    dist[source] = 0
    queue[0] = source
    head = 0
    tail = 1
    far = 0
    while head < tail:
        v = queue[head]
        head += 1
        dv = dist[v] + 1
        if dv > limit:
            return limit + 1
        u = v + 1
        if dist[u] == unseen:
            dist[u] = dv
            queue[tail] = u
            tail += 1
        u = v - 1
        if dist[u] == unseen:
            dist[u] = dv
            queue[tail] = u
            tail += 1
        u = v + pitch
        if dist[u] == unseen:
            dist[u] = dv
            queue[tail] = u
            tail += 1
        u = v - pitch
        if dist[u] == unseen:
            dist[u] = dv
            queue[tail] = u
            tail += 1
        if diagonal:
            # walls never change, so "!= wall" is "free" (no corner cutting)
            for sy in (pitch, -pitch):
                for sx in (1, -1):
                    u = v + sy + sx
                    if dist[u] == unseen and dist[v + sx] != wall and dist[v + sy] != wall:
                        dist[u] = dv
                        queue[tail] = u
                        tail += 1
        far = dv - 1
    return far


@njit(cache=True, nogil=True)
def _bfs_rows(base: np.ndarray, pitch: int, diagonal: bool, padded: np.ndarray, sources: np.ndarray,
              out: np.ndarray, sentinel: int, lo: int, hi: int) -> int:
    """One BFS per compact source id sources[lo:hi] into out[row] (compact ids); unreachable
    cells get `sentinel`. Returns the largest finite distance so that the caller can tell
    whether the row type was wide enough. Releases the GIL: threads run chunks side by side."""
    n = padded.shape[0]
    # scratch buffers once per chunk: fresh large allocations cost page faults
    dist = np.empty_like(base)
    queue = np.empty(n, dtype=np.int32)
    unseen = base[padded[0]] if n > 0 else 0
    wall = base[0]
    limit = min(sentinel, min(unseen, wall)) - 1 if wall > 0 else sentinel - 1
    best = 0
    for r in range(lo, hi):
        far = _bfs(base, pitch, diagonal, padded[sources[r]], dist, queue, unseen, wall, limit)
        best = max(best, far)
        row = out[r]
        for v in range(n):
            d = dist[padded[v]]
            if d < 0 or d >= sentinel:
                row[v] = sentinel
            else:
                row[v] = d
    return best


def _scipy_rows(nbr: np.ndarray, sources: np.ndarray, out: np.ndarray, sentinel: int) -> int:
    """`_bfs_rows`'s numbers by SciPy's compiled Dijkstra on unit steps, for a process whose
    kernels run interpreted (a fresh clone's first plan, build/interpreted.py): 50 fields of the
    450x450 warehouse in 1 s instead of 11 s."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    n = nbr.shape[0]
    has = nbr >= 0
    graph = csr_matrix((np.ones(int(has.sum()), dtype=np.float32),
                        (np.repeat(np.arange(n, dtype=np.int32), has.sum(axis=1)), nbr[has])), shape=(n, n))
    dist = dijkstra(graph, unweighted=True, indices=sources).reshape(len(sources), n)
    dist[np.isinf(dist)] = -1.0
    far = int(dist.max(initial=0.0))
    dist[dist < 0] = sentinel
    np.minimum(dist, sentinel, out=dist)
    out[...] = dist
    return far


@dataclass(frozen=True, eq=False)
class DistanceTable:
    """Distances to a set of goals: `dist[rows[k], v]` = steps from compact cell v to goals[k]."""
    graph: GridGraph
    goals: list[Cell]
    dist: np.ndarray          # uint16 or int32 [n_rows, graph.n]
    rows: np.ndarray          # int32 [len(goals)]
    unreachable: int          # the sentinel stored for cells that cannot reach the goal

    def field(self, k: int) -> np.ndarray:
        """Distances to goals[k] as a full int32 [h, w] grid; -1 = obstacle or unreachable."""
        out = np.full(self.graph.free.size, -1, dtype=np.int32)
        row = self.dist[self.rows[k]].astype(np.int32)
        row[self.dist[self.rows[k]] == self.unreachable] = -1
        out[self.graph.cells] = row
        return out.reshape(self.graph.free.shape)

    def at(self, k: int, cell: Cell) -> float:
        """Steps from cell to goals[k]; inf when unreachable."""
        d = int(self.dist[self.rows[k], self.graph.id_of(cell)])
        return float("inf") if d == self.unreachable else float(d)


_TABLE_CACHE: list[DistanceTable] = []


def clear_cache() -> None:
    """Drops the cached grid graph and distance table (they can take hundreds of MB)."""
    _TABLE_CACHE.clear()
    _GRAPH_CACHE.clear()


def _compute_rows(graph: GridGraph, sources: np.ndarray) -> tuple[np.ndarray, int]:
    out = np.empty((sources.size, graph.n), dtype=np.uint16)
    far = graph.bfs_rows(sources, out, UNREACHABLE_16)
    if far < UNREACHABLE_16 - 2:     # 65534 and 65535 mark walls and unseen cells in the search
        return out, UNREACHABLE_16
    del out  # a maze longer than 65534 steps: redo with wide rows
    out = np.empty((sources.size, graph.n), dtype=np.int32)
    graph.bfs_rows(sources, out, UNREACHABLE_32)
    return out, UNREACHABLE_32


def distance_fields(free: np.ndarray, goals: list[Cell], connectivity: int = 4) -> DistanceTable:
    """BFS distance rows for many goals at once (in parallel), sharing rows of repeated goals.

    Reuses the cached table when it already holds every requested goal.
    """
    graph = grid_graph(free, connectivity)
    ids = graph.ids_of(list(goals), "goal")
    if _TABLE_CACHE:
        old = _TABLE_CACHE[0]
        if old.graph is graph:
            row_of = {int(old.graph.index[_flat(graph, g)]): int(old.rows[k]) for k, g in enumerate(old.goals)}
            rows = [row_of.get(int(i), -1) for i in ids]
            if all(r >= 0 for r in rows):
                return DistanceTable(graph, list(goals), old.dist, np.array(rows, dtype=np.int32), old.unreachable)
    _TABLE_CACHE.clear()  # free the old table before allocating the new one
    uniq, rows = np.unique(ids, return_inverse=True)
    dist, sentinel = _compute_rows(graph, uniq.astype(np.int32))
    table = DistanceTable(graph, list(goals), dist, rows.astype(np.int32).ravel(), sentinel)
    _TABLE_CACHE.append(table)
    return table


def _flat(graph: GridGraph, cell: Cell) -> int:
    return int(cell[1]) * graph.width + int(cell[0])


def distance_field(free: np.ndarray, goal: Cell, connectivity: int = 4) -> np.ndarray:
    """Steps from every cell to `goal` as int32 [h, w]; -1 = obstacle or unreachable."""
    graph = grid_graph(free, connectivity)
    src = graph.id_of(goal, "goal")
    dist = np.empty(graph.base.size, dtype=np.int32)
    queue = np.empty(graph.n, dtype=np.int32)
    _bfs(graph.base, graph.width + 2, connectivity == 8, int(graph.padded[src]), dist, queue, -1, -2, UNREACHABLE_32 - 1)
    h, w = graph.free.shape
    return np.maximum(dist.reshape(h + 2, w + 2)[1:-1, 1:-1], -1)


def cost_matrix(free: np.ndarray, starts: list[Cell], goals: list[Cell], connectivity: int = 4) -> np.ndarray:
    """cost[i, j] = shortest-path steps from starts[i] to goals[j] (float64, inf if unreachable)."""
    table = distance_fields(free, goals, connectivity)
    sid = table.graph.ids_of(list(starts), "start")
    raw = table.dist[:, sid][table.rows].T  # gather the starts' columns first: the table is large
    cost = raw.astype(np.float64)
    cost[raw == table.unreachable] = np.inf
    return cost


@dataclass(frozen=True, eq=False)
class Instance:
    """A problem compiled to compact ids, with distances to every robot's goal."""
    problem: Problem
    graph: GridGraph
    table: DistanceTable
    starts: np.ndarray        # int32 [n] compact ids
    goals: np.ndarray         # int32 [n] compact ids
    rows: np.ndarray          # int32 [n]: robot i's row of table.dist

    @property
    def n(self) -> int:
        return int(self.starts.size)

    def start_distances(self) -> np.ndarray:
        """Each robot's shortest-path length (int64)."""
        return self.table.dist[self.rows, self.starts].astype(np.int64)

    def lower_bound(self) -> int:
        return int(self.start_distances().sum())

    def to_paths(self, ids: list[np.ndarray]) -> list[list[Cell]]:
        w = self.graph.width
        out = []
        for p in ids:
            flat = self.graph.cells[np.asarray(p, dtype=np.int64)]
            out.append(list(zip((flat % w).tolist(), (flat // w).tolist())))
        return out


def compile_problem(problem: Problem) -> Instance:
    """Checks a problem (cells on free cells, distinct starts and goals, goals reachable)."""
    if len(problem.starts) != len(problem.goals):
        raise PlanningError(f"{len(problem.starts)} starts but {len(problem.goals)} goals")
    graph = grid_graph(problem.free, problem.connectivity)
    starts = graph.ids_of(list(problem.starts), "start of robot")
    goals = graph.ids_of(list(problem.goals), "goal of robot")
    for what, ids, cells in (("start", starts, problem.starts), ("goal", goals, problem.goals)):
        uniq, first, counts = np.unique(ids, return_index=True, return_counts=True)
        if uniq.size < ids.size:
            cell = cells[int(first[np.argmax(counts > 1)])]
            robots = np.flatnonzero(ids == ids[first[np.argmax(counts > 1)]])
            raise PlanningError(f"robots {robots[0]} and {robots[1]} share the {what} cell {tuple(cell)}")
    table = distance_fields(problem.free, list(problem.goals), problem.connectivity)
    inst = Instance(problem, graph, table, starts, goals, table.rows)
    d = table.dist[inst.rows, starts]
    bad = np.flatnonzero(d == table.unreachable)
    if bad.size:
        i = int(bad[0])
        raise PlanningError(f"robot {i}: goal {tuple(problem.goals[i])} is unreachable from {tuple(problem.starts[i])}"
                            + (f" ({bad.size} robots in all)" if bad.size > 1 else ""))
    return inst
