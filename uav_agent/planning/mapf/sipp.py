"""Safe interval path planning for one robot (Phillips & Likhachev, "SIPP: Safe Interval
Path Planning for Dynamic Environments", ICRA 2011).

A state is a cell and one of its safe intervals (a maximal stretch of steps
nobody holds it, `reservations.py`; the last one is cut at the step another
robot parks there), reached at the earliest step; waiting is implicit, so a
robot that must let others pass costs one state, not one per step. The paper's
getSuccessors is `_reach`: for a move to a neighbour, the first of its safe
intervals that the robot can enter before its own interval ends, at the
earliest step without a swap or (8-connected) a crossing diagonal. The
heuristic is the exact distance field; the robot can only finish in its goal's
last, endless interval, so f = max(arrival + distance, that interval's start).

Successors are generated lazily (in the spirit of partial expansion, Yoshizumi
et al., AAAI 2000): an expansion creates only the states that keep its f (the
moves straight on); for the other neighbours, and for every interval after the
first one a neighbour can enter, it leaves a deferred record that is worked out
when its lower bound comes up. Busy cells have dozens of intervals and most side
steps are never needed.

A plain-Python reading copy, with every successor generated at once:
`planning/reference/sipp.py`.
"""
from __future__ import annotations

import numpy as np
from ..compile.jit import njit

from .grid_kernels import (
    Geometry,
    Grid,
    Visits,
    begin_visits,
    grow,
    heap_pop,
    heap_push,
)
from .reservations import (
    NEVER,
    Reservations,
    edge_blocked,
    interval,
    parked_by_other,
    rs_lower,
    rs_step,
)

EMPTY = -1
TOMB = -2
BIG = np.int64(1) << np.int64(31)   # a heap key is f * BIG + (BIG - 1 - arrival): ties go to later arrivals

# ---- open-addressing hash map int64 -> int32 (keys >= 0; EMPTY/TOMB markers) ----
# Keys are (cell << 32 | interval). The slot scatters cells but keeps the intervals of one
# cell next to each other, so the lookups of one search step mostly share cache lines.


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


@njit(cache=True)
def hm_grow(keys: np.ndarray, vals: np.ndarray, meta: np.ndarray):
    """A fresh table holding the live keys, with room to grow."""
    nk, nv, nm = hm_new(2 * meta[1] + 16)
    for s in range(keys.shape[0]):
        if keys[s] >= 0:
            hm_put(nk, nv, nm, keys[s], vals[s])
    return nk, nv, nm


# ---- the search ----
# The search's arrays are locals of `sipp`, and the helpers of its loop take arrays, not
# structures: the loop runs once per state and per move (see grid_kernels on why).

@njit(cache=True, inline='always')
def heap_key(f: int, arrive: int) -> int:
    """Open-list order: lowest f first, then the latest arrival (the closest to the goal)."""
    return np.int64(f) * BIG + (BIG - 1 - arrive)


@njit(cache=True, inline='always')
def _grow_states(cell, ival, arrive, last, parent, need: int):
    return grow(cell, need), grow(ival, need), grow(arrive, need), grow(last, need), grow(parent, need)


@njit(cache=True, inline='always')
def _grow_deferred(d_state, d_slot, d_ival, need: int):
    return grow(d_state, need), grow(d_slot, need), grow(d_ival, need)


# Compiled without numba's reference counting: it allocates nothing, and the helpers inlined into it
# took and dropped a reference to each array they were passed, a runtime call each, 122 call sites
# (perf on a built refine: NRT_incref/decref 29 % of the samples, 22 % after; refinement rounds of
# 400 robots on warehouse-10-20-10-2-1 in 1.5 s, random-1..5 twice in turn: 3,630 against 3,042).
@njit(cache=True, _nrt=False)
def reach(seg, ta, geo: Geometry, v: int, t: int, last: int, u: int, iu: int, parked: bool,
          shut: int = NEVER, opens: int = NEVER):
    """The paper's getSuccessors for the move v -> u: from v (reached at step t, free until
    step `last`), the first of u's safe intervals from index iu on that the robot can move
    into, at the earliest step without a swap or crossing and outside the stretch [shut, opens]
    in which u is closed to entry (a mover's forecast, `dynamic.py`; never, by default):
    (interval index, arrival step), or (-1, -1)."""
    lu = seg[u, 1]
    while iu <= lu:
        if iu == lu and parked:
            break           # no endless interval where another robot parks
        lo, hi = interval(seg, ta, u, iu)
        arrive = max(t + 1, lo)
        if arrive > last + 1:
            break
        limit = min(hi, last + 1)
        while arrive <= limit:
            if shut <= arrive <= opens:
                arrive = opens + 1          # wait (on v) until u opens again
            elif edge_blocked(seg, ta, geo, v, u, arrive - 1):
                arrive += 1
            else:
                break
        if arrive <= limit:
            return iu, arrive
        iu += 1
    return -1, -1


@njit(cache=True)
def path_of_state(cell, arrive, parent, state: int) -> np.ndarray:
    """The cells per step from step 0 up to `state`, waits written out (the first state's too: a
    search may start its robot on its cell at a later step)."""
    end = arrive[state]
    path = np.empty(end + 1, dtype=np.int32)
    m = state
    while m >= 0:
        first = arrive[m] if parent[m] >= 0 else 0
        for step in range(first, end + 1):
            path[step] = cell[m]
        end = arrive[m] - 1
        m = parent[m]
    return path


@njit(cache=True)
def parked_reach(g: Grid, res: Reservations, agent: int, vis: Visits) -> bool:
    """A relaxation of the space-time search: can the robot reach its goal at all, ignoring
    moving robots but not the parked ones (a cell can be entered only before its robot parks
    there)? False proves that no space-time path exists."""
    goal = g.goals[agent]
    mark = begin_visits(vis, g.starts[agent])
    head = 0
    tail = 1
    t = 0
    level_end = 1
    while head < tail:
        if head == level_end:
            t += 1
            level_end = tail
        v = vis.queue[head]
        head += 1
        if v == goal:
            return True
        for j in range(g.nbr.shape[1]):
            u = g.nbr[v, j]
            if u < 0:
                break
            if vis.stamp[1 + u] == mark:
                continue
            if parked_by_other(res.park_owner, u, agent) and res.park_time[u] <= t + 1:
                continue
            vis.stamp[1 + u] = mark
            vis.queue[tail] = u
            tail += 1
    return False


@njit(cache=True)
def sipp(g: Grid, res: Reservations, agent: int, max_expand: int, f_max: int, vis: Visits) -> np.ndarray:
    """The robot's path from (start, step 0) to its goal around the reservations: cell ids per
    step, or an empty array (no path arriving by step f_max, or more than max_expand expansions).

    Open-list items >= 0 are states; an item < 0 is deferred record -1 - item: a move (state,
    neighbour slot) whose successors are generated when its lower bound comes up, from the
    earliest interval on or from a given one. A search that drags on first checks
    `parked_reach`, so that a robot walled in by parked robots fails fast; `vis` is scratch
    for that check.
    """
    nbr, geo, seg, ta, park_owner = g.nbr, g.geo, res.seg, res.ta, res.park_owner
    drow = g.dist[g.rows[agent]]
    unreach = g.unreach
    start = g.starts[agent]
    goal = g.goals[agent]
    k = nbr.shape[1]
    gl = seg[goal, 1]
    free_from = 0 if gl == 0 else rs_step(seg, ta, goal, gl - 1) + 1
    cap = 256
    cell = np.empty(cap, dtype=np.int32)      # states: a cell,
    ival = np.empty(cap, dtype=np.int32)      # the index of one of its safe intervals,
    arrive = np.empty(cap, dtype=np.int64)    # the earliest arrival found,
    last = np.empty(cap, dtype=np.int64)      # the interval's last step
    parent = np.empty(cap, dtype=np.int32)
    d_state = np.empty(cap, dtype=np.int32)   # deferred records: state, neighbour slot,
    d_slot = np.empty(cap, dtype=np.int32)
    d_ival = np.empty(cap, dtype=np.int32)    # first interval to try, -1 for the earliest
    hk = np.empty(cap, dtype=np.int64)        # the open list (a binary heap)
    hn = np.empty(cap, dtype=np.int32)
    sk, sv, sm = hm_new(cap)                  # (cell, interval) -> its state
    i0 = rs_lower(seg, ta, start, 0)
    cell[0] = start
    ival[0] = i0
    arrive[0] = 0
    last[0] = interval(seg, ta, start, i0)[1]
    parent[0] = -1
    states = 1
    deferred = 0
    hk[0] = heap_key(max(drow[start], free_from), 0)
    hn[0] = 0
    hsize = 1
    hm_put(sk, sv, sm, st_key(start, i0), 0)
    expanded = 0
    check_at = 2 * drow[start] + 500 + nbr.shape[0] // 8
    while hsize > 0:
        item = hn[0]
        f = hk[0] // BIG
        if f > f_max:
            break
        heap_pop(hk, hn, hsize)
        hsize -= 1
        if item >= 0:
            node = item
            v = cell[node]
            if sv[hm_slot(sk, st_key(v, ival[node]))] != node:
                continue        # superseded by an earlier arrival in the same interval
            if v == goal and ival[node] == seg[v, 1]:
                return path_of_state(cell, arrive, parent, node)
            expanded += 1
            if expanded > max_expand:
                break
            if expanded == check_at and not parked_reach(g, res, agent, vis):
                break
            j_lo = 0
            j_hi = k
        else:
            node = d_state[-item - 1]
            j_lo = d_slot[-item - 1]
            j_hi = j_lo + 1
        # room for what this expansion adds: per move at most a state and a deferred record
        if states + k > cell.shape[0]:
            cell, ival, arrive, last, parent = _grow_states(cell, ival, arrive, last, parent, states + k)
        if deferred + k > d_state.shape[0]:
            d_state, d_slot, d_ival = _grow_deferred(d_state, d_slot, d_ival, deferred + k)
        if hsize + 2 * k > hk.shape[0]:
            hk = grow(hk, hsize + 2 * k)
            hn = grow(hn, hsize + 2 * k)
        if 2 * (sm[0] + k) > sk.shape[0]:
            sk, sv, sm = hm_grow(sk, sv, sm)
        v = cell[node]
        t = arrive[node]
        for j in range(j_lo, j_hi):
            u = nbr[v, j]
            if u < 0:
                break
            hu = drow[u]
            if hu >= unreach:
                continue
            if item >= 0 and max(t + 1 + hu, free_from) > f:
                # a detour or a wait: only a deferred record for now (most are never needed)
                d_state[deferred] = node
                d_slot[deferred] = j
                d_ival[deferred] = -1
                heap_push(hk, hn, hsize, heap_key(max(t + 1 + hu, free_from), t + 1), -deferred - 1)
                hsize += 1
                deferred += 1
                continue
            first = rs_lower(seg, ta, u, t + 1) if item >= 0 or d_ival[-item - 1] < 0 else d_ival[-item - 1]
            parked = parked_by_other(park_owner, u, agent)
            iu, at = reach(seg, ta, geo, v, t, last[node], u, first, parked)
            if iu < 0:
                continue
            key = st_key(u, iu)
            slot = hm_slot(sk, key)
            known = sv[slot] if sk[slot] == key else -1
            if known < 0 or arrive[known] > at:
                cell[states] = u
                ival[states] = iu
                arrive[states] = at
                last[states] = interval(seg, ta, u, iu)[1]
                parent[states] = node
                hm_put(sk, sv, sm, key, states)
                heap_push(hk, hn, hsize, heap_key(max(at + hu, free_from), at), states)
                hsize += 1
                states += 1
            # the later intervals of u, for when this one leads nowhere
            lu = seg[u, 1]
            if iu + 1 <= lu and not (iu + 1 == lu and parked):
                lo = rs_step(seg, ta, u, iu) + 1
                if lo <= last[node] + 1:
                    d_state[deferred] = node
                    d_slot[deferred] = j
                    d_ival[deferred] = iu + 1
                    at = max(t + 1, lo)
                    heap_push(hk, hn, hsize, heap_key(max(at + hu, free_from), at), -deferred - 1)
                    hsize += 1
                    deferred += 1
    return np.empty(0, dtype=np.int32)
