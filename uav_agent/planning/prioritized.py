"""Prioritized planning: robots one after another, each routed around the paths before it.

Robots with shorter shortest paths go first. (The usual longer-first order
was measured worse: a short-trip robot then has to wait until every long
trip has crossed its goal; on the 450x450 warehouse with 500 robots that
gives a sum of costs 12 % above the lower bound against 0.02 %.) A robot's
path is found by safe interval path planning (SIPP, a space-time A* whose
states are a cell and a stretch of free steps) with the exact distance field
as heuristic, avoiding the reservations of earlier paths (vertex, swap and,
in 8-connectivity, crossing-diagonal conflicts) and the goals where earlier
robots have parked for good; it may only end on its own goal once no earlier
path crosses that goal later.

A robot that finds no path gets a local repair: the robots walling in its
start or goal and those in its way are taken out, it is planned, and they are
planned again after it. If that fails, the robot moves to the front of the
order and the planning restarts (with random reorders after a few tries), up
to MAX_TRIES orders or the time limit.

The reservations and the search are numba kernels shared with LaCAM's
refinement (`lacam.py`), which replans groups of robots with them.
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
UNBOUNDED = 2**40                # an f bound that never cuts a search
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
def hm_slot(keys: np.ndarray, key: int) -> int:
    """The slot holding key, or the empty slot ending its probe (check keys[slot] == key)."""
    mask = keys.shape[0] - 1
    s = _slot(key, mask)
    while True:
        k = keys[s]
        if k == key or k == EMPTY:
            return s
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


# ---- reservations: for every cell, the steps at which robots hold it, sorted ----
# A cell's entries (step << 32 | robot) sit in one segment of the arena `ta`; seg[v] is
# (offset, length, capacity). A full segment moves to the arena's end with twice the room.
# Sorted per-cell lists answer "who holds v at t" with a short binary search in one cache
# line, and give the safe intervals (the free stretches between holds) that SIPP needs.

FOREVER = np.int64(1) << np.int64(40)     # the end of the last safe interval of a cell


@njit(cache=True)
def rs_new(n: int, capacity: int):
    """Empty reservations for n cells: (seg, ta, meta); meta = [arena used, live entries]."""
    return np.zeros((n, 3), dtype=np.int64), np.empty(max(capacity, 1024), dtype=np.int64), \
        np.zeros(2, dtype=np.int64)


@njit(cache=True, inline='always')
def rs_lower(seg, ta, v: int, t: int) -> int:
    """Index in v's list of the first entry at step >= t (the list length if none)."""
    off = seg[v, 0]
    lo = 0
    hi = seg[v, 1]
    key = np.int64(t) << np.int64(32)
    while lo < hi:
        mid = (lo + hi) >> 1
        if ta[off + mid] < key:
            lo = mid + 1
        else:
            hi = mid
    return lo


@njit(cache=True, inline='always')
def rs_step(seg, ta, v: int, i: int) -> int:
    """The step of entry i of v's list."""
    return ta[seg[v, 0] + i] >> np.int64(32)


@njit(cache=True, inline='always')
def rs_find(seg, ta, v: int, t: int) -> int:
    """The robot holding v at step t, or -1."""
    i = rs_lower(seg, ta, v, t)
    if i < seg[v, 1]:
        x = ta[seg[v, 0] + i]
        if (x >> np.int64(32)) == t:
            return np.int64(x & np.int64(0xFFFFFFFF))
    return -1


@njit(cache=True)
def rs_insert(seg, ta, meta, v: int, t: int, agent: int):
    """Adds (v, t) -> agent (not already held); returns the arena, which may have moved."""
    off = seg[v, 0]
    ln = seg[v, 1]
    if ln == seg[v, 2]:
        cap = max(np.int64(4), 2 * seg[v, 2])
        ta = grow(ta, meta[0] + cap)
        for i in range(ln):
            ta[meta[0] + i] = ta[off + i]
        off = meta[0]
        seg[v, 0] = off
        seg[v, 2] = cap
        meta[0] += cap
    i = rs_lower(seg, ta, v, t)
    for j in range(ln, i, -1):
        ta[off + j] = ta[off + j - 1]
    ta[off + i] = (np.int64(t) << np.int64(32)) | np.int64(agent)
    seg[v, 1] = ln + 1
    meta[1] += 1
    return ta


@njit(cache=True)
def rs_remove(seg, ta, meta, v: int, t: int) -> None:
    i = rs_lower(seg, ta, v, t)
    ln = seg[v, 1]
    if i < ln and rs_step(seg, ta, v, i) == t:
        off = seg[v, 0]
        for j in range(i, ln - 1):
            ta[off + j] = ta[off + j + 1]
        seg[v, 1] = ln - 1
        meta[1] -= 1


@njit(cache=True)
def reserve(seg, ta, meta, path: np.ndarray, agent: int, park_time: np.ndarray, park_owner: np.ndarray):
    """Books a path (its last cell is the robot's goal, held from then on); returns the arena."""
    for t in range(path.shape[0]):
        ta = rs_insert(seg, ta, meta, path[t], t, agent)
    g = path[path.shape[0] - 1]
    park_time[g] = path.shape[0] - 1
    park_owner[g] = agent
    return ta


@njit(cache=True)
def unreserve(seg, ta, meta, path: np.ndarray, park_time: np.ndarray, park_owner: np.ndarray) -> None:
    for t in range(path.shape[0]):
        rs_remove(seg, ta, meta, path[t], t)
    g = path[path.shape[0] - 1]
    park_time[g] = NEVER
    park_owner[g] = -1


@njit(cache=True, inline='always')
def _edge_blocked(seg, ta, v: int, u: int, t: int, xs, ys, index, width: int) -> bool:
    """Whether the move v -> u between steps t and t+1 swaps with, or (diagonally) crosses,
    a reserved move."""
    b = rs_find(seg, ta, v, t + 1)
    if b >= 0 and rs_find(seg, ta, u, t) == b:
        return True
    if xs[u] != xs[v] and ys[u] != ys[v]:
        p = index[ys[v] * width + xs[u]]
        q = index[ys[u] * width + xs[v]]
        b = rs_find(seg, ta, p, t)
        if b >= 0 and rs_find(seg, ta, q, t + 1) == b:
            return True
        b = rs_find(seg, ta, q, t)
        if b >= 0 and rs_find(seg, ta, p, t + 1) == b:
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


@njit(cache=True, inline='always')
def _interval(seg, ta, u: int, iu: int, lu: int) -> tuple:
    """The first and last step of u's safe interval iu (the one after iu entries of its list)."""
    lo = 0 if iu == 0 else rs_step(seg, ta, u, iu - 1) + 1
    hi = FOREVER if iu == lu else rs_step(seg, ta, u, iu) - 1
    return lo, hi


@njit(cache=True)
def _reach(seg, ta, v: int, t: int, last: int, u: int, iu: int, parked: bool, xs, ys, index, width: int):
    """From v (reached at step t, free until step `last`), the first of u's safe intervals from
    index iu on that the robot can move into: (interval index, arrival step), or (-1, -1)."""
    lu = seg[u, 1]
    while iu <= lu:
        if iu == lu and parked:
            break           # no endless interval where another robot parks
        lo, hi = _interval(seg, ta, u, iu, lu)
        arrive = max(t + 1, lo)
        if arrive > last + 1:
            break
        limit = min(hi, last + 1)
        while arrive <= limit and _edge_blocked(seg, ta, v, u, arrive - 1, xs, ys, index, width):
            arrive += 1
        if arrive <= limit:
            return iu, arrive
        iu += 1
    return -1, -1


@njit(cache=True)
def sipp(nbr, drow, unreach: int, start: int, goal: int, agent: int, seg, ta, park_time, park_owner,
         xs, ys, index, width: int, max_expand: int, f_max: int, stamp, queue) -> np.ndarray:
    """Safe interval path planning (Phillips & Likhachev, ICRA 2011) from (start, step 0) to goal.

    Returns the cell ids per step, or an empty array (no path arriving by step f_max, or more
    than max_expand expansions). A state is a cell and one of its safe intervals (a maximal
    stretch of steps nobody holds it; the last one is cut at the step another robot parks
    there), reached at the earliest step; waiting is implicit, so a robot that must let others
    pass costs one state, not one per step. Swaps and crossing diagonals are checked on each
    move; a blocked move leaves one step later. The robot can only finish in its goal's last,
    endless interval; f = max(arrival + distance, that interval's start). Ties go to the
    later arrival (closer to the goal).
    Successors are generated lazily: an expansion creates only the states that keep its f (the
    moves straight on); for the other neighbours, and for every interval after the first one
    a neighbour can enter, it leaves a deferred record (a heap entry < 0) that is worked out
    when its lower bound comes up. Busy cells have dozens of intervals and most side steps are
    never needed.
    A search that drags on first checks `parked_reach`, so that a robot walled in by parked
    robots fails fast; stamp (n+1) and queue (n) are scratch arrays for that check.
    """
    n = nbr.shape[0]
    gl = seg[goal, 1]
    free_from = 0 if gl == 0 else rs_step(seg, ta, goal, gl - 1) + 1
    cap = 256
    nv = np.empty(cap, dtype=np.int32)        # cell
    ni = np.empty(cap, dtype=np.int32)        # safe interval index
    na_ = np.empty(cap, dtype=np.int64)       # arrival step
    nl = np.empty(cap, dtype=np.int64)        # last step of the interval
    npar = np.empty(cap, dtype=np.int32)
    dn = np.empty(cap, dtype=np.int32)        # deferred records: node, neighbour slot, next interval
    dj = np.empty(cap, dtype=np.int32)
    di = np.empty(cap, dtype=np.int32)
    hk = np.empty(cap, dtype=np.int64)
    hn = np.empty(cap, dtype=np.int32)
    sk, sv, sm = hm_new(cap)
    big = np.int64(1) << np.int64(31)
    i0 = rs_lower(seg, ta, start, 0)
    nv[0] = start
    ni[0] = i0
    na_[0] = 0
    nl[0] = _interval(seg, ta, start, i0, seg[start, 1])[1]
    npar[0] = -1
    nodes = 1
    deferred = 0
    hk[0] = np.int64(max(drow[start], free_from)) * big + (big - 1)
    hn[0] = 0
    hsize = 1
    hm_put(sk, sv, sm, st_key(start, i0), 0)
    expanded = 0
    check_at = 2 * drow[start] + 500 + n // 8
    while hsize > 0:
        item = hn[0]
        f = hk[0] // big
        if f > f_max:
            break
        _heap_pop(hk, hn, hsize)
        hsize -= 1
        if item >= 0:
            node = item
            v = nv[node]
            if sv[hm_slot(sk, st_key(v, ni[node]))] != node:
                continue        # superseded by an earlier arrival in the same interval
            t = na_[node]
            if v == goal and ni[node] == seg[v, 1]:
                path = np.empty(t + 1, dtype=np.int32)
                m = node
                end = t
                while m >= 0:
                    for s in range(na_[m], end + 1):
                        path[s] = nv[m]
                    end = na_[m] - 1
                    m = npar[m]
                return path
            expanded += 1
            if expanded > max_expand:
                break
            if expanded == check_at and not parked_reach(start, goal, agent, nbr, park_time, park_owner, stamp,
                                                         queue):
                break
            j_lo = 0
            j_hi = nbr.shape[1]
        else:
            rec = -item - 1
            node = dn[rec]
            v = nv[node]
            t = na_[node]
            j_lo = dj[rec]
            j_hi = j_lo + 1
        last = nl[node]
        for j in range(j_lo, j_hi):
            u = nbr[v, j]
            if u < 0:
                break
            hu = drow[u]
            if hu >= unreach:
                continue
            parked = park_owner[u] >= 0 and park_owner[u] != agent
            if item >= 0 and max(t + 1 + hu, free_from) > f:
                # a detour or a wait: only a deferred record for now (most are never needed)
                if deferred == dn.shape[0]:
                    dn = grow(dn, deferred + 1)
                    dj = grow(dj, deferred + 1)
                    di = grow(di, deferred + 1)
                dn[deferred] = node
                dj[deferred] = j
                di[deferred] = -1
                if hsize == hk.shape[0]:
                    hk, hn = _heap_grow(hk, hn)
                _heap_push(hk, hn, hsize, np.int64(max(t + 1 + hu, free_from)) * big + (big - 1 - (t + 1)),
                           -deferred - 1)
                hsize += 1
                deferred += 1
                continue
            first = rs_lower(seg, ta, u, t + 1) if item >= 0 or di[-item - 1] < 0 else di[-item - 1]
            iu, arrive = _reach(seg, ta, v, t, last, u, first, parked, xs, ys, index, width)
            if iu < 0:
                continue
            key = st_key(u, iu)
            s_ = hm_slot(sk, key)
            known = sv[s_] if sk[s_] == key else -1
            if known < 0 or na_[known] > arrive:
                if nodes == nv.shape[0]:
                    nv = grow(nv, nodes + 1)
                    ni = grow(ni, nodes + 1)
                    na_ = grow(na_, nodes + 1)
                    nl = grow(nl, nodes + 1)
                    npar = grow(npar, nodes + 1)
                lu = seg[u, 1]
                nv[nodes] = u
                ni[nodes] = iu
                na_[nodes] = arrive
                nl[nodes] = _interval(seg, ta, u, iu, lu)[1]
                npar[nodes] = node
                hm_put(sk, sv, sm, key, nodes)
                if hm_full(sk, sm):
                    sk, sv, sm = hm_grow(sk, sv, sm)
                if hsize == hk.shape[0]:
                    hk, hn = _heap_grow(hk, hn)
                _heap_push(hk, hn, hsize, np.int64(max(arrive + hu, free_from)) * big + (big - 1 - arrive), nodes)
                hsize += 1
                nodes += 1
            # the later intervals of u, for when this one leads nowhere
            lu = seg[u, 1]
            if iu + 1 <= lu and not (iu + 1 == lu and parked):
                lo = rs_step(seg, ta, u, iu) + 1
                if lo <= last + 1:
                    if deferred == dn.shape[0]:
                        dn = grow(dn, deferred + 1)
                        dj = grow(dj, deferred + 1)
                        di = grow(di, deferred + 1)
                    dn[deferred] = node
                    dj[deferred] = j
                    di[deferred] = iu + 1
                    if hsize == hk.shape[0]:
                        hk, hn = _heap_grow(hk, hn)
                    at = max(t + 1, lo)
                    _heap_push(hk, hn, hsize, np.int64(max(at + hu, free_from)) * big + (big - 1 - at),
                               -deferred - 1)
                    hsize += 1
                    deferred += 1
    return np.empty(0, dtype=np.int32)


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
    while head < tail < WALL_CELLS and m < out.shape[0]:
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
                if planned[b]:
                    m = _add_new(out, m, b)
                continue
            queue[tail] = u
            tail += 1
    return m


@njit(cache=True)
def blockers(a: int, nbr, drow, start: int, goal: int, seg, ta, park_time, park_owner, planned,
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
            b = rs_find(seg, ta, v, t + dt)
            if b >= 0 and b != a and planned[b]:
                m = _add_new(out, m, b)
        b = park_owner[v]
        if b >= 0 and b != a and planned[b]:
            m = _add_new(out, m, b)
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
    seg, ta, meta = rs_new(n, 4 * n)
    park_time = np.full(n, NEVER, dtype=np.int32)
    park_owner = np.full(n, -1, dtype=np.int32)
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
    first_failed = -1
    for r in range(order.shape[0]):
        if now() > deadline:
            return -2, buf, poff, plen
        a = order[r]
        path = sipp(nbr, dist[rows[a]], unreach, starts[a], goals[a], a, seg, ta, park_time, park_owner,
                    xs, ys, index, width, max_expand, UNBOUNDED, stamp, queue)
        m = 0
        if path.shape[0] == 0:
            m = blockers(a, nbr, dist[rows[a]], starts[a], goals[a], seg, ta, park_time, park_owner, planned,
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
                unreserve(seg, ta, meta, buf[poff[b]:poff[b] + plen[b]], park_time, park_owner)
                planned[b] = False
            if m > 0:
                path = sipp(nbr, dist[rows[a]], unreach, starts[a], goals[a], a, seg, ta, park_time, park_owner,
                            xs, ys, index, width, max_expand, UNBOUNDED, stamp, queue)
        if path.shape[0] > 0:
            ta = reserve(seg, ta, meta, path, a, park_time, park_owner)
            buf = grow(buf, used + path.shape[0])
            copy_into(buf, used, path, path.shape[0])
            poff[a] = used
            plen[a] = path.shape[0]
            used += path.shape[0]
            planned[a] = True
            done = 0
            for j in range(m):
                b = group[j]
                p = sipp(nbr, dist[rows[b]], unreach, starts[b], goals[b], b, seg, ta, park_time, park_owner,
                         xs, ys, index, width, max_expand, UNBOUNDED, stamp, queue)
                if p.shape[0] == 0:
                    break
                ta = reserve(seg, ta, meta, p, b, park_time, park_owner)
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
                unreserve(seg, ta, meta, buf[poff[b]:poff[b] + plen[b]], park_time, park_owner)
            unreserve(seg, ta, meta, buf[poff[a]:poff[a] + plen[a]], park_time, park_owner)
            planned[a] = False
            plen[a] = 0
        for j in range(m):
            b = group[j]
            poff[b] = old_off[j]
            plen[b] = old_len[j]
            ta = reserve(seg, ta, meta, buf[poff[b]:poff[b] + plen[b]], b, park_time, park_owner)
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
