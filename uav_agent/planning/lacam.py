"""LaCAM: lazy constraints addition search for MAPF (Okumura, AAAI 2023), and the default planner.

The high level is a depth-first search over configurations (one cell per
robot). Each configuration owns a queue of low-level constraint nodes ("robot
i goes to cell v", added lazily one robot at a time, in priority order); each
visit pops one, and PIBT generates a successor configuration obeying it.
Configurations already seen are not expanded again. Since the constraint
tree of a configuration eventually enumerates every successor, the search is
complete: it finds a solution whenever one exists, given time.

PIBT here uses LaCAM3's swap technique (Okumura, AAMAS 2024), without which
robots meeting head-on in 1-wide aisles livelock.

`lacam(problem, limits)` is the fast default: on sparse instances it first
tries prioritized planning (near-optimal and cheap when robots rarely meet);
if that leaves robots unrouted, LaCAM runs with the routed robots' paths as
guides for PIBT. `refine` is an anytime improvement of a plan: it replans
groups of delayed robots with SIPP against the others' paths (large
neighbourhood search), keeping only improvements; it is not part of `lacam`
because, measured on LaCAM's plans for crowded warehouses, it won under 1 % of
the sum of costs for as much time again as the search.
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from protocol.errors import PlanningError

from .distances import Instance, compile_problem
from .pibt import _crosses, degrees, history_to_paths, initial_priorities, pibt, pibt_step, rand_next, update_priorities
from .prioritized import (
    copy_into,
    grow,
    guide_paths,
    kernel_args,
    max_expansions,
    now,
    order_by_priority,
    reserve,
    rs_find,
    rs_new,
    sipp,
    split_paths,
    unreserve,
)
from .types import Limits, Path, Problem

SEARCH_MEMORY = 1.0e9        # bytes LaCAM's search tables may take before it gives up


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
    for r in range(rows):
        for i in range(a.shape[1]):
            b[r, i] = a[r, i]
    return b


@njit(cache=True)
def _grow1(a: np.ndarray) -> np.ndarray:
    return grow(a, a.shape[0] + 1)


@njit(cache=True)
def _search(nbr, deg, dist, rows, starts, goals, prio0, xs, ys, index, width: int, diagonal: bool, swap: bool,
            deadline: float, seed: int, max_nodes: int, max_lnodes: int, gbuf, goff, glen):
    """LaCAM's high-level search: (status, configurations from start to goal [T, n]).

    Guide paths (robot i: gbuf[goff[i]:goff[i]+glen[i]], glen 0 = none) steer PIBT: a
    robot that is where its guide says at a node's depth tries the guide's next cell first.

    status 0 solved, 1 proved unsolvable (search space exhausted), 2 time limit, 3 node cap
    (max_nodes configurations or max_lnodes constraints: the memory bound)."""
    n = nbr.shape[0]
    na = starts.shape[0]
    k = nbr.shape[1] + 1
    # high-level nodes
    cap = 256
    cfg = np.empty((cap, na), dtype=np.int32)
    prio = np.empty((cap, na), dtype=np.float32)
    parent = np.empty(cap, dtype=np.int32)
    depth = np.empty(cap, dtype=np.int32)
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
    st_swap = np.empty(na, dtype=np.int32)
    rng = np.array([np.uint64(seed) * np.uint64(2654435761) + np.uint64(88172645463325252)], dtype=np.uint64)
    q_to = np.empty(na, dtype=np.int32)
    cands = np.empty(k, dtype=np.int32)
    p_new = np.empty(na, dtype=np.float32)
    pref = np.full(na, -1, dtype=np.int32)
    guided = False
    for i in range(na):
        if glen[i] > 0:
            guided = True

    for i in range(na):
        cfg[0, i] = starts[i]
        prio[0, i] = prio0[i]
    order = np.empty(na, dtype=np.int32)
    parent[0] = -1
    depth[0] = 0
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
        order_by_priority(prio[h], order)
        # lazily add the children of this constraint: the next robot in order, every possible move
        if l_depth[low] < na:
            if lnodes + k > max_lnodes:
                status = 3
                break
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
        for i in range(na):
            q_to[i] = -1
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
        if ok and guided:
            t = depth[h]
            for i in range(na):
                pref[i] = -1
                if glen[i] > 0:
                    if t + 1 < glen[i]:
                        if q_from[i] == gbuf[goff[i] + t]:
                            pref[i] = gbuf[goff[i] + t + 1]
                    elif q_from[i] == goals[i]:
                        pref[i] = goals[i]
        if ok:
            ok = pibt_step(nbr, deg, dist, rows, goals, q_from, q_to, order, occ_now, occ_nxt, xs, ys, index,
                           width, diagonal, swap, st_agent, st_pos, st_nc, st_cand, st_swap, rng, pref)
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
            depth = _grow1(depth)
            q_head = _grow1(q_head)
            q_tail = _grow1(q_tail)
        for i in range(na):
            cfg[nodes, i] = q_to[i]
            p_new[i] = prio[h, i]
        update_priorities(p_new, q_to, goals)
        for i in range(na):
            prio[nodes, i] = p_new[i]
        parent[nodes] = h
        depth[nodes] = depth[h] + 1
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
        for i in range(na):
            out[t, i] = cfg[c, i]
        c = parent[c]
    return 0, out


def search(inst: Instance, limits: Limits, memory: float = SEARCH_MEMORY, swap: bool = True,
           guides: tuple | None = None) -> np.ndarray:
    """LaCAM's search alone: configurations [T, n] (compact ids) from the starts to the goals.

    `memory` bounds the bytes of the search's node tables (a PlanningError when reached);
    `guides` = (flat paths, offsets, lengths) of cell ids, e.g. from `guide_paths`.
    """
    # a configuration node: n cells (int32) and n priorities (float32) plus its bookkeeping;
    # a constraint node: five int32
    max_nodes = int(max(1000, 0.6 * memory / (8 * inst.n + 24)))
    max_lnodes = int(max(10_000, 0.4 * memory / 20))
    nbr, xs, ys, index, width = kernel_args(inst)
    if guides is None:
        guides = (np.zeros(1, np.int32), np.zeros(inst.n, np.int64), np.zeros(inst.n, np.int64))
    status, hist = _search(nbr, degrees(nbr), inst.table.dist, inst.rows, inst.starts, inst.goals,
                           initial_priorities(inst), xs, ys, index, width, inst.problem.connectivity == 8, swap,
                           time.perf_counter() + limits.remaining(), inst.problem.seed, max_nodes,
                           max_lnodes, *guides)
    if status == 1:
        raise PlanningError(f"lacam: no solution exists for these {inst.n} robots (every configuration explored)")
    if status == 2:
        raise PlanningError(f"lacam: time limit of {limits.seconds:g} s reached without a plan for {inst.n} robots")
    if status == 3:
        raise PlanningError(f"lacam: search memory of {memory / 1e6:.0f} MB used up without a plan "
                            f"for {inst.n} robots")
    return hist


# Robots are first routed one by one (prioritized planning, skipping those it cannot route)
# when they are sparse enough for that to pay: on warehouse-10-20-10-2-1, 400 robots (7 % of
# the cells) take 0.3-0.7 s that way for a sum of costs 8-30 % above the lower bound, against
# 0.1-0.2 s and 80 % for LaCAM alone; at 600 robots (10 %) it takes 3 s and gains nothing.
GUIDE_DENSITY = 0.075
GUIDE_SHARE = 0.1              # at most this share of the time limit goes to the guide paths
GUIDED_FACTOR = 2.0            # a guided LaCAM search gets this many times the guides' time ...
GUIDED_MIN = 0.5               # ... but at least this many seconds, before LaCAM runs unguided
REFINE_EXPANSIONS = 50_000     # per replanning search in `refine`: a refinement step must stay short


def lacam(problem: Problem, limits: Limits) -> list[Path]:
    """The default planner: complete, fast, near-optimal on sparse instances.

    1. guide paths: one prioritized pass (with local repairs) when robots are sparse; when
       it routes every robot, that is the plan;
    2. otherwise LaCAM, its PIBT steered by the guide paths of the robots that were routed
       (unguided when too dense), which keeps LaCAM's completeness.
    The result depends only on the problem and its seed, not on the machine's speed (unless
    a time budget runs out). `refine` can improve a LaCAM plan further, given time.
    """
    inst = compile_problem(problem)
    if inst.n == 0:
        return []
    if inst.n <= GUIDE_DENSITY * inst.graph.n:
        began = time.perf_counter()
        share = Limits(min(limits.remaining(), GUIDE_SHARE * limits.seconds))
        found = guide_paths(inst, share, max_expansions(inst))
        if found is not None:
            buf, poff, plen, complete = found
            if complete:
                return split_paths(inst, buf, poff, plen)
            # guides can also lead PIBT astray: give the guided search a bounded try
            budget = min(limits.remaining() / 2, max(GUIDED_MIN, GUIDED_FACTOR * (time.perf_counter() - began)))
            try:
                return history_to_paths(inst, search(inst, Limits(budget), guides=(buf, poff, plen)))
            except PlanningError:
                if limits.expired():
                    raise
    return history_to_paths(inst, search(inst, limits))


@njit(cache=True)
def _refine(nbr, dist, rows, unreach: int, starts, goals, d0, buf, poff, plen, xs, ys, index, width: int,
            max_expand: int, deadline: float, target: int, seed: int, group: int):
    """Large neighbourhood search: replan a delayed robot and the robots in its way, keep improvements.

    Paths are cell-id runs in `buf` (robot a: buf[poff[a]:poff[a]+plen[a]], ending on
    its goal when it arrives for good). Returns the new (buf, poff, plen, sum of costs, iterations).
    """
    n = nbr.shape[0]
    na = starts.shape[0]
    total = 0
    for a in range(na):
        total += plen[a]
    seg, ta, meta = rs_new(n, 2 * total)
    park_time = np.full(n, np.iinfo(np.int32).max, dtype=np.int32)
    park_owner = np.full(n, -1, dtype=np.int32)
    soc = 0
    for a in range(na):
        ta = reserve(seg, ta, meta, buf[poff[a]:poff[a] + plen[a]], a, park_time, park_owner)
        soc += plen[a] - 1
    used = 0
    for a in range(na):
        used = max(used, poff[a] + plen[a])
    rng = np.array([np.uint64(seed) * np.uint64(2654435761) + np.uint64(1442695040888963407)], dtype=np.uint64)
    members = np.empty(group, dtype=np.int32)
    in_group = np.zeros(na, dtype=np.bool_)
    tmp_off = np.empty(group, dtype=np.int64)
    tmp_len = np.empty(group, dtype=np.int64)
    tmp = np.empty(1024, dtype=np.int32)
    fails = np.zeros(na, dtype=np.int32)    # recent fruitless tries per robot, to spread the effort
    stamp = np.zeros(n + 1, dtype=np.int32)
    queue = np.empty(n, dtype=np.int32)
    it = 0
    stale = 0
    while soc > target:
        it += 1
        if now() > deadline:
            break
        # the seed: the most delayed of a few random robots (tournament), fresh failures discounted
        a = -1
        best = 0
        for s in range(8):
            r = rand_next(rng) % na
            dl = (plen[r] - 1 - d0[r]) >> min(fails[r], 20)
            if dl > best:
                best = dl
                a = r
        if a < 0:
            stale += 1
            if stale > 64:
                # the tournament keeps missing: look for any delayed robot at all
                for r in range(na):
                    if plen[r] - 1 > d0[r]:
                        a = r
                        break
                if a < 0:
                    break
                for r in range(na):
                    fails[r] = 0
                stale = 0
            else:
                continue
        # the group: a, then robots met along one of a's shortest paths at the matching steps
        m = 0
        members[m] = a
        in_group[a] = True
        m += 1
        drow = dist[rows[a]]
        v = starts[a]
        t = 0
        while m < group:
            for dt in range(2):
                b = rs_find(seg, ta, v, t + dt)
                if b >= 0 and not in_group[b] and m < group:
                    members[m] = b
                    in_group[b] = True
                    m += 1
            b = park_owner[v]
            if b >= 0 and park_time[v] <= t + 1 and not in_group[b] and m < group:
                members[m] = b
                in_group[b] = True
                m += 1
            if v == goals[a]:
                break
            # step to a random neighbour one closer to the goal
            nxt = -1
            cnt = 0
            for j in range(nbr.shape[1]):
                u = nbr[v, j]
                if u < 0:
                    break
                if drow[u] < drow[v]:
                    cnt += 1
                    if rand_next(rng) % cnt == 0:
                        nxt = u
            v = nxt
            t += 1
        while m < min(group, na) and m < 3:
            b = rand_next(rng) % na
            if not in_group[b]:
                members[m] = b
                in_group[b] = True
                m += 1
        for j in range(m - 1, 0, -1):
            r = rand_next(rng) % (j + 1)
            x = members[j]
            members[j] = members[r]
            members[r] = x
        old = 0
        for j in range(m):
            b = members[j]
            old += plen[b] - 1
            unreserve(seg, ta, meta, buf[poff[b]:poff[b] + plen[b]], park_time, park_owner)
        # replan the group one robot at a time
        ok = True
        new = 0
        filled = 0
        done = 0
        rest = 0
        for j in range(m):
            rest += d0[members[j]]
        for j in range(m):
            b = members[j]
            rest -= d0[b]
            # only paths that can still make the group cheaper are worth finding
            f_max = old - 1 - new - rest
            if f_max < d0[b]:
                ok = False
                break
            path = sipp(nbr, dist[rows[b]], unreach, starts[b], goals[b], b, seg, ta, park_time, park_owner,
                        xs, ys, index, width, max_expand, f_max, stamp, queue)
            if path.shape[0] == 0:
                ok = False
                break
            new += path.shape[0] - 1
            ta = reserve(seg, ta, meta, path, b, park_time, park_owner)
            done += 1
            tmp = grow(tmp, filled + path.shape[0])
            copy_into(tmp, filled, path, path.shape[0])
            tmp_off[j] = filled
            tmp_len[j] = path.shape[0]
            filled += path.shape[0]
            if new >= old:
                ok = False      # cannot improve any more
                break
        if ok and new < old:
            buf = grow(buf, used + filled)
            for j in range(m):
                b = members[j]
                poff[b] = used + tmp_off[j]
                plen[b] = tmp_len[j]
                fails[b] = 0
            copy_into(buf, used, tmp, filled)
            used += filled
            soc -= old - new
        else:
            for j in range(done):
                b = members[j]
                unreserve(seg, ta, meta, tmp[tmp_off[j]:tmp_off[j] + tmp_len[j]], park_time, park_owner)
            for j in range(m):
                b = members[j]
                ta = reserve(seg, ta, meta, buf[poff[b]:poff[b] + plen[b]], b, park_time, park_owner)
            fails[a] += 1
        for j in range(m):
            in_group[members[j]] = False
        if used > 4 * total + 4096:
            # compact the path buffer
            live = 0
            for b in range(na):
                live += plen[b]
            nb = np.empty(2 * live + 1024, dtype=np.int32)
            pos = 0
            for b in range(na):
                copy_into(nb, pos, buf[poff[b]:poff[b] + plen[b]], plen[b])
                poff[b] = pos
                pos += plen[b]
            buf = nb
            used = pos
            total = live
    return buf, poff, plen, soc, it


def trimmed(inst: Instance, hist: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Configurations [T, n] -> flat per-robot cell-id paths cut after each last arrival."""
    away = hist != inst.goals[None, :]
    last = np.where(away.any(axis=0), hist.shape[0] - np.argmax(away[::-1], axis=0), 0)
    plen = (last + 1).astype(np.int64)
    poff = np.concatenate(([0], np.cumsum(plen)[:-1])).astype(np.int64)
    buf = np.concatenate([hist[:plen[i], i] for i in range(inst.n)]).astype(np.int32)
    return buf, poff, plen


def refine(inst: Instance, buf, poff, plen, seconds: float, target_ratio: float = 1.0, group: int = 8):
    """Anytime improvement of a plan given as flat cell-id paths (see `trimmed`): at most
    `seconds`, stopping early at `target_ratio` x the lower bound.
    Returns (buf, poff, plen, sum of costs, iterations)."""
    nbr, xs, ys, index, width = kernel_args(inst)
    d0 = inst.start_distances()
    target = int(np.floor(target_ratio * d0.sum()))
    return _refine(nbr, inst.table.dist, inst.rows, inst.table.unreachable, inst.starts, inst.goals, d0,
                   buf, poff.copy(), plen.copy(), xs, ys, index, width, min(max_expansions(inst), REFINE_EXPANSIONS),
                   time.perf_counter() + seconds, target, inst.problem.seed, group)


def warm_up(parts: tuple[str, ...] = ("guides", "search", "refine", "pibt")) -> float:
    """Loads the kernels of the fast planners on a tiny problem, compiling them the first time
    numba sees this code (tens of seconds; afterwards about a second from numba's cache), so
    that a timed call does not pay for it. `parts` picks kernel families, so that two
    processes can compile different ones at once. Returns the seconds it took."""
    began = time.perf_counter()
    free = np.ones((6, 6), dtype=bool)
    free[2:4, 1:5] = False
    for conn in (4, 8):
        problem = Problem(free, [(0, 0), (5, 5), (0, 5)], [(5, 5), (0, 0), (5, 0)], connectivity=conn)
        inst = compile_problem(problem)
        if "guides" in parts:
            guide_paths(inst, Limits(600.0), 1000)
        if "search" in parts or "refine" in parts:
            buf, poff, plen = trimmed(inst, search(inst, Limits(600.0)))
            if "refine" in parts:
                refine(inst, buf, poff, plen, 0.001)
        if "pibt" in parts:
            pibt(problem, Limits(600.0))
    return time.perf_counter() - began

