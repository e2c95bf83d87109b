"""Prioritized planning: robots one after another, each routed around the paths before it.

The method of Erdmann & Lozano-Pérez ("On Multiple Moving Objects",
Algorithmica 1987) as Silver's cooperative A* ("Cooperative Pathfinding", AIIDE
2005) runs it: each robot books its path in a reservation table
(`reservations.py`) that the robots after it avoid, here found by SIPP
(`sipp.py`) with the exact distance field as heuristic. A robot avoids vertex,
swap and, in 8-connectivity, crossing-diagonal conflicts with earlier paths and
the goals where earlier robots have parked for good; it may only end on its
own goal once no earlier path crosses that goal later.

Robots with shorter shortest paths go first. (The usual longer-first order
was measured worse: a short-trip robot then has to wait until every long
trip has crossed its goal; on the 450x450 warehouse with 500 robots that
gives a sum of costs 12 % above the lower bound against 0.02 %.)

A robot that finds no path gets a local repair: the robots walling in its
start or goal and those in its way are taken out, it is planned, and they are
planned again after it. If that fails, the robot moves to the front of the
order and the planning restarts, as in the search over priority schemes of
Bennewitz, Burgard & Thrun ("Finding and Optimizing Solvable Priority Schemes
for Decoupled Path Planning Techniques for Teams of Mobile Robots", Robotics
and Autonomous Systems 2002), with random reorders after a few tries, up to
MAX_TRIES orders or the time limit.

`guide_paths` is one pass that skips the robots it cannot route: the default
planner (`planning/portfolio.py`) uses its paths as a plan when complete and as
LaCAM's PIBT's guides otherwise.
"""
from __future__ import annotations

import math
import time

import numpy as np
from ..compile.jit import njit

from protocol.errors import PlanningError, PlanningTimeout

from .distances import Instance, compile_problem
from .grid_kernels import Grid, Visits, begin_visits, downhill, grid_of, new_visits, now
from .reservations import (
    Paths,
    Reservations,
    holder,
    new_paths,
    new_reservations,
    parked_by_other,
    path_of,
    reserve,
    store,
    unreserve,
)
from .sipp import sipp
from ..types import Limits, Path, Problem

UNBOUNDED = np.int64(2**40)      # an f bound that never cuts a search (int64, not a literal: see blockers)
MAX_TRIES = 100                  # orders tried before prioritized planning gives up
REPAIR_GROUP = 12                # robots a blocked robot may displace (replanned after it)
WALL_CELLS = 400                 # ... among them robots parked around its start or goal (cells searched)


@njit(cache=True)
def _add_new(out: np.ndarray, m: int, b: int) -> int:
    """Appends robot b to out[:m] unless it is there already or out is full; returns the count."""
    if m >= out.shape[0]:
        return m
    for k in range(m):
        if out[k] == b:
            return m
    out[m] = b
    return m + 1


@njit(cache=True)
def _walls(g: Grid, res: Reservations, a: int, src: int, out, m: int, vis: Visits) -> int:
    """Adds to out[m:] the robots parked on the rim of the region around src that is not
    parked on (breadth-first, nearest first, a few hundred cells at most)."""
    mark = begin_visits(vis, src)
    head = 0
    tail = 1
    while head < tail < WALL_CELLS and m < out.shape[0]:
        v = vis.queue[head]
        head += 1
        for j in range(g.nbr.shape[1]):
            u = g.nbr[v, j]
            if u < 0:
                break
            if vis.stamp[1 + u] == mark:
                continue
            vis.stamp[1 + u] = mark
            if parked_by_other(res.park_owner, u, a):
                m = _add_new(out, m, res.park_owner[u])
                continue
            vis.queue[tail] = u
            tail += 1
    return m


@njit(cache=True)
def blockers(g: Grid, res: Reservations, a: int, out: np.ndarray, rng, vis: Visits) -> int:
    """Robots in the way of robot a: those parked around its goal or start, then along one of
    its shortest paths (random ties) those that hold a cell at the matching step or the next
    one, or park on it. Returns how many (<= out.size). Every robot the table names has its
    path booked, so all of them can be taken out and planned again."""
    # an int64 0, not a literal one, which numba would compile _walls for once more
    m = np.int64(0)
    goal = g.goals[a]
    # robots parked around a's goal or start may wall them in: they come first
    for src in (goal, g.starts[a]):
        m = _walls(g, res, a, src, out, m, vis)
    drow = g.dist[g.rows[a]]
    v = g.starts[a]
    t = 0
    while m < out.shape[0]:
        for dt in range(2):
            b = holder(res.seg, res.ta, v, t + dt)
            if b >= 0 and b != a:
                m = _add_new(out, m, b)
        if parked_by_other(res.park_owner, v, a):
            m = _add_new(out, m, res.park_owner[v])
        if v == goal:
            break
        v = downhill(g.nbr, drow, v, rng, True)
        t += 1
    return m


@njit(cache=True, inline='always')
def _by_rank(group: np.ndarray, m: int, rank: np.ndarray) -> None:
    """Insertion sort of group[:m] by rank in the order."""
    for j in range(1, m):
        x = group[j]
        i = j
        while i > 0 and rank[group[i - 1]] > rank[x]:
            group[i] = group[i - 1]
            i -= 1
        group[i] = x


@njit(cache=True)
def _repair(g: Grid, res: Reservations, paths: Paths, a: int, rank, rng, max_expand: int, vis: Visits):
    """Robot a found no path: take its blockers out, plan a, then them again (in their own
    priority order). Returns (reservations, paths, success); on failure everything is as before."""
    group = np.empty(REPAIR_GROUP, dtype=np.int64)
    m = blockers(g, res, a, group, rng, vis)
    if m == 0:
        return res, paths, False
    _by_rank(group, m, rank)
    old_off = np.empty(m, dtype=np.int64)
    old_len = np.empty(m, dtype=np.int64)
    for j in range(m):
        b = group[j]
        old_off[j] = paths.off[b]
        old_len[j] = paths.length[b]
        unreserve(res, path_of(paths, b))
    path = sipp(g, res, a, max_expand, UNBOUNDED, vis)
    if path.shape[0] > 0:
        res = reserve(res, path, a)
        paths = store(paths, a, path)
        done = 0
        for j in range(m):
            b = group[j]
            p = sipp(g, res, b, max_expand, UNBOUNDED, vis)
            if p.shape[0] == 0:
                break
            res = reserve(res, p, b)
            paths = store(paths, b, p)
            done += 1
        if done == m:
            return res, paths, True
        for j in range(done):
            unreserve(res, path_of(paths, group[j]))
        unreserve(res, path_of(paths, a))
        paths.length[a] = 0
    for j in range(m):
        b = group[j]
        paths.off[b] = old_off[j]
        paths.length[b] = old_len[j]
        res = reserve(res, path_of(paths, b), b)
    return res, paths, False


@njit(cache=True)
def _plan_in_order(g: Grid, order, max_expand: int, deadline: float, skip_failures: bool):
    """Plans robots in `order`: (first failed robot, or -1, or -2 on timeout; their Paths).

    A robot that finds no path gets one repair. With skip_failures a robot still without a
    path gets length 0 and the others are planned; without, planning stops there.
    """
    n = g.nbr.shape[0]
    na = g.starts.shape[0]
    res = new_reservations(n, 4 * n)
    paths = new_paths(na, 1024)
    rank = np.full(na, na, dtype=np.int32)
    for r in range(order.shape[0]):
        rank[order[r]] = r
    rng = np.array([np.uint64(12345)], dtype=np.uint64)
    vis = new_visits(n)
    first_failed = -1
    for r in range(order.shape[0]):
        if now() > deadline:
            return -2, paths
        a = order[r]
        path = sipp(g, res, a, max_expand, UNBOUNDED, vis)
        if path.shape[0] > 0:
            res = reserve(res, path, a)
            paths = store(paths, a, path)
            continue
        res, paths, ok = _repair(g, res, paths, a, rank, rng, max_expand, vis)
        if ok:
            continue
        if not skip_failures:
            return a, paths
        if first_failed < 0:
            first_failed = a
    return first_failed, paths


def max_expansions(inst: Instance) -> int:
    """A per-search expansion cap, so one stuck robot triggers a restart rather than a long search."""
    return int(min(4_000_000, max(200_000, 4 * inst.graph.n)))


def split_paths(inst: Instance, buf: np.ndarray, poff: np.ndarray, plen: np.ndarray) -> list[Path]:
    return inst.to_paths([buf[poff[i]:poff[i] + plen[i]] for i in range(inst.n)])


def prioritized(problem: Problem, limits: Limits) -> list[Path]:
    """Prioritized planning with space-time A*; PlanningError if no order works within the limit."""
    inst = compile_problem(problem)
    if inst.n == 0:
        return []
    ok, buf, poff, plen, tries, failed = plan_prioritized(inst, limits)
    if not ok:
        if limits.expired():
            raise PlanningTimeout(f"prioritized planning: time limit of {limits.seconds:g} s reached after "
                                f"{tries} priority orders")
        raise PlanningError(f"prioritized planning: no conflict-free priority order in {tries} tries "
                            f"(robot {failed} from {tuple(problem.starts[failed])} stays blocked)")
    return split_paths(inst, buf, poff, plen)


def _shortest_first(inst: Instance, rng: np.random.Generator) -> np.ndarray:
    # shorter paths first (see the module doc); the random key breaks ties reproducibly
    return np.lexsort((rng.random(inst.n), inst.start_distances())).astype(np.int64)


def first_then_shortest(inst: Instance, first: np.ndarray) -> np.ndarray:
    """The shortest-first order with the robots `first` moved to its front (in that order)."""
    order = _shortest_first(inst, np.random.default_rng(inst.problem.seed))
    first = np.asarray(first, dtype=np.int64)
    return np.concatenate((first, order[~np.isin(order, first)])).astype(np.int64)


def plan_prioritized(inst: Instance, limits: Limits, max_tries: int | None = None, order: np.ndarray | None = None):
    """Restarts until an order works: (ok, flat paths, offsets, lengths, tries, last failed robot).

    Gives up after `max_tries` orders (default: MAX_TRIES, or every order of a handful of robots).
    `order` is the first order tried (default: shortest first).
    """
    if max_tries is None:
        max_tries = min(MAX_TRIES, math.factorial(min(inst.n, 8)))
    g = grid_of(inst)
    rng = np.random.default_rng(inst.problem.seed)
    if order is None:
        order = _shortest_first(inst, rng)
    failed = -1
    tries = 0
    cap = max_expansions(inst)
    while tries < max_tries:
        limits.check("prioritized planning")
        tries += 1
        deadline = time.perf_counter() + limits.remaining()
        failed, paths = _plan_in_order(g, order, cap, deadline, False)
        if failed == -1:
            return True, paths.buf, paths.off, paths.length, tries, -1
        if failed == -2:
            break
        pos = int(np.flatnonzero(order == failed)[0])
        if tries % 4 == 0:
            # promoting the blocked robot keeps failing: shuffle the rest of the order
            rest = np.delete(order, pos)
            rng.shuffle(rest)
            order = np.concatenate(([failed], rest)).astype(np.int64)
        else:
            order = np.concatenate(([failed], np.delete(order, pos))).astype(np.int64)
    return False, None, None, None, tries, failed


def guide_paths(inst: Instance, limits: Limits, max_expand: int):
    """One prioritized pass that skips robots it cannot route: (flat paths, offsets, lengths, complete?).

    Unrouted robots get length 0. None when the time runs out. The paths are
    conflict-free among themselves; LaCAM uses them to guide PIBT.
    """
    order = _shortest_first(inst, np.random.default_rng(inst.problem.seed))
    failed, paths = _plan_in_order(grid_of(inst), order, max_expand, time.perf_counter() + limits.remaining(), True)
    if failed == -2:
        return None
    return paths.buf, paths.off, paths.length, failed == -1
