"""LaCAM: lazy constraints addition search for MAPF (Okumura, "LaCAM: Search-Based
Algorithm for Quick Multi-Agent Pathfinding", AAAI 2023): the search alone.

The high level is a depth-first search over configurations (one cell per
robot). Each configuration owns a queue of low-level constraint nodes ("robot
i goes to cell v", added lazily one robot at a time, in priority order); each
visit pops one, and PIBT (`pibt.py`, with LaCAM3's swap technique) generates a
successor configuration obeying it. Configurations already seen are not
expanded again. Since the constraint tree of a configuration eventually
enumerates every successor, the search is complete: it finds a solution
whenever one exists, given time.

`search` is what the default planner (`planning/portfolio.py`) runs after its prioritized
passes, steered by their paths or by scatter's routes. A plain-Python reading copy of the
same search, without the tables and the steering: `planning/reference/lacam.py`.
"""
from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from ..compile.jit import njit

from protocol.errors import PlanningError, PlanningTimeout

from ..types import Limits
from .distances import Instance
from .grid_kernels import (
    Geometry,
    Grid,
    grid_of,
    grow,
    grow_rows,
    now,
    order_by_priority,
    shuffle,
)
from .pibt import (
    at_goals,
    crosses,
    initial_priorities,
    new_pibt,
    pibt_step,
    update_priorities,
)
from .reservations import Paths
from .sipp import hm_slot

SEARCH_MEMORY = 1.0e9        # bytes LaCAM's search tables may take before it gives up


class Configs(NamedTuple):
    """High-level nodes: a configuration, its priorities, and its queue of constraints to try."""
    cfg: np.ndarray           # int32 [cap, robots]
    prio: np.ndarray          # float32 [cap, robots]
    parent: np.ndarray        # int32 [cap]
    depth: np.ndarray         # int32 [cap]
    q_head: np.ndarray        # int32 [cap]: the queue of low-level nodes, linked by Constraints.next
    q_tail: np.ndarray        # int32 [cap]
    size: np.ndarray          # int64 [1]: nodes in use


class Constraints(NamedTuple):
    """Low-level nodes: robot `who` goes to cell `where`, on top of the constraints of `parent`."""
    parent: np.ndarray        # int32
    who: np.ndarray           # int32, -1 at a root (no robot fixed)
    where: np.ndarray         # int32
    depth: np.ndarray         # int32: robots fixed
    next: np.ndarray          # int32: the next node in its configuration's queue
    size: np.ndarray          # int64 [1]


class Explored(NamedTuple):
    """Configuration hash -> node, open addressing; equal hashes are told apart by content."""
    keys: np.ndarray          # int64, -1 empty
    vals: np.ndarray          # int32
    used: np.ndarray          # int64 [1]


@njit(cache=True)
def _hash_cfg(q: np.ndarray) -> int:
    h = np.uint64(1469598103934665603)
    for i in range(q.shape[0]):
        h = (h ^ np.uint64(q[i])) * np.uint64(1099511628211)
        h ^= h >> np.uint64(29)
    return np.int64(h >> np.uint64(1))     # non-negative: -1 marks an empty slot


@njit(cache=True, inline='always')
def _home(h: int, mask: int) -> int:
    return np.int64((np.uint64(h) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(29)) & mask


@njit(cache=True)
def _find_cfg(ex: Explored, cfg, q: np.ndarray, h: int) -> int:
    """The node holding configuration q (hash h), or -1."""
    mask = ex.keys.shape[0] - 1
    s = _home(h, mask)
    while True:
        k = ex.keys[s]
        if k == -1:
            return -1
        if k == h:
            node = ex.vals[s]
            same = True
            for i in range(q.shape[0]):
                if cfg[node, i] != q[i]:
                    same = False
                    break
            if same:
                return node
        s = (s + 1) & mask


@njit(cache=True)
def _add_cfg(ex: Explored, h: int, node: int) -> Explored:
    """Inserts (h -> node); the table may move."""
    keys, vals = ex.keys, ex.vals
    if 2 * (ex.used[0] + 1) > keys.shape[0]:
        nk = np.full(2 * keys.shape[0], -1, dtype=np.int64)
        nv = np.empty(2 * keys.shape[0], dtype=np.int32)
        mask = nk.shape[0] - 1
        for s in range(keys.shape[0]):
            if keys[s] >= 0:
                t = _home(keys[s], mask)
                while nk[t] != -1:
                    t = (t + 1) & mask
                nk[t] = keys[s]
                nv[t] = vals[s]
        keys, vals = nk, nv
    mask = keys.shape[0] - 1
    s = _home(h, mask)
    while keys[s] != -1:
        s = (s + 1) & mask
    keys[s] = h
    vals[s] = node
    ex.used[0] += 1
    return Explored(keys, vals, ex.used)


# The helpers of one high-level iteration take arrays rather than the structures: a call
# counts a reference to every array it is passed (see grid_kernels), and LaCAM makes many
# short iterations.

@njit(cache=True, inline='always')
def _with_room(con: Constraints, need: int) -> Constraints:
    return Constraints(grow(con.parent, need), grow(con.who, need), grow(con.where, need), grow(con.depth, need),
                       grow(con.next, need), con.size)


@njit(cache=True)
def _add_constraint(con: Constraints, parent: int, who: int, where: int, depth: int) -> int:
    """Appends a low-level node (the caller has made room); returns its id."""
    c = con.size[0]
    con.parent[c] = parent
    con.who[c] = who
    con.where[c] = where
    con.depth[c] = depth
    con.next[c] = -1
    con.size[0] = c + 1
    return c


@njit(cache=True, inline='always')
def _add_config(hi: Configs, q, prio, parent: int, depth: int, root: int) -> Configs:
    """Appends a high-level node whose constraint queue holds the root constraint `root`."""
    c = hi.size[0]
    if c == hi.cfg.shape[0]:
        hi = Configs(grow_rows(hi.cfg, c), grow_rows(hi.prio, c), grow(hi.parent, c + 1), grow(hi.depth, c + 1),
                     grow(hi.q_head, c + 1), grow(hi.q_tail, c + 1), hi.size)
    for i in range(q.shape[0]):
        hi.cfg[c, i] = q[i]
        hi.prio[c, i] = prio[i]
    hi.parent[c] = parent
    hi.depth[c] = depth
    hi.q_head[c] = root
    hi.q_tail[c] = root
    hi.size[0] = c + 1
    return hi


@njit(cache=True)
def _add_children(nbr, con: Constraints, low: int, i: int, v: int, q_head, q_tail, h: int, rng) -> None:
    """The low-level expansion: below constraint `low`, one child per cell robot i (at v) can
    take next (its neighbours and its own cell, in random order as in the paper), queued at
    node h. The caller has made room."""
    k = nbr.shape[1] + 1
    cands = np.empty(k, dtype=np.int32)
    m = 0
    for j in range(k):
        u = v if j == k - 1 else nbr[v, j]
        if u >= 0:
            cands[m] = u
            m += 1
    shuffle(cands, m, rng)
    for j in range(m):
        c = _add_constraint(con, low, i, cands[j], con.depth[low] + 1)
        if q_head[h] < 0:
            q_head[h] = c
        else:
            con.next[q_tail[h]] = c
        q_tail[h] = c


@njit(cache=True)
def _constrain(who, where, parent, low: int, geo: Geometry, occ_now, occ_nxt, q_from, q_to) -> bool:
    """Starts the successor of q_from with the moves constraint `low` fixes (q_to, with the
    occupancy maps PIBT reads); False, with the next-step map cleared again, when two of them
    take one cell, swap, or cross."""
    for i in range(q_to.shape[0]):
        q_to[i] = -1
    ok = True
    c = low
    while who[c] >= 0:
        if occ_nxt[where[c]] >= 0:
            ok = False
            break
        q_to[who[c]] = where[c]
        occ_nxt[where[c]] = who[c]
        c = parent[c]
    for i in range(q_from.shape[0]):
        occ_now[q_from[i]] = i
    c = low
    while ok and who[c] >= 0:
        a = who[c]
        j = occ_now[q_to[a]]
        if (j >= 0 and j != a and q_to[j] == q_from[a]) \
                or (geo.diagonal and crosses(geo, q_from[a], q_to[a], q_to, occ_now)):
            ok = False
        c = parent[c]
    if not ok:
        for i in range(q_to.shape[0]):
            if q_to[i] >= 0:
                occ_nxt[q_to[i]] = -1
    return ok


@njit(cache=True, inline='always')
def _follow_guides(guides: Paths, goals, t: int, q_from, pref) -> None:
    """A robot that is where its guide path says at step t tries the guide's next cell first
    (at the guide's end, it stays on its goal)."""
    for i in range(q_from.shape[0]):
        pref[i] = -1
        n = guides.length[i]
        if n > 0:
            if t + 1 < n:
                if q_from[i] == guides.buf[guides.off[i] + t]:
                    pref[i] = guides.buf[guides.off[i] + t + 1]
            elif q_from[i] == goals[i]:
                pref[i] = goals[i]


@njit(cache=True, inline='always')
def _follow_routes(keys, vals, q_from, pref) -> None:
    """A robot standing on its scatter route (`scatter.py`) tries the route's next cell first."""
    for i in range(q_from.shape[0]):
        key = (np.int64(i) << np.int64(32)) | np.int64(q_from[i])
        slot = hm_slot(keys, key)
        pref[i] = vals[slot] if keys[slot] == key else -1


@njit(cache=True, inline='always')
def _history(hi: Configs, node: int) -> np.ndarray:
    """The configurations from the root to `node` [T, robots]."""
    length = 0
    c = node
    while c >= 0:
        length += 1
        c = hi.parent[c]
    out = np.empty((length, hi.cfg.shape[1]), dtype=np.int32)
    c = node
    for t in range(length - 1, -1, -1):
        for i in range(hi.cfg.shape[1]):
            out[t, i] = hi.cfg[c, i]
        c = hi.parent[c]
    return out


@njit(cache=True)
def _search(g: Grid, prio0, swap: bool, deadline: float, seed: int, max_nodes: int, max_lnodes: int,
            guides: Paths, route_keys, route_vals):
    """LaCAM's high-level search: (status, configurations from start to goal [T, n]).

    Guide paths (robot i: guides.length[i] 0 = none) steer PIBT: a robot that is where its
    guide says at a node's depth tries the guide's next cell first.

    status 0 solved, 1 proved unsolvable (search space exhausted), 2 time limit, 3 node cap
    (max_nodes configurations or max_lnodes constraints: the memory bound)."""
    na = g.starts.shape[0]
    k = g.nbr.shape[1] + 1
    hi = Configs(np.empty((256, na), dtype=np.int32), np.empty((256, na), dtype=np.float32),
                 np.empty(256, dtype=np.int32), np.empty(256, dtype=np.int32), np.empty(256, dtype=np.int32),
                 np.empty(256, dtype=np.int32), np.zeros(1, dtype=np.int64))
    con = Constraints(np.empty(1024, dtype=np.int32), np.empty(1024, dtype=np.int32), np.empty(1024, dtype=np.int32),
                      np.empty(1024, dtype=np.int32), np.empty(1024, dtype=np.int32), np.zeros(1, dtype=np.int64))
    ex = Explored(np.full(1024, -1, dtype=np.int64), np.empty(1024, dtype=np.int32), np.zeros(1, dtype=np.int64))
    open_ = np.empty(1024, dtype=np.int32)      # the depth-first stack of high-level nodes
    w = new_pibt(g, seed, swap)
    q_to = np.empty(na, dtype=np.int32)
    p_new = np.empty(na, dtype=np.float32)
    order = np.empty(na, dtype=np.int64)
    guided = False
    for i in range(na):
        if guides.length[i] > 0:
            guided = True
    routed = route_keys.shape[0] > 1
    root = hi.size[0]
    _add_constraint(con, -1, -1, -1, 0)
    hi = _add_config(hi, g.starts, prio0, -1, 0, 0)
    ex = _add_cfg(ex, _hash_cfg(g.starts), root)
    open_[0] = root
    top = 1
    it = 0
    status = 1
    while top > 0:
        it += 1
        if (it & 255) == 0 and now() > deadline:
            status = 2
            break
        h = open_[top - 1]
        q_from = hi.cfg[h]
        if at_goals(q_from, g.goals):
            return 0, _history(hi, h)
        if hi.q_head[h] < 0:
            top -= 1        # every successor of h tried
            continue
        low = hi.q_head[h]
        hi.q_head[h] = con.next[low]
        order_by_priority(hi.prio[h], order)
        if con.depth[low] < na:
            if con.size[0] + k > max_lnodes:
                status = 3
                break
            if con.size[0] + k > con.parent.shape[0]:
                con = _with_room(con, con.size[0] + k)
            i = order[con.depth[low]]
            _add_children(g.nbr, con, low, i, hi.cfg[h, i], hi.q_head, hi.q_tail, h, w.rng)
        # the configuration generator: PIBT for the robots the constraint leaves free
        ok = _constrain(con.who, con.where, con.parent, low, g.geo, w.occ_now, w.occ_nxt, q_from, q_to)
        if ok:
            if guided:
                _follow_guides(guides, g.goals, hi.depth[h], q_from, w.pref)
            elif routed:
                _follow_routes(route_keys, route_vals, q_from, w.pref)
            ok = pibt_step(g, w, q_from, q_to, order)
        for i in range(na):
            w.occ_now[q_from[i]] = -1
        if not ok:
            continue
        hq = _hash_cfg(q_to)
        node = _find_cfg(ex, hi.cfg, q_to, hq)
        if node < 0:
            node = hi.size[0]
            if node >= max_nodes:
                status = 3
                break
            for i in range(na):
                p_new[i] = hi.prio[h, i]
            update_priorities(p_new, q_to, g.goals)
            if con.size[0] == con.parent.shape[0]:
                con = _with_room(con, con.size[0] + 1)
            hi = _add_config(hi, q_to, p_new, h, hi.depth[h] + 1, _add_constraint(con, -1, -1, -1, 0))
            ex = _add_cfg(ex, hq, node)
        # onto the stack: the new node, or the known one again (its remaining constraints may lead elsewhere)
        open_ = grow(open_, top + 1)
        open_[top] = node
        top += 1
    return status, hi.cfg[:0]


def search(inst: Instance, limits: Limits, memory: float = SEARCH_MEMORY, swap: bool = True,
           guides: tuple | None = None, routes: tuple | None = None) -> np.ndarray:
    """LaCAM's search alone: configurations [T, n] (compact ids) from the starts to the goals.

    `memory` bounds the bytes of the search's node tables (a PlanningError when reached);
    `guides` = (flat paths, offsets, lengths) of cell ids, e.g. from `guide_paths`;
    `routes` = (keys, values) of scatter's next-cell map (`scatter.routes`).
    """
    # a configuration node: n cells (int32) and n priorities (float32) plus its bookkeeping;
    # a constraint node: five int32
    max_nodes = int(max(1000, 0.6 * memory / (8 * inst.n + 24)))
    max_lnodes = int(max(10_000, 0.4 * memory / 20))
    if guides is None:
        guides = (np.zeros(1, np.int32), np.zeros(inst.n, np.int64), np.zeros(inst.n, np.int64))
    buf, off, length = guides
    guide = Paths(np.asarray(buf, np.int32), np.asarray(off, np.int64), np.asarray(length, np.int64),
                  np.zeros(1, np.int64))
    keys, vals = routes if routes is not None else (np.full(1, -1, np.int64), np.zeros(1, np.int32))
    status, hist = _search(grid_of(inst), initial_priorities(inst), swap, time.perf_counter() + limits.remaining(),
                           int(inst.problem.seed), max_nodes, max_lnodes, guide, keys, vals)
    if status == 1:
        raise PlanningError(f"lacam: no solution exists for these {inst.n} robots (every configuration explored)")
    if status == 2:
        raise PlanningTimeout(f"lacam: time limit of {limits.seconds:g} s reached without a plan for {inst.n} robots")
    if status == 3:
        raise PlanningError(f"lacam: search memory of {memory / 1e6:.0f} MB used up without a plan "
                            f"for {inst.n} robots")
    return hist
