"""Anytime improvement of a plan by large neighbourhood search, after MAPF-LNS (Li, Chen,
Harabor, Stuckey & Koenig, "Anytime Multi-Agent Path Finding via Large Neighborhood
Search", IJCAI 2021).

Each round picks a delayed robot (a tournament among a few random ones, robots
whose recent rounds failed discounted), builds its neighbourhood (the robots
met along one of its shortest paths, MAPF-LNS's agent-based neighbourhood),
takes their paths out of the reservation table and replans them one by one
with SIPP (`sipp.py`) against everyone else's paths, in random order. Each
search is cut at the f that could still make the group cheaper, so a round
that cannot win stops early; the new paths are kept only when their sum of
costs is lower.
"""
from __future__ import annotations

import time

import numpy as np
from ..compile.jit import njit

from .distances import Instance, compile_problem
from .grid_kernels import (
    Grid,
    copy_into,
    downhill,
    grid_of,
    grow,
    new_visits,
    now,
    rand_next,
    seeded,
    shuffle,
)
from .pibt import arrivals
from .prioritized import max_expansions, split_paths
from .reservations import (
    Paths,
    Reservations,
    holder,
    new_paths,
    new_reservations,
    path_of,
    reserve,
    store,
    unreserve,
)
from .sipp import sipp
from ..types import Path, Problem

REFINE_EXPANSIONS = 50_000     # per replanning search: a refinement round must stay short
TOURNAMENT = 8                 # random robots a round's seed is the most delayed of
STALE_ROUNDS = 64              # rounds whose tournament found no delayed robot before a full scan


@njit(cache=True)
def _tournament(paths: Paths, d0, fails, rng) -> int:
    """The most delayed of a few random robots, each delay halved per recent failure; -1 if
    none of them is delayed."""
    na = d0.shape[0]
    a = -1
    best = 0
    for _ in range(TOURNAMENT):
        r = rand_next(rng) % na
        dl = (paths.length[r] - 1 - d0[r]) >> min(fails[r], 20)
        if dl > best:
            best = dl
            a = r
    return a


@njit(cache=True)
def _first_delayed(paths: Paths, d0) -> int:
    for r in range(d0.shape[0]):
        if paths.length[r] - 1 > d0[r]:
            return r
    return -1


@njit(cache=True)
def _join(members, in_group, m: int, b: int) -> int:
    if b >= 0 and not in_group[b] and m < members.shape[0]:
        members[m] = b
        in_group[b] = True
        m += 1
    return m


@njit(cache=True)
def _neighbourhood(g: Grid, res: Reservations, a: int, members, in_group, rng) -> int:
    """Robot a, then the robots met along one of a's shortest paths (holding a cell at the
    matching step or the next, or parked on it by then), topped up at random to three, in
    random order. Returns how many (<= members.size); in_group marks them."""
    group = members.shape[0]
    na = in_group.shape[0]
    m = _join(members, in_group, 0, a)
    drow = g.dist[g.rows[a]]
    v = g.starts[a]
    t = 0
    while m < group:
        for dt in range(2):
            m = _join(members, in_group, m, holder(res.seg, res.ta, v, t + dt))
        if res.park_time[v] <= t + 1:
            m = _join(members, in_group, m, res.park_owner[v])
        if v == g.goals[a]:
            break
        v = downhill(g.nbr, drow, v, rng, False)
        t += 1
    while m < min(group, na) and m < 3:
        m = _join(members, in_group, m, rand_next(rng) % na)
    shuffle(members, m, rng)
    return m


@njit(cache=True)
def _replan(g: Grid, res: Reservations, members, m: int, d0, old: int, new: Paths, max_expand: int, vis):
    """Plans the (taken out) group one robot at a time into `new` (by member slot), each
    search cut where the group could no longer beat `old`: (reservations, new, robots
    planned and booked, sum of their costs, success)."""
    cost = 0
    done = 0
    rest = 0
    for j in range(m):
        rest += d0[members[j]]
    for j in range(m):
        b = members[j]
        rest -= d0[b]
        f_max = old - 1 - cost - rest
        if f_max < d0[b]:
            return res, new, done, cost, False
        path = sipp(g, res, b, max_expand, f_max, vis)
        if path.shape[0] == 0:
            return res, new, done, cost, False
        cost += path.shape[0] - 1
        res = reserve(res, path, b)
        done += 1
        new = store(new, j, path)
        if cost >= old:
            return res, new, done, cost, False
    return res, new, done, cost, True


@njit(cache=True)
def _adopt(paths: Paths, new: Paths, members, m: int) -> Paths:
    """The group's new paths replace their old ones (appended to the buffer as one block)."""
    used = paths.end[0]
    filled = new.end[0]
    buf = grow(paths.buf, used + filled)
    for j in range(m):
        b = members[j]
        paths.off[b] = used + new.off[j]
        paths.length[b] = new.length[j]
    copy_into(buf, used, new.buf, filled)
    paths.end[0] = used + filled
    return Paths(buf, paths.off, paths.length, paths.end)


@njit(cache=True)
def _compact(paths: Paths) -> Paths:
    """A fresh buffer with only the live paths, and room for as much again."""
    live = 0
    for b in range(paths.off.shape[0]):
        live += paths.length[b]
    nb = np.empty(2 * live + 1024, dtype=np.int32)
    pos = 0
    for b in range(paths.off.shape[0]):
        copy_into(nb, pos, path_of(paths, b), paths.length[b])
        paths.off[b] = pos
        pos += paths.length[b]
    paths.end[0] = pos
    return Paths(nb, paths.off, paths.length, paths.end)


@njit(cache=True)
def _refine(g: Grid, d0, paths: Paths, max_expand: int, deadline: float, target: int, seed: int, group: int):
    """Large neighbourhood search rounds until the sum of costs reaches `target` or the time
    is up: (paths, sum of costs, rounds)."""
    n = g.nbr.shape[0]
    na = g.starts.shape[0]
    total = 0
    for a in range(na):
        total += paths.length[a]
    res = new_reservations(n, 2 * total)
    soc = 0
    for a in range(na):
        res = reserve(res, path_of(paths, a), a)
        soc += paths.length[a] - 1
    rng = seeded(seed)
    members = np.empty(group, dtype=np.int64)
    in_group = np.zeros(na, dtype=np.bool_)
    new = new_paths(group, 1024)
    fails = np.zeros(na, dtype=np.int32)    # recent fruitless tries per robot, to spread the effort
    vis = new_visits(n)
    it = 0
    stale = 0
    while soc > target:
        it += 1
        if now() > deadline:
            break
        a = _tournament(paths, d0, fails, rng)
        if a < 0:
            stale += 1
            if stale <= STALE_ROUNDS:
                continue
            a = _first_delayed(paths, d0)
            if a < 0:
                break
            for r in range(na):
                fails[r] = 0
            stale = 0
        m = _neighbourhood(g, res, a, members, in_group, rng)
        old = np.int64(0)   # not a literal 0, which numba would compile _replan for once more
        for j in range(m):
            b = members[j]
            old += paths.length[b] - 1
            unreserve(res, path_of(paths, b))
        new.end[0] = 0
        res, new, done, cost, ok = _replan(g, res, members, m, d0, old, new, max_expand, vis)
        if ok:
            paths = _adopt(paths, new, members, m)
            for j in range(m):
                fails[members[j]] = 0
            soc -= old - cost
        else:
            for j in range(done):
                unreserve(res, path_of(new, j))
            for j in range(m):
                res = reserve(res, path_of(paths, members[j]), members[j])
            fails[a] += 1
        for j in range(m):
            in_group[members[j]] = False
        if paths.end[0] > 4 * total + 4096:
            paths = _compact(paths)
            total = paths.end[0]
    return paths, soc, it


def trimmed(inst: Instance, hist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Configurations [T, n] -> flat per-robot cell-id paths cut after each last arrival."""
    plen = (arrivals(inst, hist) + 1).astype(np.int64)
    poff = np.concatenate(([0], np.cumsum(plen)[:-1])).astype(np.int64)
    buf = np.concatenate([hist[:plen[i], i] for i in range(inst.n)]).astype(np.int32)
    return buf, poff, plen


def refine(inst: Instance, buf, poff, plen, seconds: float, target_ratio: float = 1.0, group: int = 8):
    """Anytime improvement of a plan given as flat cell-id paths (see `trimmed`): at most
    `seconds`, stopping early at `target_ratio` x the lower bound.
    Returns (buf, poff, plen, sum of costs, iterations)."""
    d0 = inst.start_distances()
    target = int(np.floor(target_ratio * d0.sum()))
    poff = np.array(poff, dtype=np.int64)
    plen = np.array(plen, dtype=np.int64)
    end = np.array([int((poff + plen).max(initial=0))], dtype=np.int64)
    cap = min(max_expansions(inst), REFINE_EXPANSIONS)
    paths, soc, it = _refine(grid_of(inst), d0, Paths(buf, poff, plen, end), cap, time.perf_counter() + seconds,
                             target, int(inst.problem.seed), group)
    return paths.buf, paths.off, paths.length, soc, it


def improve(problem: Problem, paths: list[Path], seconds: float, group: int = 8) -> tuple[list[Path], int]:
    """`refine` for a plan given as cell paths: the paths, each cut after its last arrival (no
    dearer than before), and the rounds run. Stops at once when no robot is delayed."""
    inst = compile_problem(problem)
    w = problem.free.shape[1]
    ids = []
    for p in paths:
        a = inst.graph.index[np.array([y * w + x for x, y in p], dtype=np.int64)].astype(np.int32)
        k = len(a)
        while k > 1 and a[k - 2] == a[-1]:
            k -= 1
        ids.append(a[:k])
    plen = np.array([len(a) for a in ids], dtype=np.int64)
    poff = np.concatenate(([0], np.cumsum(plen)[:-1])).astype(np.int64)
    if int((plen - 1).sum()) <= inst.lower_bound():
        return split_paths(inst, np.concatenate(ids), poff, plen), 0
    buf, poff, plen, _, rounds = refine(inst, np.concatenate(ids), poff, plen, seconds, group=group)
    return split_paths(inst, buf, poff, plen), int(rounds)
