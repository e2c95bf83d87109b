"""SIPP among the fleet's booked paths and cells the movers' forecast closes to entry: the
forecast as time-dependent obstacles (Phillips & Likhachev, "SIPP: Safe Interval Path
Planning for Dynamic Environments", ICRA 2011, made safe intervals for exactly this).

The forecast (`planning/forecast.py`) says from which step on a person or a forklift may be
on a cell, until the end of the window it is trusted for: cell u is closed from step
closed[u] to step until[u]. A robot must not *enter* a closed cell; it may *stay* on one,
since no mover steps into the cell a robot stands on. That is not a reservation, which would
forbid staying as well (and would make a robot that a mover walks up to flee its own, safe,
cell), so this is `sipp.py`'s search with one more rule in the paper's getSuccessors
(`_reach`): an arrival in [closed[u], until[u]] is put off to until[u] + 1. Arriving earlier
in a safe interval still dominates arriving later (the robot may wait on the cell it
entered), so SIPP's earliest-arrival argument holds.

A robot may also be made to stay on its cell up to a step (`hold`) before the search goes on:
the repair's hold (`planning/avoid.py`), whose rest of the way is planned here too.

Unlike `sipp.py` this search generates every successor of an expansion at once, as the
reading copy `planning/reference/sipp.py` does: a repair plans a handful of robots, and the
simpler loop is the easier one to trust with the rule above.
"""
from __future__ import annotations

import numpy as np
from ..compile.jit import njit

from .grid_kernels import Geometry, Grid, Visits, grow, heap_pop, heap_push
from .reservations import (
    NEVER,
    Reservations,
    interval,
    parked_by_other,
    reserve,
    rs_lower,
    rs_step,
)
from .sipp import heap_key, hm_grow, hm_new, hm_put, hm_slot, parked_reach, path_of_state, reach, st_key

OPEN = NEVER          # closed[u] of a cell the forecast never closes


@njit(cache=True)
def plan_around(g: Grid, res: Reservations, agent: int, closed: np.ndarray, until: np.ndarray, hold: int,
                max_expand: int, vis: Visits) -> np.ndarray:
    """Robot `agent`'s earliest path from its start to its goal: cell ids per step from step 0,
    or an empty array (none, or more than max_expand expansions).

    It avoids the booked paths of `res` (vertex, swap, crossing; goals parked on for good), never
    enters a cell u at a step in [closed[u], until[u]], and stays on its start up to step `hold`
    (0: no hold), which needs the start free of bookings until then.
    """
    nbr, geo, seg, ta, park_owner = g.nbr, g.geo, res.seg, res.ta, res.park_owner
    drow = g.dist[g.rows[agent]]
    unreach = g.unreach
    start = g.starts[agent]
    goal = g.goals[agent]
    k = nbr.shape[1]
    if drow[start] >= unreach:
        return np.empty(0, dtype=np.int32)
    gl = seg[goal, 1]
    free_from = 0 if gl == 0 else rs_step(seg, ta, goal, gl - 1) + 1
    i0 = rs_lower(seg, ta, start, 0)
    last0 = interval(seg, ta, start, i0)[1]
    if last0 < hold or (i0 == seg[start, 1] and parked_by_other(park_owner, start, agent)):
        return np.empty(0, dtype=np.int32)
    cap = 256
    cell = np.empty(cap, dtype=np.int32)      # states: a cell,
    ival = np.empty(cap, dtype=np.int32)      # the index of one of its safe intervals,
    arrive = np.empty(cap, dtype=np.int64)    # the earliest arrival found,
    last = np.empty(cap, dtype=np.int64)      # the interval's last step
    parent = np.empty(cap, dtype=np.int32)
    hk = np.empty(cap, dtype=np.int64)        # the open list (a binary heap)
    hn = np.empty(cap, dtype=np.int32)
    sk, sv, sm = hm_new(cap)                  # (cell, interval) -> its state
    cell[0] = start
    ival[0] = i0
    arrive[0] = hold
    last[0] = last0
    parent[0] = -1
    states = 1
    hk[0] = heap_key(max(hold + drow[start], free_from), hold)
    hn[0] = 0
    hsize = 1
    hm_put(sk, sv, sm, st_key(start, i0), 0)
    expanded = 0
    check_at = 2 * drow[start] + 500 + nbr.shape[0] // 8
    while hsize > 0:
        node = hn[0]
        heap_pop(hk, hn, hsize)
        hsize -= 1
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
        t = arrive[node]
        for j in range(k):
            u = nbr[v, j]
            if u < 0:
                break
            hu = drow[u]
            if hu >= unreach:
                continue
            parked = parked_by_other(park_owner, u, agent)
            iu = rs_lower(seg, ta, u, t + 1)
            # every interval of u the robot can still reach from v's, earliest arrival each
            while True:
                iu, at = reach(seg, ta, geo, v, t, last[node], u, iu, parked, closed[u], until[u])
                if iu < 0:
                    break
                key = st_key(u, iu)
                slot = hm_slot(sk, key)
                known = sv[slot] if sk[slot] == key else -1
                if known < 0 or arrive[known] > at:
                    # room for one more state (the arrays double when full)
                    if states == cell.shape[0]:
                        cell, ival, arrive = grow(cell, states + 1), grow(ival, states + 1), grow(arrive, states + 1)
                        last, parent = grow(last, states + 1), grow(parent, states + 1)
                    if hsize == hk.shape[0]:
                        hk, hn = grow(hk, hsize + 1), grow(hn, hsize + 1)
                    if 2 * (sm[0] + 1) > sk.shape[0]:
                        sk, sv, sm = hm_grow(sk, sv, sm)
                    cell[states] = u
                    ival[states] = iu
                    arrive[states] = at
                    last[states] = interval(seg, ta, u, iu)[1]
                    parent[states] = node
                    hm_put(sk, sv, sm, key, states)
                    heap_push(hk, hn, hsize, heap_key(max(at + hu, free_from), at), states)
                    hsize += 1
                    states += 1
                iu += 1
    return np.empty(0, dtype=np.int32)


@njit(cache=True)
def book_all(res: Reservations, buf: np.ndarray, off: np.ndarray, length: np.ndarray,
             agents: np.ndarray) -> Reservations:
    """Books the paths buf[off[a]:off[a] + length[a]] of `agents`; the arena may move."""
    for i in range(agents.shape[0]):
        a = agents[i]
        res = reserve(res, buf[off[a]:off[a] + length[a]], a)
    return res


@njit(cache=True)
def met_forecast(buf: np.ndarray, off: np.ndarray, length: np.ndarray, closed: np.ndarray,
                 window: int, out: np.ndarray) -> None:
    """out[a] = True when robot a's path enters a cell at a step in [closed[cell], window]
    (steps 1..window; a wait on a cell is never an entry)."""
    for a in range(off.shape[0]):
        out[a] = False
        o = off[a]
        for t in range(1, min(window, length[a] - 1) + 1):
            u = buf[o + t]
            if u != buf[o + t - 1] and closed[u] <= t:
                out[a] = True
                break
