"""LaCAM: lazy constraints addition search for MAPF (Okumura, AAAI 2023), and the default planner.

The high level is a depth-first search over configurations (one cell per
robot). Each configuration owns a queue of low-level constraint nodes ("robot
i goes to cell v", added lazily one robot at a time, in priority order); each
visit pops one, and PIBT generates a successor configuration obeying it.
Configurations already seen are not expanded again. Since the constraint
tree of a configuration eventually enumerates every successor, the search is
complete: it finds a solution whenever one exists, given time.

`lacam(problem, limits)` is the fast default: on sparse instances it first
tries prioritized planning (near-optimal and cheap when robots rarely meet),
otherwise LaCAM; then, while a small refinement budget lasts and the sum of
costs is above the lower bound, it replans groups of delayed robots with
space-time A* against the others' paths (large neighbourhood search), keeping
only improvements. Every result is a full valid plan at every moment.
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from protocol.errors import PlanningError

from .distances import Instance, compile_problem
from .pibt import _crosses, history_to_paths, initial_priorities, pibt_step, rand_next, update_priorities
from .prioritized import (hm_fit, hm_get, hm_new, hm_put, kernel_args, max_expansions, now, plan_prioritized,
                          reserve, st_astar, unreserve)
from .types import Limits, Path, Problem


@njit(cache=True)
def _hash_cfg(q: np.ndarray) -> int:
    h = np.uint64(1469598103934665603)
    for i in range(q.shape[0]):
        h = (h ^ np.uint64(q[i])) * np.uint64(1099511628211)
        h ^= h >> np.uint64(29)
    return np.int64(h >> np.uint64(1))     # non-negative: the hash map reserves negative keys


@njit(cache=True)
def _find_cfg(keys, vals, cfg, q: np.ndarray, h: int) -> int:
    """The node holding configuration q (hash h), or -1; hash collisions are told apart by content."""
    mask = keys.shape[0] - 1
    s = np.int64((np.uint64(h) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(29)) & mask
    while True:
        k = keys[s]
        if k == -1:
            return -1
        if k == h:
            node = vals[s]
            same = True
            for i in range(q.shape[0]):
                if cfg[node, i] != q[i]:
                    same = False
                    break
            if same:
                return node
        s = (s + 1) & mask


@njit(cache=True)
def _add_cfg(keys, vals, meta, h: int, node: int):
    """Inserts (h -> node) allowing equal hashes for different configurations."""
    if 2 * (meta[0] + 1) > keys.shape[0]:
        nk = np.full(2 * keys.shape[0], -1, dtype=np.int64)
        nv = np.empty(2 * keys.shape[0], dtype=np.int32)
        mask = nk.shape[0] - 1
        for s in range(keys.shape[0]):
            if keys[s] >= 0:
                t = np.int64((np.uint64(keys[s]) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(29)) & mask
                while nk[t] != -1:
                    t = (t + 1) & mask
                nk[t] = keys[s]
                nv[t] = vals[s]
        keys, vals = nk, nv
    mask = keys.shape[0] - 1
    s = np.int64((np.uint64(h) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(29)) & mask
    while keys[s] != -1:
        s = (s + 1) & mask
    keys[s] = h
    vals[s] = node
    meta[0] += 1
    return keys, vals


@njit(cache=True)
def _grow2(a: np.ndarray, rows: int) -> np.ndarray:
    b = np.empty((2 * a.shape[0], a.shape[1]), dtype=a.dtype)
    b[:rows] = a[:rows]
    return b


@njit(cache=True)
def _grow1(a: np.ndarray) -> np.ndarray:
    b = np.empty(2 * a.shape[0], dtype=a.dtype)
    b[:a.shape[0]] = a
    return b


@njit(cache=True)
def _search(nbr, dist, rows, starts, goals, prio0, xs, ys, index, width: int, diagonal: bool,
            deadline: float, seed: int, max_nodes: int):
    """LaCAM's high-level search: (status, configurations from start to goal [T, n]).

    status 0 solved, 1 proved unsolvable (search space exhausted), 2 time limit, 3 node cap."""
    n = nbr.shape[0]
    na = starts.shape[0]
    k = nbr.shape[1] + 1
    # high-level nodes
    cap = 256
    cfg = np.empty((cap, na), dtype=np.int32)
    prio = np.empty((cap, na), dtype=np.float32)
    parent = np.empty(cap, dtype=np.int32)
    q_head = np.empty(cap, dtype=np.int32)    # queue of low-level nodes to try
    q_tail = np.empty(cap, dtype=np.int32)
    # low-level (constraint) nodes
    lcap = 1024
    l_parent = np.empty(lcap, dtype=np.int32)
    l_who = np.empty(lcap, dtype=np.int32)
    l_where = np.empty(lcap, dtype=np.int32)
    l_depth = np.empty(lcap, dtype=np.int32)
    l_next = np.empty(lcap, dtype=np.int32)
    # explored configurations
    hkeys = np.full(1024, -1, dtype=np.int64)
    hvals = np.empty(1024, dtype=np.int32)
    hmeta = np.zeros(1, dtype=np.int64)
    open_ = np.empty(1024, dtype=np.int32)
    # scratch for PIBT
    occ_now = np.full(n, -1, dtype=np.int32)
    occ_nxt = np.full(n, -1, dtype=np.int32)
    st_agent = np.empty(na, dtype=np.int32)
    st_pos = np.empty(na, dtype=np.int32)
    st_nc = np.empty(na, dtype=np.int32)
    st_cand = np.empty((na, k), dtype=np.int32)
    rng = np.array([np.uint64(seed) * np.uint64(2654435761) + np.uint64(88172645463325252)], dtype=np.uint64)
    q_to = np.empty(na, dtype=np.int32)
    cands = np.empty(k, dtype=np.int32)
    p_new = np.empty(na, dtype=np.float64)

    cfg[0] = starts
    for i in range(na):
        prio[0, i] = prio0[i]
    parent[0] = -1
    l_parent[0] = -1
    l_who[0] = -1
    l_where[0] = -1
    l_depth[0] = 0
    l_next[0] = -1
    q_head[0] = 0
    q_tail[0] = 0
    nodes = 1
    lnodes = 1
    hkeys, hvals = _add_cfg(hkeys, hvals, hmeta, _hash_cfg(starts), 0)
    open_[0] = 0
    top = 1
    it = 0
    goal_node = -1
    status = 1
    while top > 0:
        it += 1
        if (it & 255) == 0 and now() > deadline:
            status = 2
            break
        h = open_[top - 1]
        is_goal = True
        for i in range(na):
            if cfg[h, i] != goals[i]:
                is_goal = False
                break
        if is_goal:
            goal_node = h
            status = 0
            break
        if q_head[h] < 0:
            top -= 1
            continue
        low = q_head[h]
        q_head[h] = l_next[low]
        order = np.argsort(-prio[h])
        # lazily add the children of this constraint: the next robot in order, every possible move
        if l_depth[low] < na:
            i = order[l_depth[low]]
            v = cfg[h, i]
            m = 0
            for j in range(k):
                u = v if j == k - 1 else nbr[v, j]
                if u >= 0:
                    cands[m] = u
                    m += 1
            for j in range(m - 1, 0, -1):      # random order, as in the paper
                r = rand_next(rng) % (j + 1)
                tmp = cands[j]
                cands[j] = cands[r]
                cands[r] = tmp
            for j in range(m):
                if lnodes == l_parent.shape[0]:
                    l_parent = _grow1(l_parent)
                    l_who = _grow1(l_who)
                    l_where = _grow1(l_where)
                    l_depth = _grow1(l_depth)
                    l_next = _grow1(l_next)
                l_parent[lnodes] = low
                l_who[lnodes] = i
                l_where[lnodes] = cands[j]
                l_depth[lnodes] = l_depth[low] + 1
                l_next[lnodes] = -1
                if q_head[h] < 0:
                    q_head[h] = lnodes
                else:
                    l_next[q_tail[h]] = lnodes
                q_tail[h] = lnodes
                lnodes += 1
        # successor configuration under the constraints of `low`
        q_from = cfg[h]
        q_to[:] = -1
        ok = True
        c = low
        while l_who[c] >= 0:
            who = l_who[c]
            wh = l_where[c]
            if occ_nxt[wh] >= 0:
                ok = False
                break
            q_to[who] = wh
            occ_nxt[wh] = who
            c = l_parent[c]
        for i in range(na):
            occ_now[q_from[i]] = i
        if ok:
            c = low
            while l_who[c] >= 0:
                who = l_who[c]
                j = occ_now[q_to[who]]
                if j >= 0 and j != who and q_to[j] == q_from[who]:
                    ok = False
                    break
                if diagonal and _crosses(q_from[who], q_to[who], q_to, occ_now, xs, ys, index, width):
                    ok = False
                    break
                c = l_parent[c]
        if ok:
            ok = pibt_step(nbr, dist, rows, q_from, q_to, order, occ_now, occ_nxt, xs, ys, index, width,
                           diagonal, st_agent, st_pos, st_nc, st_cand, rng)
        else:
            for i in range(na):
                if q_to[i] >= 0:
                    occ_nxt[q_to[i]] = -1
        for i in range(na):
            occ_now[q_from[i]] = -1
        if not ok:
            continue
        hq = _hash_cfg(q_to)
        found = _find_cfg(hkeys, hvals, cfg, q_to, hq)
        if found >= 0:
            # known configuration: revisit it (its remaining constraints may lead elsewhere)
            if top == open_.shape[0]:
                open_ = _grow1(open_)
            open_[top] = found
            top += 1
            continue
        if nodes >= max_nodes:
            status = 3
            break
        if nodes == cfg.shape[0]:
            cfg = _grow2(cfg, nodes)
            prio = _grow2(prio, nodes)
            parent = _grow1(parent)
            q_head = _grow1(q_head)
            q_tail = _grow1(q_tail)
        cfg[nodes] = q_to
        for i in range(na):
            p_new[i] = prio[h, i]
        update_priorities(p_new, q_to, goals)
        for i in range(na):
            prio[nodes, i] = p_new[i]
        parent[nodes] = h
        # a fresh root constraint (no robot fixed yet) for the new configuration
        if lnodes == l_parent.shape[0]:
            l_parent = _grow1(l_parent)
            l_who = _grow1(l_who)
            l_where = _grow1(l_where)
            l_depth = _grow1(l_depth)
            l_next = _grow1(l_next)
        l_parent[lnodes] = -1
        l_who[lnodes] = -1
        l_where[lnodes] = -1
        l_depth[lnodes] = 0
        l_next[lnodes] = -1
        q_head[nodes] = lnodes
        q_tail[nodes] = lnodes
        lnodes += 1
        hkeys, hvals = _add_cfg(hkeys, hvals, hmeta, hq, nodes)
        if top == open_.shape[0]:
            open_ = _grow1(open_)
        open_[top] = nodes
        top += 1
        nodes += 1
    if goal_node < 0:
        return status, cfg[:0]
    length = 0
    c = goal_node
    while c >= 0:
        length += 1
        c = parent[c]
    out = np.empty((length, na), dtype=np.int32)
    c = goal_node
    for t in range(length - 1, -1, -1):
        out[t] = cfg[c]
        c = parent[c]
    return 0, out


def search(inst: Instance, limits: Limits, max_nodes: int = 2**31 - 1) -> np.ndarray:
    """LaCAM's search alone: configurations [T, n] (compact ids) from the starts to the goals."""
    nbr, xs, ys, index, width = kernel_args(inst)
    status, hist = _search(nbr, inst.table.dist, inst.rows, inst.starts, inst.goals, initial_priorities(inst),
                           xs, ys, index, width, inst.problem.connectivity == 8,
                           time.perf_counter() + limits.remaining(), inst.problem.seed, max_nodes)
    if status == 1:
        raise PlanningError(f"lacam: no solution exists for these {inst.n} robots (every configuration explored)")
    if status == 2:
        raise PlanningError(f"lacam: time limit of {limits.seconds:g} s reached without a plan for {inst.n} robots")
    if status == 3:
        raise PlanningError(f"lacam: node cap of {max_nodes} reached without a plan for {inst.n} robots")
    return hist


def lacam(problem: Problem, limits: Limits) -> list[Path]:
    inst = compile_problem(problem)
    if inst.n == 0:
        return []
    return history_to_paths(inst, search(inst, limits))
