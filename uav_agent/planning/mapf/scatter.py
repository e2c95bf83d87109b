"""Guide routes that spread a crowded fleet over the floor before LaCAM plans it: LaCAM3's
"scatter", its space-utilisation optimisation (Okumura, "Engineering LaCAM*: Towards
Real-Time, Large-Scale, and Near-Optimal Multi-Agent Pathfinding", AAMAS 2024).

Unguided, every robot's PIBT step heads down its own distance field, so a crowded fleet
pours into the same aisles and waits there. Scatter routes each robot once through space
(no waiting), nearly as short as its shortest path (at most `MARGIN` steps longer), choosing
among those routes the one that meets the fewest other routes at the same step: a vertex,
a swap, or a cell another robot has parked on for good. The robots are routed one after
another in random order, each against all the others' current routes, in rounds, until a
round no longer lowers the number of such meetings. LaCAM's PIBT then tries a robot's route's
next cell first wherever the robot stands on its route (`lacam._follow_routes`); the routes
only steer it, so LaCAM stays complete.
"""
from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from ..compile.jit import njit

from .distances import Instance
from .grid_kernels import Grid, grid_of, grow, now, seeded, shuffle
from .sipp import hm_new, hm_put

# A route may be this many steps longer than the robot's shortest path (on a 4-connected grid a
# route without waits is longer by an even number: 3 routes as 2 does). 6 against 2, median SoC/LB
# over random-1..5 in-process: warehouse-10-20-10-2-1 600 / 1000 robots 1.491 / 2.023 against
# 1.607 / 2.199, random-64-64-20 1.339 / 1.974 against 1.444 / 2.027, room-64-64-8 3.119 / 5.398
# against 3.160 / 5.488, in about the same time; 8 was better on some and worse on others.
MARGIN = 6
MAX_ROUNDS = 100               # LaCAM3 has no cap; the rounds stop earlier when the meetings stop falling
MAX_TABLE_BYTES = 800e6       # the meeting tables' size (steps x cells x (1 + moves) int32) before scatter is skipped
FAR = np.int64(1) << np.int64(40)


class Tables(NamedTuple):
    """What the routes booked so far occupy."""
    cnt: np.ndarray           # int32 [steps, cells]: routes on a cell at a step
    moves: np.ndarray         # int32 [steps, cells, slots]: routes leaving a cell by a neighbour slot at a step
    back: np.ndarray          # int32 [cells, slots]: the slot of nbr[v, j] that leads back to v
    park: np.ndarray          # int64 [cells]: the step from which a robot stays on the cell (its goal)


@njit(cache=True, inline='always')
def _meetings(tb: Tables, nbr, v: int, j: int, t: int) -> int:
    """What the move from v by slot j, from step t to t+1, meets: routes on its cell at t+1,
    routes making the opposite move at once (a swap), a robot parked there since before t+1."""
    u = nbr[v, j]
    c = tb.cnt[t + 1, u] + tb.moves[t, u, tb.back[v, j]]
    if t + 1 > tb.park[u]:
        c += 1
    return c


@njit(cache=True, inline='always')
def _slot(nbr, v: int, u: int) -> int:
    for j in range(nbr.shape[1]):
        if nbr[v, j] == u:
            return j
    return -1


@njit(cache=True)
def _book(tb: Tables, nbr, buf, off: int, n: int, sign: int) -> int:
    """Books (sign 1) or takes out (sign -1) the route buf[off:off + n]: the meetings it has with
    the other routes booked (each move is met against the tables without the route itself)."""
    met = 0
    goal = buf[off + n - 1]
    if sign < 0:
        tb.park[goal] = FAR
    for t in range(n):
        v = buf[off + t]
        if sign < 0:
            tb.cnt[t, v] -= 1
        if t > 0:
            p = buf[off + t - 1]
            j = _slot(nbr, p, v)
            if sign < 0:
                tb.moves[t - 1, p, j] -= 1
            met += _meetings(tb, nbr, p, j, t - 1)
            if sign > 0:
                tb.moves[t - 1, p, j] += 1
        if sign > 0:
            tb.cnt[t, v] += 1
    if sign > 0:
        tb.park[goal] = n - 1
    for t in range(n, tb.cnt.shape[0]):
        met += tb.cnt[t, goal]
    return met


@njit(cache=True)
def _route(g: Grid, tb: Tables, a: int, bound: int, parent, used, head, nxt, nv, ng, nc, np_):
    """Robot a's route with the fewest meetings, then the fewest steps, within `bound` steps:
    A* over cells (each closed once, so a route never waits or comes back), ordered by
    (meetings, f). Returns (route length, 0 if none; cells closed, listed in `used`; the
    search's arrays, grown). The caller reads the route back through `parent` from the goal,
    then resets `parent` for the closed cells.

    The open list is a bucket queue (`head`, all -1 between calls, and `nxt`): a key is
    meetings x width + (f - the shortest distance), f takes only `width` values within the
    bound, and a child's key is never below its parent's, so the lowest bucket only moves up."""
    nbr = g.nbr
    drow = g.dist[g.rows[a]]
    start = g.starts[a]
    goal = g.goals[a]
    d = np.int64(drow[start])
    width = bound - d + 1
    nodes = 1
    nv[0] = start
    ng[0] = 0
    nc[0] = 0
    np_[0] = -1
    nxt[0] = -1
    head[0] = 0
    lo = 0
    hi = 0
    closed = 0
    found = -1
    while True:
        while lo <= hi and head[lo] < 0:
            lo += 1
        if lo > hi:
            break
        node = head[lo]
        head[lo] = nxt[node]
        v = nv[node]
        if parent[v] != -2:
            continue
        parent[v] = np_[node]
        used[closed] = v
        closed += 1
        if v == goal:
            found = node
            break
        t = ng[node]
        for j in range(nbr.shape[1]):
            u = nbr[v, j]
            if u < 0:
                break
            if parent[u] != -2 or drow[u] + t + 1 > bound:
                continue
            if nodes + 1 > nv.shape[0]:
                nv = grow(nv, nodes + 1)
                ng = grow(ng, nodes + 1)
                nc = grow(nc, nodes + 1)
                np_ = grow(np_, nodes + 1)
                nxt = grow(nxt, nodes + 1)
            c = nc[node] + _meetings(tb, nbr, v, j, t)
            b = c * width + (t + 1 + drow[u] - d)
            if b >= head.shape[0]:
                wider = np.full(max(b + 1, 2 * head.shape[0]), -1, dtype=np.int32)
                wider[:head.shape[0]] = head
                head = wider
            nv[nodes] = u
            ng[nodes] = t + 1
            nc[nodes] = c
            np_[nodes] = v
            nxt[nodes] = head[b]
            head[b] = nodes
            hi = max(hi, b)
            nodes += 1
    for b in range(lo, hi + 1):
        head[b] = -1
    length = 0 if found < 0 else ng[found] + 1
    return length, closed, head, nxt, nv, ng, nc, np_


@njit(cache=True)
def _scatter(g: Grid, d0, margin: int, deadline: float, seed: int, max_rounds: int):
    """Rounds of routing every robot in random order against the others' routes, until a round
    no longer lowers the meetings, `max_rounds` rounds or the time is up: (flat routes, offsets,
    lengths, meetings, rounds). A robot keeps its route from the last round it was routed in."""
    na = g.starts.shape[0]
    n = g.nbr.shape[0]
    horizon = 0
    for a in range(na):
        horizon = max(horizon, d0[a] + margin + 1)
    k = g.nbr.shape[1]
    back = np.zeros((n, k), dtype=np.int32)
    for v in range(n):
        for j in range(k):
            u = g.nbr[v, j]
            if u >= 0:
                back[v, j] = _slot(g.nbr, u, v)
    tb = Tables(np.zeros((horizon + 1, n), dtype=np.int32), np.zeros((horizon + 1, n, k), dtype=np.int32), back,
                np.full(n, FAR, dtype=np.int64))
    off = np.empty(na, dtype=np.int64)
    total = 0
    for a in range(na):
        off[a] = total
        total += d0[a] + margin + 1
    buf = np.empty(total, dtype=np.int32)
    length = np.zeros(na, dtype=np.int64)
    parent = np.full(n, -2, dtype=np.int32)
    used = np.empty(n, dtype=np.int32)
    head = np.full(1024, -1, dtype=np.int32)
    nxt = np.empty(1024, dtype=np.int32)
    nv = np.empty(1024, dtype=np.int32)
    ng = np.empty(1024, dtype=np.int64)
    nc = np.empty(1024, dtype=np.int64)
    np_ = np.empty(1024, dtype=np.int32)
    order = np.arange(na)
    rng = seeded(seed)
    met = 0
    last = np.int64(-1)
    rounds = 0
    while (rounds < 2 or met < last) and rounds < max_rounds:
        if now() > deadline:
            break
        rounds += 1
        last = met
        shuffle(order, na, rng)
        for ii in range(na):
            if (ii & 63) == 0 and now() > deadline:
                break
            a = order[ii]
            if length[a] > 0:
                met -= _book(tb, g.nbr, buf, off[a], length[a], -1)
            m, closed, head, nxt, nv, ng, nc, np_ = _route(g, tb, a, d0[a] + margin, parent, used, head, nxt,
                                                          nv, ng, nc, np_)
            if m > 0:
                v = g.goals[a]
                for t in range(m - 1, -1, -1):
                    buf[off[a] + t] = v
                    v = parent[v]
                length[a] = m
            for j in range(closed):
                parent[used[j]] = -2
            if length[a] > 0:
                met += _book(tb, g.nbr, buf, off[a], length[a], 1)
        if met == 0:
            break
    return buf, off, length, met, rounds


@njit(cache=True)
def _next_cells(buf, off, length):
    """(robot << 32 | cell) -> the cell after it on the robot's route, as an open-addressing map."""
    size = 0
    for a in range(length.shape[0]):
        size += max(length[a] - 1, 0)
    keys, vals, meta = hm_new(size + 1)
    for a in range(length.shape[0]):
        for t in range(length[a] - 1):
            hm_put(keys, vals, meta, (np.int64(a) << np.int64(32)) | np.int64(buf[off[a] + t]),
                   buf[off[a] + t + 1])
    return keys, vals


def routes(inst: Instance, seconds: float, margin: int = MARGIN, max_rounds: int = MAX_ROUNDS):
    """Scatter's routes as (keys, values) of `_next_cells`' map, and a few figures; None when
    the meeting tables would not fit (`MAX_TABLE_BYTES`)."""
    g = grid_of(inst)
    d0 = inst.start_distances().astype(np.int64)
    horizon = int(d0.max(initial=0)) + margin + 2
    if 4.0 * horizon * g.nbr.shape[0] * (1 + g.nbr.shape[1]) > MAX_TABLE_BYTES:
        return None
    buf, off, length, met, rounds = _scatter(g, d0, margin, time.perf_counter() + seconds, int(inst.problem.seed),
                                             max_rounds)
    keys, vals = _next_cells(buf, off, length)
    return keys, vals, {"meetings": int(met), "rounds": int(rounds), "route_steps": int((np.maximum(length, 1) - 1).sum())}
