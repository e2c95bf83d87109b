"""The running plan repaired around the movers' forecast, one tick at a time: rolling-horizon
replanning in the manner of RHCR (Li et al., "Lifelong Multi-Agent Path Finding in
Large-Scale Warehouses", AAAI 2021), which resolves what it must within a window of the
next W ticks and leaves the rest to the next round.

Before each tick k the forecast (`forecast.py`) closes cells to entry for ticks up to k + W,
the stretch it is trusted for (the next image will refresh it). A robot that stays on its
cell is always safe (no mover steps into a robot's cell), so only entries count: the robots
whose steps within [k+1, k+W] enter a closed cell are replanned, each with SIPP against the
others' paths as reservations and the forecast as cells closed for a while
(`mapf/dynamic.py`), keeping its goal; the other robots keep their paths, unchanged. A
robot for which no such path exists is held: it stays on its cell through the window and
then goes on by the earliest path from there, and the robots whose paths cross its cell in
the window are replanned too (the cascade: only these). Since the window slides by one every
tick and the very next step is always inside it, no robot ever steps where a mover may be,
whatever the window's length. A longer one sees trouble coming earlier and keeps the plan
safe up to the next image should a tick's repair not run; a shorter one holds fewer robots
back for cells a mover will most likely never reach.

A held robot that finds no way on afterwards (its delay put it behind a robot that parks in
its way for good, say) has the robots sharing a cell with its old way planned again after
it, as prioritized planning's repair does (`mapf/prioritized.py`). Should that fail too, or
the tick's budget run out, every robot is held: the whole plan waits W ticks, a shift that
keeps it conflict-free and enters nothing in the window (`Repair.frozen`). Every result is
conflict-free by construction; the tests check it with the independent validator.
"""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import chain

import numpy as np

from protocol.errors import PlanningError

from .forecast import Forecast
from .mapf.distances import UNREACHABLE_16, GridGraph, distance_fields, grid_graph
from .mapf.dynamic import OPEN, book_all, met_forecast, plan_around
from .mapf.grid_kernels import Geometry, Grid, new_visits
from .mapf.reservations import new_reservations, reserve, unreserve
from .types import Cell

BUDGET_S = 0.05           # one tick's repair: the 50 ms
MAX_EXPAND = 100_000      # per search: a repair that drags on holds rather than stalls the tick
LINGER = 8                # ticks past the window a mover is planned around on the cell it was last seen on
STATIC = 400              # ... a pallet, which stays where it fell


@dataclass(frozen=True)
class Repair:
    paths: dict[int, list[Cell]]      # every robot's path from the tick on (unchanged ones: the caller's own lists)
    met: frozenset[int]               # robots whose steps in the window entered a cell the forecast closed
    replanned: frozenset[int]         # robots given a new path (met, or in a held robot's way)
    held: frozenset[int]              # robots held on their cells through the window
    frozen: bool                      # every robot held: a hold found no way on, or the budget ran out
    seconds: float
    displaced: frozenset[int] = frozenset()   # robots replanned because a held robot needed their way


_GEOMETRY: list[tuple[GridGraph, Geometry]] = []


def geometry_of(graph: GridGraph) -> Geometry:
    if not _GEOMETRY or _GEOMETRY[0][0] is not graph:
        xs, ys = graph.xy()
        _GEOMETRY[:] = [(graph, Geometry(xs.astype(np.int32), ys.astype(np.int32), graph.index,
                                         int(graph.width), graph.connectivity == 8))]
    return _GEOMETRY[0][1]


def _ids(graph: GridGraph, paths: list[Sequence[Cell]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All paths as compact ids in one buffer: (buf, offsets, lengths)."""
    length = np.fromiter((len(p) for p in paths), dtype=np.int64, count=len(paths))
    if (length == 0).any():
        raise PlanningError(f"robot path {int(np.flatnonzero(length == 0)[0])} is empty")
    xy = np.fromiter(chain.from_iterable(chain.from_iterable(paths)), dtype=np.int64,
                     count=2 * int(length.sum())).reshape(-1, 2)
    h, w = graph.free.shape
    if ((xy < 0) | (xy >= (w, h))).any():
        raise PlanningError("a path leaves the grid")
    buf = graph.index[xy[:, 1] * w + xy[:, 0]]
    if (buf < 0).any():
        raise PlanningError("a path crosses an obstacle")
    off = np.zeros(len(paths), dtype=np.int64)
    np.cumsum(length[:-1], out=off[1:])
    return buf.astype(np.int32), off, length


def closures(graph: GridGraph, forecast: Forecast, tick: int, window: int, linger: int = LINGER,
             static: int = STATIC) -> tuple[np.ndarray, np.ndarray]:
    """Per compact cell, the steps after `tick` it is closed to entry: from closed[v] (OPEN: never)
    to until[v].

    Within the window the forecast is the rule. Past it a plan would walk into a pallet, or a
    forklift parked in an aisle, as soon as the window has slid by, wait for that, and wait
    again the next tick (the rolling horizon's livelock); so each mover's own cell stays closed
    a while longer, as a preference: a search that finds no way so is run again without it.
    """
    closed = np.full(graph.n, OPEN, dtype=np.int32)
    until = np.full(graph.n, window, dtype=np.int32)
    soon = forecast.first <= tick + window
    ids = graph.index[forecast.flat[soon]]
    ok = ids >= 0
    closed[ids[ok]] = np.maximum(forecast.first[soon][ok] - tick, 0)
    h, w = graph.free.shape
    for r in forecast.reaches:
        x, y = r.cell
        v = graph.index[y * w + x] if 0 <= x < w and 0 <= y < h else -1
        if v >= 0 and closed[v] != OPEN:
            until[v] = window + (static if r.speed == 0 else linger)
    return closed, until


class _Cascade:
    """The replanning of one repair: robots planned one after another against the booked paths,
    held robots' cells cleared of whoever is booked there in the window (they are planned again)."""

    def __init__(self, g: Grid, res, current: list[np.ndarray], booked: np.ndarray, closed: np.ndarray,
                 until: np.ndarray, window: int, max_expand: int, vis) -> None:
        self.g, self.res, self.current, self.booked = g, res, current, booked
        self.closed, self.until, self.window, self.max_expand, self.vis = closed, until, window, max_expand, vis
        self.hard = np.full(closed.shape[0], window, dtype=np.int32)
        self.replanned: set[int] = set()
        self.held: set[int] = set()
        self.cleared: set[int] = set()
        self.displaced: set[int] = set()
        self.queue: deque[int] = deque()

    def route(self, a: int, hold: int) -> np.ndarray:
        """Robot a's earliest path, staying on its cell up to `hold`: around the movers' cells past
        the window if it can (`closures`), else around the window's alone."""
        for until in (self.until, self.hard):
            p = plan_around(self.g, self.res, a, self.closed, until, hold, self.max_expand, self.vis)
            if p.size:
                return p
        return p

    def evict(self, b: int) -> None:
        self.displaced.add(b)
        unreserve(self.res, self.current[b])
        self.booked[b] = False
        self.replanned.discard(b)
        self.held.discard(b)
        self.queue.append(b)

    def book(self, a: int, p: np.ndarray) -> None:
        self.res = reserve(self.res, p, a)
        self.current[a] = p
        self.booked[a] = True

    def run(self, order: list[int], deadline: float) -> bool:
        """Plans the robots of `order` and those they displace; False when a held robot finds no
        way on even with the robots on its old way out of it, or the deadline passes."""
        self.queue.extend(order)
        while self.queue:
            if time.perf_counter() > deadline:
                return False
            a = self.queue.popleft()
            p = self.route(a, 0)
            if p.size:
                self.replanned.add(a)
                self.book(a, p)
                continue
            # held: whoever is booked on its cell within the window makes way
            c = self.g.starts[a]
            for b in np.flatnonzero(self.booked).tolist():
                if b != a and (self.current[b][:self.window + 1] == c).any():
                    self.evict(b)
            p = self.route(a, self.window)
            if p.size == 0 and a not in self.cleared:
                # its delay put it behind robots it used to pass, one parked in its way for good, say:
                # those sharing a cell with its old way are planned again after it (once per robot)
                self.cleared.add(a)
                way = set(self.current[a].tolist())
                for b in np.flatnonzero(self.booked).tolist():
                    if b != a and not way.isdisjoint(self.current[b].tolist()):
                        self.evict(b)
                p = self.route(a, self.window)
            if p.size == 0:
                return False
            self.held.add(a)
            self.book(a, p)
        return True


def repair(free: np.ndarray, paths: Mapping[int, Sequence[Cell]], forecast: Forecast, tick: int, window: int,
           connectivity: int = 4, *, budget_s: float = BUDGET_S, max_expand: int = MAX_EXPAND,
           linger: int = LINGER, static: int = STATIC) -> Repair:
    """The paths from tick `tick` on, none entering a cell the forecast closes within ticks
    (tick, tick + window].

    paths: robot -> its cells for ticks tick, tick + 1, ..., its goal last: a conflict-free plan
    (the one the fleet runs); path[0] is where the robot stands now.
    """
    began = time.perf_counter()
    if window < 1:
        raise ValueError(f"the window must be at least one tick, got {window}")
    if forecast.shape != np.shape(free):
        raise ValueError(f"a forecast of a {forecast.shape} floor for a {np.shape(free)} one")
    if forecast.until < tick + window:
        raise ValueError(f"a forecast up to tick {forecast.until} cannot close cells up to tick {tick + window}")
    robots = sorted(paths)
    plan = [paths[r] for r in robots]
    graph = grid_graph(np.asarray(free, dtype=bool), connectivity)
    buf, off, length = _ids(graph, plan)
    closed, until = closures(graph, forecast, tick, window, linger, static)
    met = np.zeros(len(robots), dtype=np.bool_)
    met_forecast(buf, off, length, closed, window, met)
    if not met.any():
        return Repair(dict(zip(robots, plan)), frozenset(), frozenset(), frozenset(), False,
                      time.perf_counter() - began)

    starts = buf[off]
    goals = buf[off + length - 1]
    table = distance_fields(graph.free, [graph.cell_of(int(v)) for v in goals], connectivity)
    g = Grid(graph.nbr, geometry_of(graph), table.dist, table.rows, int(table.unreachable), starts, goals)
    res = new_reservations(graph.n, 2 * int(length.sum()) + 1024)
    res = book_all(res, buf, off, length, np.flatnonzero(~met).astype(np.int64))
    current = [buf[off[a]:off[a] + length[a]] for a in range(len(robots))]
    # the longest trips first: they set the makespan
    order = sorted(np.flatnonzero(met).tolist(), key=lambda a: (-int(length[a]), a))
    fix = _Cascade(g, res, current, ~met, closed, until, window, max_expand, vis=new_visits(graph.n))
    frozen = not fix.run(order, began + budget_s)
    replanned, held = fix.replanned, fix.held
    if frozen:
        # every robot waits out the window, then runs the plan it had: a shift of a conflict-free plan
        out = {r: [p[0]] * window + list(p) for r, p in zip(robots, plan)}
        return Repair(out, frozenset(robots[a] for a in np.flatnonzero(met)), frozenset(), frozenset(robots),
                      True, time.perf_counter() - began)
    w = graph.width
    out = dict(zip(robots, plan))
    for a in replanned | held:
        flat = graph.cells[current[a]]
        out[robots[a]] = list(zip((flat % w).tolist(), (flat // w).tolist()))
    return Repair(out, frozenset(robots[a] for a in np.flatnonzero(met)), frozenset(robots[a] for a in replanned),
                  frozenset(robots[a] for a in held), False, time.perf_counter() - began,
                  frozenset(robots[a] for a in fix.displaced))



def warm_up() -> float:
    """Compiles the repair's kernels (or loads them from numba's cache) on a three-cell corridor
    built here, not through the planners' one-map caches (which hold the mission's floor), so
    that no tick's budget pays for it: the seconds it took."""
    began = time.perf_counter()
    n = 3
    ids = np.arange(n, dtype=np.int32)
    nbr = np.array([[1, -1, -1, -1], [2, 0, -1, -1], [1, -1, -1, -1]], dtype=np.int32)
    g = Grid(nbr, Geometry(ids.copy(), np.zeros(n, dtype=np.int32), ids.copy(), n, False),
             np.array([[2, 1, 0]], dtype=np.uint16), np.zeros(1, dtype=np.int32), int(UNREACHABLE_16),
             np.array([0], dtype=np.int32), np.array([2], dtype=np.int32))
    buf, off, length = ids.copy(), np.zeros(1, dtype=np.int64), np.array([n], dtype=np.int64)
    closed = np.array([OPEN, 1, OPEN], dtype=np.int32)
    met = np.zeros(1, dtype=np.bool_)
    met_forecast(buf, off, length, closed, 1, met)
    res = book_all(new_reservations(n, 16), buf, off, length, np.zeros(0, dtype=np.int64))
    p = plan_around(g, res, 0, closed, np.full(n, 1, dtype=np.int32), 0, MAX_EXPAND, new_visits(n))
    res = reserve(res, p, 0)
    unreserve(res, p)
    return time.perf_counter() - began
