"""Prioritized planning: robots one after another, each with space-time A* around the paths before it.

Robots with shorter shortest paths go first. (The usual longer-first order
was measured worse: a short-trip robot then has to wait until every long trip
has crossed its goal; on the 450x450 warehouse with 500 robots that gives a
sum of costs 12 % above the lower bound against 0.02 % shorter-first.) A robot's path is found by A*
over (cell, step) with the exact distance field as heuristic, avoiding the
reservation table of earlier paths (vertex, swap and, in 8-connectivity,
crossing-diagonal conflicts) and the goals where earlier robots have parked
for good; it may only end on its own goal once no earlier path crosses that
goal later. When a robot finds no path, it moves to the front of the order
and the planning restarts (with random reorders after a few tries), up to
MAX_TRIES orders or the time limit.

The reservation table and the search are numba kernels shared with the
LaCAM refinement (`lacam.py`), which replans groups of robots with them.
"""
from __future__ import annotations

import math
import time

import numpy as np
from numba import njit, objmode

from protocol.errors import PlanningError

from .distances import Instance, compile_problem
from .types import Limits, Path, Problem

EMPTY = -1
TOMB = -2
NEVER = np.iinfo(np.int32).max   # park time of a cell nobody parks on
MAX_TRIES = 100                  # orders tried before prioritized planning gives up
REPAIR_GROUP = 12                # robots a blocked robot may displace (replanned after it)
WALL_CELLS = 400                 # ... among them robots parked around its start or goal (cells searched)


@njit(cache=True)
def now() -> float:
    with objmode(t="float64"):
        t = time.perf_counter()
    return t


# ---- small array helpers: explicit loops, because numpy slice assignment and concatenate
# ---- pull broadcasting and error-formatting code into every kernel and slow compiling down

@njit(cache=True)
def copy_into(dst: np.ndarray, at: int, src: np.ndarray, count: int) -> None:
    for i in range(count):
        dst[at + i] = src[i]


@njit(cache=True)
def grow(a: np.ndarray, need: int) -> np.ndarray:
    """a itself if it holds `need` items, else a copy at least twice as long."""
    if need <= a.shape[0]:
        return a
    size = max(need, 2 * a.shape[0])
    b = np.empty(size, dtype=a.dtype)
    for i in range(a.shape[0]):
        b[i] = a[i]
    return b


@njit(cache=True)
def order_by_priority(prio: np.ndarray, out: np.ndarray) -> None:
    """out = robot indices by decreasing priority (heapsort; ties by index)."""
    n = prio.shape[0]
    for i in range(n):
        out[i] = i
    # a min-heap on priority, popped to the back, leaves the array in decreasing order
    for start in range((n - 2) // 2, -1, -1):
        _sift(prio, out, start, n)
    for end in range(n - 1, 0, -1):
        tmp = out[0]
        out[0] = out[end]
        out[end] = tmp
        _sift(prio, out, 0, end)


@njit(cache=True)
def _sift(prio, out, i: int, n: int) -> None:
    while True:
        c = 2 * i + 1
        if c >= n:
            return
        if c + 1 < n and _before(prio, out[c + 1], out[c]):
            c += 1
        if not _before(prio, out[c], out[i]):
            return
        tmp = out[i]
        out[i] = out[c]
        out[c] = tmp
        i = c


@njit(cache=True, inline='always')
def _before(prio, a: int, b: int) -> bool:
    """Heap order: lower priority first, then higher index (so the result reads high to low)."""
    return prio[a] < prio[b] or (prio[a] == prio[b] and a > b)


# ---- open-addressing hash map int64 -> int32 (keys >= 0; EMPTY/TOMB markers) ----
# Keys are (cell << 32 | step). The slot scatters cells but keeps the steps of one cell
# next to each other, so the lookups of one search step mostly share cache lines.

@njit(cache=True, inline='always')
def st_key(v: int, t: int) -> int:
    return (np.int64(v) << np.int64(32)) | np.int64(t)


@njit(cache=True, inline='always')
def _slot(key: int, mask: int) -> int:
    h = np.uint64(key >> np.int64(32)) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64(((h >> np.uint64(29)) + np.uint64(key & np.int64(0xFFFFFFFF))) & np.uint64(mask))


@njit(cache=True, inline='always')
def hm_get(keys: np.ndarray, vals: np.ndarray, key: int) -> int:
    mask = keys.shape[0] - 1
    s = _slot(key, mask)
    while True:
        k = keys[s]
        if k == key:
            return vals[s]
        if k == EMPTY:
            return -1
        s = (s + 1) & mask


@njit(cache=True, inline='always')
def hm_put(keys: np.ndarray, vals: np.ndarray, meta: np.ndarray, key: int, val: int) -> None:
    """Insert or overwrite; meta[0] counts used slots (live + tombstones), meta[1] live keys."""
    mask = keys.shape[0] - 1
    s = _slot(key, mask)
    tomb = -1
    while True:
        k = keys[s]
        if k == key:
            vals[s] = val
            return
        if k == EMPTY:
            break
        if k == TOMB and tomb < 0:
            tomb = s
        s = (s + 1) & mask
    if tomb >= 0:
        s = tomb
    else:
        meta[0] += 1
    keys[s] = key
    vals[s] = val
    meta[1] += 1


@njit(cache=True)
def hm_del(keys: np.ndarray, meta: np.ndarray, key: int) -> None:
    mask = keys.shape[0] - 1
    s = _slot(key, mask)
    while True:
        k = keys[s]
        if k == key:
            keys[s] = TOMB
            meta[1] -= 1
            return
        if k == EMPTY:
            return
        s = (s + 1) & mask


@njit(cache=True)
def hm_new(capacity: int):
    cap = 16
    while cap < 2 * capacity:
        cap *= 2
    return np.full(cap, EMPTY, dtype=np.int64), np.empty(cap, dtype=np.int32), np.zeros(2, dtype=np.int64)


@njit(cache=True, inline='always')
def hm_full(keys: np.ndarray, meta: np.ndarray) -> bool:
    """More than half the slots used (tombstones count): time to call hm_grow."""
    return 2 * meta[0] > keys.shape[0]


@njit(cache=True)
def hm_grow(keys: np.ndarray, vals: np.ndarray, meta: np.ndarray):
    """A fresh table holding the live keys, with room to grow."""
    nk, nv, nm = hm_new(2 * meta[1] + 16)
    for s in range(keys.shape[0]):
        if keys[s] >= 0:
            hm_put(nk, nv, nm, keys[s], vals[s])
    return nk, nv, nm


# ---- reservations: (cell, step) -> robot, park times of goals, latest use of each cell ----

@njit(cache=True)
def reserve(keys, vals, meta, n: int, path: np.ndarray, agent: int, park_time: np.ndarray,
            park_owner: np.ndarray, last_use: np.ndarray):
    """Books a path (its last cell is the robot's goal, held from then on)."""
    for t in range(path.shape[0]):
        v = path[t]
        hm_put(keys, vals, meta, st_key(v, t), agent)
        if hm_full(keys, meta):
            keys, vals, meta = hm_grow(keys, vals, meta)
        if t > last_use[v]:
            last_use[v] = t
    g = path[path.shape[0] - 1]
    park_time[g] = path.shape[0] - 1
    park_owner[g] = agent
    return keys, vals, meta


@njit(cache=True)
def unreserve(keys, meta, n: int, path: np.ndarray, park_time: np.ndarray, park_owner: np.ndarray) -> None:
    """Removes a path; last_use stays an upper bound, which only makes goal checks scan further."""
    for t in range(path.shape[0]):
        hm_del(keys, meta, st_key(path[t], t))
    g = path[path.shape[0] - 1]
    park_time[g] = NEVER
    park_owner[g] = -1


@njit(cache=True, inline='always')
def _blocked(keys, vals, n: int, v: int, u: int, t: int, agent: int, park_time, park_owner,
             xs, ys, index, width: int) -> bool:
    """Whether moving v -> u between steps t and t+1 conflicts with a reservation."""
    t1 = t + 1
    if park_time[u] <= t1 and park_owner[u] != agent:
        return True
    if hm_get(keys, vals, st_key(u, t1)) >= 0:
        return True
    if u != v:
        b = hm_get(keys, vals, st_key(v, t1))
        if b >= 0 and hm_get(keys, vals, st_key(u, t)) == b:
            return True  # swap
        if xs[u] != xs[v] and ys[u] != ys[v]:
            p = index[ys[v] * width + xs[u]]
            q = index[ys[u] * width + xs[v]]
            b = hm_get(keys, vals, st_key(p, t))
            if b >= 0 and hm_get(keys, vals, st_key(q, t1)) == b:
                return True  # crossing diagonals
            b = hm_get(keys, vals, st_key(q, t))
            if b >= 0 and hm_get(keys, vals, st_key(p, t1)) == b:
                return True
    return False


@njit(cache=True)
def _heap_grow(hk, hn):
    return grow(hk, hk.shape[0] + 1), grow(hn, hn.shape[0] + 1)


@njit(cache=True, inline='always')
def _heap_push(hk, hn, hsize: int, key: int, node: int) -> None:
    """Adds (key, node); the caller makes sure hsize < capacity."""
    i = hsize
    while i > 0:
        p = (i - 1) >> 1
        if hk[p] <= key:
            break
        hk[i] = hk[p]
        hn[i] = hn[p]
        i = p
    hk[i] = key
    hn[i] = node


@njit(cache=True, inline='always')
def _heap_pop(hk, hn, hsize: int) -> None:
    """Removes the minimum (read hk[0], hn[0] first); hsize is the size before removal."""
    hsize -= 1
    if hsize == 0:
        return
    lk = hk[hsize]
    ln = hn[hsize]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= hsize:
            break
        if c + 1 < hsize and hk[c + 1] < hk[c]:
            c += 1
        if hk[c] >= lk:
            break
        hk[i] = hk[c]
        hn[i] = hn[c]
        i = c
    hk[i] = lk
    hn[i] = ln


@njit(cache=True)
def parked_reach(start: int, goal: int, agent: int, nbr, park_time, park_owner, stamp, queue) -> bool:
    """A relaxation of the space-time search: can the robot reach its goal at all, ignoring
    moving robots but not the parked ones (a cell can be entered only before its robot parks
    there)? False proves that no space-time path exists."""
    stamp[0] += 1
    mark = stamp[0]
    vis = stamp[1:]
    vis[start] = mark
    queue[0] = start
    head = 0
    tail = 1
    t = 0
    level_end = 1
    while head < tail:
        if head == level_end:
            t += 1
            level_end = tail
        v = queue[head]
        head += 1
        if v == goal:
            return True
        for j in range(nbr.shape[1]):
            u = nbr[v, j]
            if u < 0:
                break
            if vis[u] == mark:
                continue
            if park_owner[u] >= 0 and park_owner[u] != agent and park_time[u] <= t + 1:
                continue
            vis[u] = mark
            queue[tail] = u
            tail += 1
    return False


@njit(cache=True)
def st_astar(nbr, drow, unreach: int, start: int, goal: int, agent: int, keys, vals,
             park_time, park_owner, last_use, xs, ys, index, width: int,
             max_expand: int, t_max: int, f_max: int, stamp, queue) -> np.ndarray:
    """Space-time A* from (start, 0) to goal; returns the cell ids per step, or an empty array
    (no path arriving by step f_max, or more than max_expand expansions).

    Every step costs 1 and (cell, step) determines the cost so far, so a state is
    generated at most once. Ties on f go to the deeper state (closer to the goal).
    The robot cannot finish before the last step another robot uses its goal,
    so f = max(t + h, that step + 1): without it the search would fill the whole
    space-time volume below that step before diving.
    Partial expansion (PEA*): a popped state generates only the successors whose
    f equals its own and goes back into the heap with the next larger f, so the
    side steps and waits of an unobstructed robot are never checked or stored.
    A search that drags on first checks `parked_reach`, so that a robot walled in by
    parked robots fails fast. stamp (n+1) and queue (n) are scratch arrays for that check.
    """
    n = nbr.shape[0]
    s = last_use[goal]
    while s >= 0 and hm_get(keys, vals, st_key(goal, s)) < 0:
        s -= 1
    last_use[goal] = s  # tightened: unreserve leaves it an upper bound
    free_from = s + 1
    k = nbr.shape[1]
    cap = 1024
    nv = np.empty(cap, dtype=np.int32)
    nt = np.empty(cap, dtype=np.int32)
    npar = np.empty(cap, dtype=np.int32)
    hk = np.empty(cap, dtype=np.int64)
    hn = np.empty(cap, dtype=np.int32)
    sk, sv, sm = hm_new(cap)
    big = np.int64(1) << np.int64(31)
    nv[0] = start
    nt[0] = 0
    npar[0] = -1
    nodes = 1
    hk[0] = np.int64(max(drow[start], free_from)) * big + (big - 1)
    hn[0] = 0
    hsize = 1
    hm_put(sk, sv, sm, st_key(start, 0), 0)
    expanded = 0
    # late enough that the check (a sweep of the map) costs less than the search so far
    check_at = 2 * drow[start] + 500 + n // 8
    no_more = np.int64(1) << np.int64(62)
    while hsize > 0:
        node = hn[0]
        f = hk[0] // big
        if f > f_max:
            break
        _heap_pop(hk, hn, hsize)
        hsize -= 1
        v = nv[node]
        t = nt[node]
        if v == goal and t >= free_from:
            path = np.empty(t + 1, dtype=np.int32)
            m = node
            while m >= 0:
                path[nt[m]] = nv[m]
                m = npar[m]
            return path
        expanded += 1
        if expanded > max_expand:
            break
        if expanded == check_at and not parked_reach(start, goal, agent, nbr, park_time, park_owner, stamp, queue):
            break
        if t >= t_max:
            continue
        f_next = no_more
        for j in range(k + 1):
            u = v if j == k else nbr[v, j]
            if u < 0:
                continue
            hu = drow[u]
            if hu >= unreach:
                continue
            fu = max(t + 1 + hu, free_from)
            if fu != f:
                if fu > f and fu < f_next:
                    f_next = fu
                continue
            if _blocked(keys, vals, n, v, u, t, agent, park_time, park_owner, xs, ys, index, width):
                continue
            key = st_key(u, t + 1)
            if hm_get(sk, sv, key) >= 0:
                continue
            if nodes == nv.shape[0]:
                nv = grow(nv, nodes + 1)
                nt = grow(nt, nodes + 1)
                npar = grow(npar, nodes + 1)
            nv[nodes] = u
            nt[nodes] = t + 1
            npar[nodes] = node
            hm_put(sk, sv, sm, key, nodes)
            if hm_full(sk, sm):
                sk, sv, sm = hm_grow(sk, sv, sm)
            if hsize == hk.shape[0]:
                hk, hn = _heap_grow(hk, hn)
            _heap_push(hk, hn, hsize, np.int64(fu) * big + (big - 1 - (t + 1)), nodes)
            hsize += 1
            nodes += 1
        if f_next != no_more:
            # come back for the costlier successors only if the cheaper ones lead nowhere
            if hsize == hk.shape[0]:
                hk, hn = _heap_grow(hk, hn)
            _heap_push(hk, hn, hsize, f_next * big + (big - 1 - t), node)
            hsize += 1
    return np.empty(0, dtype=np.int32)


@njit(cache=True)
def _walls(a: int, src: int, nbr, park_owner, planned, out, m: int, stamp, queue) -> int:
    """Adds to out[m:] the robots parked on the rim of the region around src that is not
    parked on (breadth-first, nearest first, a few hundred cells at most)."""
    stamp[0] += 1
    mark = stamp[0]
    vis = stamp[1:]
    vis[src] = mark
    queue[0] = src
    head = 0
    tail = 1
    while head < tail and tail < WALL_CELLS and m < out.shape[0]:
        v = queue[head]
        head += 1
        for j in range(nbr.shape[1]):
            u = nbr[v, j]
            if u < 0:
                break
            if vis[u] == mark:
                continue
            vis[u] = mark
            b = park_owner[u]
            if b >= 0 and b != a:
                if planned[b] and m < out.shape[0]:
                    new = True
                    for k in range(m):
                        if out[k] == b:
                            new = False
                    if new:
                        out[m] = b
                        m += 1
                continue
            queue[tail] = u
            tail += 1
    return m


@njit(cache=True)
def blockers(a: int, nbr, drow, start: int, goal: int, keys, vals, park_time, park_owner, planned,
             out: np.ndarray, rng, stamp, queue) -> int:
    """Robots in the way of robot a: those parked around its goal or start, then along one of
    its shortest paths (random ties) those that hold a cell at the matching step or the next
    one, or park on it. Returns how many (<= out.size)."""
    m = 0
    # robots parked around a's goal or start may wall them in: they come first
    for src in (goal, start):
        m = _walls(a, src, nbr, park_owner, planned, out, m, stamp, queue)
    v = start
    t = 0
    while m < out.shape[0]:
        for dt in range(2):
            b = hm_get(keys, vals, st_key(v, t + dt))
            if b >= 0 and b != a and planned[b]:
                new = True
                for j in range(m):
                    if out[j] == b:
                        new = False
                if new and m < out.shape[0]:
                    out[m] = b
                    m += 1
        b = park_owner[v]
        if b >= 0 and b != a and planned[b]:
            new = True
            for j in range(m):
                if out[j] == b:
                    new = False
            if new and m < out.shape[0]:
                out[m] = b
                m += 1
        if v == goal:
            break
        nxt = -1
        cnt = 0
        for j in range(nbr.shape[1]):
            u = nbr[v, j]
            if u < 0:
                break
            if drow[u] < drow[v]:
                cnt += 1
                rng[0] = rng[0] * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
                if np.int64(rng[0] >> np.uint64(33)) % cnt == 0:
                    nxt = u
        v = nxt
        t += 1
    return m


@njit(cache=True)
def _plan_in_order(nbr, dist, rows, unreach: int, starts, goals, order, xs, ys, index, width: int,
                   max_expand: int, deadline: float, skip_failures: bool):
    """Plans robots in `order`: (first failed robot, or -1, or -2 on timeout; flat paths, offsets, lengths).

    A robot that finds no path gets one repair: the planned robots in its way are taken out,
    it is planned, and they are planned again after it; if that fails too, everything is put
    back. With skip_failures a robot still without a path gets length 0 and the others are
    planned; without, planning stops there.
    """
    n = nbr.shape[0]
    na = starts.shape[0]
    keys, vals, meta = hm_new(1024)
    park_time = np.full(n, NEVER, dtype=np.int32)
    park_owner = np.full(n, -1, dtype=np.int32)
    last_use = np.full(n, -1, dtype=np.int32)
    poff = np.zeros(na, dtype=np.int64)
    plen = np.zeros(na, dtype=np.int64)
    planned = np.zeros(na, dtype=np.bool_)
    rank = np.full(na, na, dtype=np.int32)
    for r in range(order.shape[0]):
        rank[order[r]] = r
    buf = np.empty(1024, dtype=np.int32)
    group = np.empty(REPAIR_GROUP, dtype=np.int32)
    old_off = np.empty(REPAIR_GROUP, dtype=np.int64)
    old_len = np.empty(REPAIR_GROUP, dtype=np.int64)
    rng = np.array([np.uint64(12345)], dtype=np.uint64)
    stamp = np.zeros(n + 1, dtype=np.int32)     # [0] the current mark, [1:] a mark per cell
    queue = np.empty(n, dtype=np.int32)
    used = 0
    horizon = 0
    first_failed = -1
    for r in range(order.shape[0]):
        if now() > deadline:
            return -2, buf, poff, plen
        a = order[r]
        # after the last reserved step the world is static; nothing beyond a full sweep helps
        t_max = horizon + n + 1
        path = st_astar(nbr, dist[rows[a]], unreach, starts[a], goals[a], a, keys, vals, park_time, park_owner,
                        last_use, xs, ys, index, width, max_expand, t_max, t_max, stamp, queue)
        m = 0
        if path.shape[0] == 0:
            m = blockers(a, nbr, dist[rows[a]], starts[a], goals[a], keys, vals, park_time, park_owner, planned,
                         group, rng, stamp, queue)
            # replan the blockers in their own priority order
            for j in range(1, m):
                x = group[j]
                i = j
                while i > 0 and rank[group[i - 1]] > rank[x]:
                    group[i] = group[i - 1]
                    i -= 1
                group[i] = x
            for j in range(m):
                b = group[j]
                old_off[j] = poff[b]
                old_len[j] = plen[b]
                unreserve(keys, meta, n, buf[poff[b]:poff[b] + plen[b]], park_time, park_owner)
                planned[b] = False
            if m > 0:
                path = st_astar(nbr, dist[rows[a]], unreach, starts[a], goals[a], a, keys, vals, park_time,
                                park_owner, last_use, xs, ys, index, width, max_expand, t_max, t_max, stamp, queue)
        if path.shape[0] > 0:
            keys, vals, meta = reserve(keys, vals, meta, n, path, a, park_time, park_owner, last_use)
            horizon = max(horizon, path.shape[0])
            buf = grow(buf, used + path.shape[0])
            copy_into(buf, used, path, path.shape[0])
            poff[a] = used
            plen[a] = path.shape[0]
            used += path.shape[0]
            planned[a] = True
            done = 0
            for j in range(m):
                b = group[j]
                t_max = horizon + n + 1
                p = st_astar(nbr, dist[rows[b]], unreach, starts[b], goals[b], b, keys, vals, park_time,
                             park_owner, last_use, xs, ys, index, width, max_expand, t_max, t_max, stamp, queue)
                if p.shape[0] == 0:
                    break
                keys, vals, meta = reserve(keys, vals, meta, n, p, b, park_time, park_owner, last_use)
                horizon = max(horizon, p.shape[0])
                buf = grow(buf, used + p.shape[0])
                copy_into(buf, used, p, p.shape[0])
                poff[b] = used
                plen[b] = p.shape[0]
                used += p.shape[0]
                planned[b] = True
                done += 1
            if done == m:
                continue
            # the repair failed: take back what it planned, restore the blockers' old paths
            for j in range(done):
                b = group[j]
                unreserve(keys, meta, n, buf[poff[b]:poff[b] + plen[b]], park_time, park_owner)
            unreserve(keys, meta, n, buf[poff[a]:poff[a] + plen[a]], park_time, park_owner)
            planned[a] = False
            plen[a] = 0
        for j in range(m):
            b = group[j]
            poff[b] = old_off[j]
            plen[b] = old_len[j]
            keys, vals, meta = reserve(keys, vals, meta, n, buf[poff[b]:poff[b] + plen[b]], b, park_time,
                                       park_owner, last_use)
            planned[b] = True
        if not skip_failures:
            return a, buf, poff, plen
        if first_failed < 0:
            first_failed = a
    return first_failed, buf, poff, plen


def kernel_args(inst: Instance) -> tuple:
    """The grid arrays every search kernel takes: neighbours, coordinates, index, width."""
    g = inst.graph
    xs, ys = g.xy()
    return g.nbr, xs.astype(np.int32), ys.astype(np.int32), g.index, g.width


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
            raise PlanningError(f"prioritized planning: time limit of {limits.seconds:g} s reached after "
                                f"{tries} priority orders")
        raise PlanningError(f"prioritized planning: no conflict-free priority order in {tries} tries "
                            f"(robot {failed} from {tuple(problem.starts[failed])} stays blocked)")
    return split_paths(inst, buf, poff, plen)


def plan_prioritized(inst: Instance, limits: Limits, max_tries: int | None = None):
    """Restarts until an order works: (ok, flat paths, offsets, lengths, tries, last failed robot).

    Gives up after `max_tries` orders (default: MAX_TRIES, or every order of a handful of robots).
    """
    if max_tries is None:
        max_tries = min(MAX_TRIES, math.factorial(min(inst.n, 8)))
    nbr, xs, ys, index, width = kernel_args(inst)
    dist = inst.table.dist
    rng = np.random.default_rng(inst.problem.seed)
    d0 = inst.start_distances()
    # shorter paths first (see the module doc); the random key breaks ties reproducibly
    order = np.lexsort((rng.random(inst.n), d0)).astype(np.int32)
    failed = -1
    tries = 0
    cap = max_expansions(inst)
    while tries < max_tries:
        limits.check("prioritized planning")
        tries += 1
        deadline = time.perf_counter() + limits.remaining()
        failed, buf, poff, plen = _plan_in_order(nbr, dist, inst.rows, inst.table.unreachable, inst.starts,
                                                 inst.goals, order, xs, ys, index, width, cap, deadline, False)
        if failed == -1:
            return True, buf, poff, plen, tries, -1
        if failed == -2:
            break
        pos = int(np.flatnonzero(order == failed)[0])
        if tries % 4 == 0:
            # promoting the blocked robot keeps failing: shuffle the rest of the order
            rest = np.delete(order, pos)
            rng.shuffle(rest)
            order = np.concatenate(([failed], rest)).astype(np.int32)
        else:
            order = np.concatenate(([failed], np.delete(order, pos))).astype(np.int32)
    return False, None, None, None, tries, failed


def guide_paths(inst: Instance, limits: Limits, max_expand: int):
    """One prioritized pass that skips robots it cannot route: (flat paths, offsets, lengths, complete?).

    Unrouted robots get length 0. None when the time runs out. The paths are
    conflict-free among themselves; LaCAM uses them to guide PIBT.
    """
    nbr, xs, ys, index, width = kernel_args(inst)
    rng = np.random.default_rng(inst.problem.seed)
    order = np.lexsort((rng.random(inst.n), inst.start_distances())).astype(np.int32)
    failed, buf, poff, plen = _plan_in_order(nbr, inst.table.dist, inst.rows, inst.table.unreachable, inst.starts,
                                             inst.goals, order, xs, ys, index, width, max_expand,
                                             time.perf_counter() + limits.remaining(), True)
    if failed == -2:
        return None
    return buf, poff, plen, failed == -1
