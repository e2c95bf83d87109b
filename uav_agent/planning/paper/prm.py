"""The paper's probabilistic roadmap (Section 3.2.1), made executable on the grid.

Build (offline): `samples` distinct free cells drawn at random (seeded); an edge
joins two samples within `radius` of each other (or among each other's
`k_nearest`) when the straight segment between their centres touches only free
cells. Query (online): the start and the goal join the roadmap the same way
(or directly, when they see each other), A* over the roadmap with Euclidean
edge weights and the Euclidean heuristic picks the node sequence, and every
segment is traced back onto the grid as a walk of adjacent cells the robot can
execute one step at a time.

A segment is free when every cell its line touches is free, including both
cells beside a grid corner the line passes exactly through. So the walk along
it never enters an obstacle, and in 8-connectivity a diagonal step taken at
such a corner never cuts it.
"""
from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numpy as np
from ..compile.jit import njit
from scipy.spatial import cKDTree

from protocol.errors import PlanningError

from .astar import check_cell, padded, trace_back
from ..types import Cell, Limits

# Without a radius or k, the radius is the one whose disc would hold this many
# samples on an open floor. It is large on purpose: in a warehouse most of them
# hide behind shelves, and the few seen along a 2-wide aisle must still reach
# the next sample down the aisle, or the roadmap falls apart.
NEIGHBOURS_IN_RADIUS = 100.0


@njit(cache=True)
def _trace(grid, width, x0, y0, x1, y1, diagonal, out, n):
    """Walk the cells of segment (x0,y0)-(x1,y1) into out[n:]; the new n, or -1 if it touches an obstacle.

    Cells are unit squares centred on integer coordinates; the walk crosses one
    cell border at a time (4-adjacent steps), except where the line passes
    exactly through a corner: there both side cells must be free, and the walk
    steps diagonally (8-connectivity) or through the x-side cell (4-connectivity).
    """
    dx, dy = abs(x1 - x0), abs(y1 - y0)
    sx = 1 if x1 > x0 else -1
    sy = 1 if y1 > y0 else -1
    x, y = x0, y0
    p = (y + 1) * width + x + 1
    if not grid[p]:
        return -1
    out[n] = p
    n += 1
    ix, iy = 0, 0
    while ix < dx or iy < dy:
        d = (1 + 2 * ix) * dy - (1 + 2 * iy) * dx
        if d == 0:
            a = (y + 1) * width + x + sx + 1
            b = (y + sy + 1) * width + x + 1
            if not (grid[a] and grid[b]):
                return -1
            if not diagonal:
                out[n] = a
                n += 1
            x += sx
            y += sy
            ix += 1
            iy += 1
        elif d < 0:
            x += sx
            ix += 1
        else:
            y += sy
            iy += 1
        p = (y + 1) * width + x + 1
        if not grid[p]:
            return -1
        out[n] = p
        n += 1
    return n


@njit(cache=True)
def _segments_free(grid, width, x0, y0, x1, y1):
    ok = np.zeros(x0.size, dtype=np.bool_)
    longest = 1
    for i in range(x0.size):
        longest = max(longest, abs(x1[i] - x0[i]) + abs(y1[i] - y0[i]) + 2)
    buf = np.empty(longest, dtype=np.int64)
    for i in range(x0.size):
        ok[i] = _trace(grid, width, x0[i], y0[i], x1[i], y1[i], False, buf, 0) >= 0
    return ok


@njit(cache=True)
def _rasterise(grid, width, xs, ys, diagonal):
    """A polyline of free segments -> a walk of adjacent cells (flat padded indices)."""
    total = 1
    for i in range(xs.size - 1):
        total += abs(xs[i + 1] - xs[i]) + abs(ys[i + 1] - ys[i]) + 1
    buf = np.empty(total, dtype=np.int64)
    n = 0
    for i in range(xs.size - 1):
        if n > 0:
            n -= 1          # the segment starts where the previous one ended
        n = _trace(grid, width, xs[i], ys[i], xs[i + 1], ys[i + 1], diagonal, buf, n)
        if n < 0:
            return np.empty(0, dtype=np.int64)
    if xs.size == 1:
        buf[0] = (ys[0] + 1) * width + xs[0] + 1
        n = 1
    return buf[:n].copy()


@njit(cache=True)
def _shortcut_corners(grid, width, walk):
    """In 8-connectivity, replace an x-step plus a y-step by one diagonal where it cuts no corner."""
    out = np.empty(walk.size, dtype=np.int64)
    n = 0
    for i in range(walk.size):
        q = walk[i]
        if n >= 2:
            a, b = out[n - 2], out[n - 1]
            ax, ay, qx, qy = a % width, a // width, q % width, q // width
            if abs(qx - ax) == 1 and abs(qy - ay) == 1:
                other = a + q - b           # the corner cell the two steps did not visit
                if grid[other]:
                    out[n - 1] = q
                    continue
        out[n] = q
        n += 1
    return out[:n].copy()


@njit(cache=True)
def _graph_astar(xs, ys, indptr, indices, weights, start_nodes, start_w, goal_w):
    """A* over the roadmap plus two query nodes: start = M, goal = M + 1 (M roadmap nodes).

    Euclidean edge weights and the Euclidean heuristic; the node path, empty if none.
    """
    m = indptr.size - 1
    s, t = m, m + 1
    g = np.full(m + 2, np.inf)
    parent = np.full(m + 2, -1, dtype=np.int64)
    closed = np.zeros(m + 2, dtype=np.bool_)
    tx, ty = xs[t], ys[t]
    g[s] = 0.0
    heap = [(0.0, s)]
    while len(heap) > 0:
        _, u = heapq.heappop(heap)
        if closed[u]:
            continue
        closed[u] = True
        if u == t:
            break
        if u == s:
            lo, hi = 0, start_nodes.size
        else:
            lo, hi = indptr[u], indptr[u + 1] + 1      # one extra slot: the edge to the goal
        for e in range(lo, hi):
            if u == s:
                v, wgt = start_nodes[e], start_w[e]
            elif e < indptr[u + 1]:
                v, wgt = indices[e], weights[e]
            else:
                if not np.isfinite(goal_w[u]):
                    continue
                v, wgt = t, goal_w[u]
            if closed[v]:
                continue
            ng = g[u] + wgt
            if ng < g[v]:
                g[v] = ng
                parent[v] = u
                heapq.heappush(heap, (ng + math.sqrt((xs[v] - tx) ** 2 + (ys[v] - ty) ** 2), v))
    if not closed[t]:
        return np.empty(0, dtype=np.int64)
    return trace_back(parent, s, t)


@dataclass
class Roadmap:
    free: np.ndarray
    grid: np.ndarray            # padded(free)
    xs: np.ndarray              # sample x (column), int64
    ys: np.ndarray              # sample y (row), int64
    indptr: np.ndarray          # CSR adjacency of the roadmap
    indices: np.ndarray
    weights: np.ndarray
    tree: cKDTree
    connectivity: int
    radius: float | None
    k_nearest: int | None

    @property
    def nodes(self) -> int:
        return int(self.xs.size)

    @property
    def edges(self) -> int:
        return int(self.indices.size // 2)

    @classmethod
    def build(cls, free: np.ndarray, samples: int, seed: int = 0, k_nearest: int | None = None,
              radius: float | None = None, connectivity: int = 8, limits: Limits | None = None) -> "Roadmap":
        """Sample `samples` free cells and join the pairs that see each other.

        Neighbours: within `radius`, else the `k_nearest`, else within the radius
        that holds about NEIGHBOURS_IN_RADIUS samples on average.
        """
        if connectivity not in (4, 8):
            raise PlanningError(f"connectivity must be 4 or 8, got {connectivity}")
        grid = padded(free)
        free = np.asarray(free, dtype=bool)
        if samples < 1:
            raise PlanningError(f"a roadmap needs at least 1 sample, got {samples}")
        if radius is not None and radius <= 0:
            raise PlanningError(f"the roadmap radius must be positive, got {radius}")
        if k_nearest is not None and k_nearest < 1:
            raise PlanningError(f"k_nearest must be at least 1, got {k_nearest}")
        cells = np.flatnonzero(free)
        if cells.size == 0:
            raise PlanningError("the map has no free cell to sample")
        rng = np.random.default_rng(seed)
        pick = np.sort(rng.choice(cells, size=min(samples, cells.size), replace=False))
        w = free.shape[1]
        xs, ys = (pick % w).astype(np.int64), (pick // w).astype(np.int64)
        if radius is None and k_nearest is None:
            radius = math.sqrt(NEIGHBOURS_IN_RADIUS * cells.size / (math.pi * xs.size))
        tree = cKDTree(np.column_stack((xs, ys)).astype(float))
        if radius is not None:
            pairs = tree.query_pairs(radius, output_type="ndarray")
        else:
            k = min(k_nearest + 1, xs.size)
            _, nb = tree.query(np.column_stack((xs, ys)), k=k)
            nb = nb.reshape(xs.size, k)
            a = np.repeat(np.arange(xs.size), k - 1)
            b = nb[:, 1:].ravel()
            pairs = np.unique(np.column_stack((np.minimum(a, b), np.maximum(a, b))), axis=0)
        if limits is not None:
            limits.check("PRM roadmap")
        pairs = pairs.reshape(-1, 2).astype(np.int64)
        ok = _segments_free(grid, w + 2, xs[pairs[:, 0]], ys[pairs[:, 0]], xs[pairs[:, 1]], ys[pairs[:, 1]])
        pairs = pairs[ok]
        src = np.concatenate((pairs[:, 0], pairs[:, 1]))
        dst = np.concatenate((pairs[:, 1], pairs[:, 0]))
        order = np.argsort(src, kind="stable")
        src, dst = src[order], dst[order]
        indptr = np.zeros(xs.size + 1, dtype=np.int64)
        np.cumsum(np.bincount(src, minlength=xs.size), out=indptr[1:])
        weights = np.hypot((xs[dst] - xs[src]).astype(float), (ys[dst] - ys[src]).astype(float))
        return cls(free, grid, xs, ys, indptr, dst.astype(np.int64), weights, tree, connectivity,
                   radius, k_nearest)

    def _links(self, x: int, y: int) -> tuple[np.ndarray, np.ndarray]:
        """Roadmap nodes a query cell sees: by the build rule, else among the 64 nearest."""
        here = np.array([x, y], dtype=float)
        if self.radius is not None:
            near = np.asarray(self.tree.query_ball_point(here, self.radius), dtype=np.int64)
        else:
            near = np.atleast_1d(self.tree.query(here, k=min(self.k_nearest, self.nodes))[1]).astype(np.int64)
        wider = np.atleast_1d(self.tree.query(here, k=min(64, self.nodes))[1]).astype(np.int64)
        for cand in (near, wider):
            if cand.size == 0:
                continue
            ok = _segments_free(self.grid, self.free.shape[1] + 2, np.full(cand.size, x, np.int64),
                                np.full(cand.size, y, np.int64), self.xs[cand], self.ys[cand])
            if ok.any():
                cand = cand[ok]
                return cand, np.hypot((self.xs[cand] - x).astype(float), (self.ys[cand] - y).astype(float))
        return np.empty(0, dtype=np.int64), np.empty(0)

    def query(self, start: Cell, goal: Cell) -> list[Cell]:
        """A grid walk start -> goal along the roadmap; PlanningError when the roadmap does not join them."""
        sx, sy = check_cell(self.free, start, "start")
        gx, gy = check_cell(self.free, goal, "goal")
        width = self.free.shape[1] + 2
        diagonal = self.connectivity == 8
        ends = np.array([[sx], [sy], [gx], [gy]], dtype=np.int64)
        direct = _segments_free(self.grid, width, ends[0], ends[1], ends[2], ends[3])
        if direct[0]:
            px, py = np.array([sx, gx], dtype=np.int64), np.array([sy, gy], dtype=np.int64)
        else:
            s_nodes, s_w = self._links(sx, sy)
            g_nodes, g_w = self._links(gx, gy)
            goal_w = np.full(self.nodes, np.inf)
            goal_w[g_nodes] = g_w
            allx = np.concatenate((self.xs, [sx, gx])).astype(float)
            ally = np.concatenate((self.ys, [sy, gy])).astype(float)
            route = _graph_astar(allx, ally, self.indptr, self.indices, self.weights, s_nodes, s_w, goal_w)
            if route.size == 0:
                why = ("the start sees no roadmap node" if s_nodes.size == 0 else
                       "the goal sees no roadmap node" if g_nodes.size == 0 else
                       "they lie in parts of the roadmap that are not joined")
                raise PlanningError(f"PRM with {self.nodes} samples: no path from ({sx}, {sy}) to "
                                    f"({gx}, {gy}): {why}")
            px, py = allx[route].astype(np.int64), ally[route].astype(np.int64)
        walk = _rasterise(self.grid, width, px, py, diagonal)
        walk = _drop_loops(walk)
        if diagonal:
            walk = _shortcut_corners(self.grid, width, walk)
        return list(zip((walk % width - 1).tolist(), (walk // width - 1).tolist()))


def _drop_loops(walk: np.ndarray) -> np.ndarray:
    """Where a walk comes back to a cell it visited, cut out the detour (it stays a walk of neighbours)."""
    seen: dict[int, int] = {}
    out: list[int] = []
    for c in walk.tolist():
        if c in seen:
            for d in out[seen[c] + 1:]:
                del seen[d]
            del out[seen[c] + 1:]
            continue
        seen[c] = len(out)
        out.append(c)
    return np.asarray(out, dtype=np.int64)
