"""The grid as the planners' numba kernels see it, and the small tools they share.

No paper of its own: SIPP (`sipp.py`), prioritized planning (`prioritized.py`),
PIBT (`pibt.py`), LaCAM (`lacam.py`) and the refinement (`refine.py`) all
search the grid graph of `distances.py` under the MAPF conventions of Stern
et al. ("Multi-Agent Pathfinding: Definitions, Variants, and Benchmarks",
SoCS 2019): unit-time moves to a neighbour or waits, no two robots on one cell
or swapping, and in 8-connectivity no two diagonal moves crossing. `Grid`
bundles the arrays of one instance so that a kernel takes one argument for
them. The rest are what numba lacks: arrays that grow, a binary heap, ordering
by priority, breadth-first scratch, and small random generators whose fixed
sequences make every plan reproducible per seed.

Small helpers use explicit loops: numpy slice assignment and concatenate pull
broadcasting and error-formatting code into every kernel and slow compiling down.

Kernels take these structures; the helpers of the innermost loops (per search
state, per candidate cell, per LaCAM iteration) take the arrays they read, and
hot kernels keep the fields they use in locals. Numba takes and drops a
reference to every array of a structure argument on entering and leaving a
function (a runtime call each; its pruning pass removes them only from simple,
loop-free functions), and in an inner loop that costs more than the work:
passing the structures down, SIPP ran three times slower and PIBT and LaCAM
up to half as slow again.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
from ..compile import jit
from ..compile.jit import njit

from .distances import Instance


class Geometry(NamedTuple):
    """Where cells lie: what the no-crossing rule of diagonal moves needs."""
    xs: np.ndarray            # int32 [n]: column of each cell
    ys: np.ndarray            # int32 [n]: row of each cell
    index: np.ndarray         # int32 [h*w]: flat cell y*w+x -> compact id, -1 for obstacles
    width: int
    diagonal: bool            # 8-connected: diagonal moves must not cross


class Grid(NamedTuple):
    """An instance as the kernels read it (they never write to it); `grid_of` builds it."""
    nbr: np.ndarray           # int32 [n, 4 or 8]: compact neighbour ids, -1 padded at the end
    geo: Geometry
    dist: np.ndarray          # uint16 or int32 [goals, n]: steps to each goal
    rows: np.ndarray          # int32 [robots]: robot a's row of dist
    unreach: int              # dist's value for "cannot reach"
    starts: np.ndarray        # int32 [robots]
    goals: np.ndarray         # int32 [robots]


def grid_of(inst: Instance) -> Grid:
    g = inst.graph
    xs, ys = g.xy()
    # plain Python ints and bools: a numpy scalar would give the kernels another signature to compile
    geo = Geometry(xs.astype(np.int32), ys.astype(np.int32), g.index, int(g.width), inst.problem.connectivity == 8)
    return Grid(g.nbr, geo, inst.table.dist, inst.rows, int(inst.table.unreachable), inst.starts, inst.goals)


@njit(cache=True)
def now() -> float:
    """`time.perf_counter()`, read from compiled code (see `clock.py`)."""
    return jit.monotonic()


@njit(cache=True, inline='always')
def corners(geo: Geometry, u: int, v: int) -> tuple:
    """The two cells a diagonal move u -> v passes between: (v's column, u's row), (u's column, v's row)."""
    return geo.index[geo.ys[u] * geo.width + geo.xs[v]], geo.index[geo.ys[v] * geo.width + geo.xs[u]]


@njit(cache=True, inline='always')
def is_diagonal(geo: Geometry, u: int, v: int) -> bool:
    return geo.xs[u] != geo.xs[v] and geo.ys[u] != geo.ys[v]


# ---- arrays that grow ----

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
def grow_rows(a: np.ndarray, used: int) -> np.ndarray:
    """A 2-D array with twice the rows, holding a's first `used` rows."""
    b = np.empty((2 * a.shape[0], a.shape[1]), dtype=a.dtype)
    for r in range(used):
        for i in range(a.shape[1]):
            b[r, i] = a[r, i]
    return b


# ---- a binary min-heap of (int64 key, int32 item) in two arrays ----

@njit(cache=True, inline='always')
def heap_push(keys, items, size: int, key: int, item: int) -> None:
    """Adds (key, item); the caller makes sure size < capacity."""
    i = size
    while i > 0:
        p = (i - 1) >> 1
        if keys[p] <= key:
            break
        keys[i] = keys[p]
        items[i] = items[p]
        i = p
    keys[i] = key
    items[i] = item


@njit(cache=True, inline='always')
def heap_pop(keys, items, size: int) -> None:
    """Removes the minimum (read keys[0], items[0] first); size is the size before removal."""
    size -= 1
    if size == 0:
        return
    lk = keys[size]
    li = items[size]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= size:
            break
        if c + 1 < size and keys[c + 1] < keys[c]:
            c += 1
        if keys[c] >= lk:
            break
        keys[i] = keys[c]
        items[i] = items[c]
        i = c
    keys[i] = lk
    items[i] = li


# ---- robots by priority ----

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


# ---- random numbers: two generators, because each planner's plans follow its own sequence ----

@njit(cache=True)
def seeded(seed: int) -> np.ndarray:
    """A state for `rand_next`, from a seed."""
    return np.array([np.uint64(seed) * np.uint64(2654435761) + np.uint64(1442695040888963407)], dtype=np.uint64)


@njit(cache=True)
def rand_next(state: np.ndarray) -> int:
    """xorshift64: a small reproducible generator for tie-breaking inside kernels."""
    x = state[0]
    x ^= x << np.uint64(13)
    x ^= x >> np.uint64(7)
    x ^= x << np.uint64(17)
    state[0] = x
    return np.int64(x >> np.uint64(40))


@njit(cache=True, inline='always')
def lcg_next(state: np.ndarray) -> int:
    """Knuth's 64-bit linear congruential generator, top 31 bits: the repair's sequence."""
    state[0] = state[0] * np.uint64(6364136223846793005) + np.uint64(1442695040888963407)
    return np.int64(state[0] >> np.uint64(33))


@njit(cache=True)
def shuffle(a: np.ndarray, m: int, rng: np.ndarray) -> None:
    """Fisher-Yates on a[:m] with rand_next."""
    for j in range(m - 1, 0, -1):
        r = rand_next(rng) % (j + 1)
        tmp = a[j]
        a[j] = a[r]
        a[r] = tmp


@njit(cache=True)
def downhill(nbr, drow, v: int, rng: np.ndarray, lcg: bool) -> int:
    """A neighbour of v one step closer to drow's goal, uniformly at random (-1 at the goal):
    one step of a random shortest path."""
    nxt = np.int32(-1)      # a cell id like nbr's, so that walks keep one type
    cnt = 0
    for j in range(nbr.shape[1]):
        u = nbr[v, j]
        if u < 0:
            break
        if drow[u] < drow[v]:
            cnt += 1
            r = lcg_next(rng) if lcg else rand_next(rng)
            if r % cnt == 0:
                nxt = u
    return nxt


# ---- breadth-first scratch ----

class Visits(NamedTuple):
    """Scratch for breadth-first searches that visit few cells: no clearing between searches."""
    stamp: np.ndarray         # int32 [n+1]: [0] the current search's mark, [1 + v] the mark v was seen with
    queue: np.ndarray         # int32 [n]


@njit(cache=True, inline='always')
def new_visits(n: int) -> Visits:
    return Visits(np.zeros(n + 1, dtype=np.int32), np.empty(n, dtype=np.int32))


@njit(cache=True, inline='always')
def begin_visits(vis: Visits, src: int) -> int:
    """Starts a search from src (queued and marked seen); returns its mark."""
    vis.stamp[0] += 1
    mark = vis.stamp[0]
    vis.stamp[1 + src] = mark
    vis.queue[0] = src
    return mark
