"""The reservation table of prioritized planning, and the flat path store.

Cooperative A* (Silver, "Cooperative Pathfinding", AIIDE 2005) books each
planned path in a table of (cell, step) pairs that later robots must avoid;
SIPP (Phillips & Likhachev, ICRA 2011) reads the same table as safe intervals,
the free stretches between a cell's bookings. Here a cell's bookings are one
sorted list (step << 32 | robot) in a segment of an arena, so that "who holds
v at t" is a short binary search in one cache line and a safe interval is two
neighbouring entries. A robot that has arrived parks on its goal for good:
`park_time`/`park_owner` say from when and who, instead of endless bookings.

`Paths` keeps many robots' paths as runs of cell ids in one growing buffer.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from ..compile.jit import njit

from .grid_kernels import Geometry, copy_into, corners, grow, is_diagonal

NEVER = np.iinfo(np.int32).max   # park time of a cell nobody parks on
FOREVER = np.int64(1) << np.int64(40)     # the end of the last safe interval of a cell


class Reservations(NamedTuple):
    """Who holds which cell at which step; a full segment moves to the arena's end with twice the room."""
    seg: np.ndarray           # int64 [n, 3]: a cell's (offset, length, capacity) in ta
    ta: np.ndarray            # int64 arena of (step << 32 | robot), sorted within each segment
    meta: np.ndarray          # int64 [2]: arena used, live entries
    park_time: np.ndarray     # int32 [n]: the step from which a robot stays on the cell, or NEVER
    park_owner: np.ndarray    # int32 [n]: that robot, or -1


@njit(cache=True, inline='always')
def new_reservations(n: int, capacity: int) -> Reservations:
    return Reservations(np.zeros((n, 3), dtype=np.int64), np.empty(max(capacity, 1024), dtype=np.int64),
                        np.zeros(2, dtype=np.int64), np.full(n, NEVER, dtype=np.int32),
                        np.full(n, -1, dtype=np.int32))


# The lookups below take the arrays seg and ta rather than the table: they run in SIPP's
# innermost loop (see grid_kernels on why).

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
def holder(seg, ta, v: int, t: int) -> int:
    """The robot holding v at step t, or -1."""
    i = rs_lower(seg, ta, v, t)
    if i < seg[v, 1]:
        x = ta[seg[v, 0] + i]
        if (x >> np.int64(32)) == t:
            return np.int64(x & np.int64(0xFFFFFFFF))
    return -1


@njit(cache=True, inline='always')
def interval(seg, ta, u: int, iu: int) -> tuple:
    """The first and last step of u's safe interval iu (the one after iu entries of its list)."""
    lu = seg[u, 1]
    lo = 0 if iu == 0 else rs_step(seg, ta, u, iu - 1) + 1
    hi = FOREVER if iu == lu else rs_step(seg, ta, u, iu) - 1
    return lo, hi


@njit(cache=True, inline='always')
def edge_blocked(seg, ta, geo: Geometry, v: int, u: int, t: int) -> bool:
    """Whether the move v -> u between steps t and t+1 swaps with, or (diagonally) crosses,
    a reserved move."""
    b = holder(seg, ta, v, t + 1)
    if b >= 0 and holder(seg, ta, u, t) == b:
        return True
    if is_diagonal(geo, u, v):
        p, q = corners(geo, v, u)
        b = holder(seg, ta, p, t)
        if b >= 0 and holder(seg, ta, q, t + 1) == b:
            return True
        b = holder(seg, ta, q, t)
        if b >= 0 and holder(seg, ta, p, t + 1) == b:
            return True
    return False


@njit(cache=True, inline='always')
def parked_by_other(park_owner, v: int, agent: int) -> bool:
    return park_owner[v] >= 0 and park_owner[v] != agent


@njit(cache=True)
def _insert(seg, ta, meta, v: int, t: int, agent: int):
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
def _remove(seg, ta, meta, v: int, t: int) -> None:
    i = rs_lower(seg, ta, v, t)
    ln = seg[v, 1]
    if i < ln and rs_step(seg, ta, v, i) == t:
        off = seg[v, 0]
        for j in range(i, ln - 1):
            ta[off + j] = ta[off + j + 1]
        seg[v, 1] = ln - 1
        meta[1] -= 1


@njit(cache=True)
def reserve(res: Reservations, path: np.ndarray, agent: int) -> Reservations:
    """Books a path (its last cell is the robot's goal, held from then on); the arena may move."""
    seg, ta, meta = res.seg, res.ta, res.meta
    for t in range(path.shape[0]):
        ta = _insert(seg, ta, meta, path[t], t, agent)
    g = path[path.shape[0] - 1]
    res.park_time[g] = path.shape[0] - 1
    res.park_owner[g] = agent
    return Reservations(seg, ta, meta, res.park_time, res.park_owner)


@njit(cache=True)
def unreserve(res: Reservations, path: np.ndarray) -> None:
    seg, ta, meta = res.seg, res.ta, res.meta
    for t in range(path.shape[0]):
        _remove(seg, ta, meta, path[t], t)
    g = path[path.shape[0] - 1]
    res.park_time[g] = NEVER
    res.park_owner[g] = -1


# ---- paths of many robots in one buffer ----

class Paths(NamedTuple):
    """Robot a's path is buf[off[a]:off[a] + length[a]] (length 0: none); runs may be stale copies."""
    buf: np.ndarray           # int32 cell ids
    off: np.ndarray           # int64 [robots]
    length: np.ndarray        # int64 [robots]
    end: np.ndarray           # int64 [1]: the cells of buf in use


@njit(cache=True, inline='always')
def new_paths(robots: int, capacity: int) -> Paths:
    return Paths(np.empty(capacity, dtype=np.int32), np.zeros(robots, dtype=np.int64),
                 np.zeros(robots, dtype=np.int64), np.zeros(1, dtype=np.int64))


@njit(cache=True, inline='always')
def path_of(p: Paths, a: int) -> np.ndarray:
    return p.buf[p.off[a]:p.off[a] + p.length[a]]


@njit(cache=True)
def store(p: Paths, a: int, path: np.ndarray) -> Paths:
    """Appends robot a's new path; the buffer may move."""
    used = p.end[0]
    buf = grow(p.buf, used + path.shape[0])
    copy_into(buf, used, path, path.shape[0])
    p.off[a] = used
    p.length[a] = path.shape[0]
    p.end[0] = used + path.shape[0]
    return Paths(buf, p.off, p.length, p.end)
