"""PIBT, Priority Inheritance with Backtracking (Okumura et al., IJCAI 2019 / AIJ 2022).

One step at a time, robots in priority order pick their next cell by distance
to goal; a robot that wants an occupied cell lends its priority to the
occupant, which must then move away first (recursively), or the move is
dropped (backtracking). Vertex and swap conflicts (and crossing diagonals in
8-connectivity) are excluded by construction. A robot's priority grows while
it is away from its goal and falls back to its fractional start value once
there. PIBT alone can cycle forever (livelock), so `pibt` gives up with a
PlanningError after a step cap or the time limit; `lacam.py` uses the step
kernel as its configuration generator and is complete.
"""
from __future__ import annotations

import time

import numpy as np
from numba import njit

from protocol.errors import PlanningError

from .distances import Instance, compile_problem
from .prioritized import kernel_args, now, order_by_priority
from .types import Limits, Path, Problem


@njit(cache=True)
def rand_next(state: np.ndarray) -> int:
    """xorshift64: a small reproducible generator for tie-breaking inside kernels."""
    x = state[0]
    x ^= x << np.uint64(13)
    x ^= x >> np.uint64(7)
    x ^= x << np.uint64(17)
    state[0] = x
    return np.int64(x >> np.uint64(40))


@njit(cache=True)
def _candidates(nbr, drow, v: int, occ_now, out: np.ndarray, rng: np.ndarray, pref: int) -> int:
    """Neighbours of v and v itself, `pref` first, then nearest to the goal first; ties prefer
    free cells, then random."""
    k = nbr.shape[1]
    keys = np.empty(k + 1, dtype=np.int64)
    m = 0
    for j in range(k + 1):
        u = v if j == k else nbr[v, j]
        if u < 0:
            continue
        key = (np.int64(drow[u]) << np.int64(26)) + (np.int64(1 << 25) if occ_now[u] >= 0 else 0) \
            + (rand_next(rng) & np.int64((1 << 24) - 1))
        if u == pref:
            key = -1
        # insertion sort: at most 9 entries
        i = m
        while i > 0 and keys[i - 1] > key:
            keys[i] = keys[i - 1]
            out[i] = out[i - 1]
            i -= 1
        keys[i] = key
        out[i] = u
        m += 1
    return m


@njit(cache=True)
def _crosses(u: int, v: int, q_to, occ_now, xs, ys, index, width: int) -> bool:
    """Whether the diagonal move u -> v crosses an already chosen diagonal move."""
    if xs[u] == xs[v] or ys[u] == ys[v]:
        return False
    p = index[ys[u] * width + xs[v]]
    q = index[ys[v] * width + xs[u]]
    j = occ_now[p]
    if j >= 0 and q_to[j] == q:
        return True
    j = occ_now[q]
    return bool(j >= 0 and q_to[j] == p)


@njit(cache=True)
def _ignorable(nbr, deg, u: int, v_pusher: int, occ_now, goals) -> bool:
    """A neighbour that does not count as an escape: the pusher's cell, or a dead end
    where a robot already sits on its goal."""
    if u == v_pusher:
        return True
    a = occ_now[u]
    return deg[u] == 1 and a >= 0 and goals[a] == u


@njit(cache=True)
def _swap_required(pusher: int, puller: int, v_pusher: int, v_puller: int, nbr, deg, dist, rows,
                   occ_now, goals) -> bool:
    """Simulates the pusher driving the puller ahead along a corridor: True when they would
    have to exchange places (no side cell to step aside into before the pusher's way ends)."""
    dp = dist[rows[pusher]]
    dq = dist[rows[puller]]
    tmp = -1
    steps = 0
    while dp[v_puller] < dp[v_pusher] and steps < nbr.shape[0]:
        steps += 1
        m = 0
        for j in range(nbr.shape[1]):
            u = nbr[v_puller, j]
            if u < 0:
                break
            if not _ignorable(nbr, deg, u, v_pusher, occ_now, goals):
                m += 1
                tmp = u
        if m >= 2:
            return False   # room to step aside
        if m <= 0:
            break
        v_pusher = v_puller
        v_puller = tmp
    return dq[v_pusher] < dq[v_puller] and (dp[v_pusher] == 0 or dp[v_puller] < dp[v_pusher])


@njit(cache=True)
def _swap_possible(v_pusher_origin: int, v_puller_origin: int, nbr, deg, occ_now, goals) -> bool:
    """Simulates pulling: True when the corridor behind opens onto a cell with a side exit."""
    v_pusher = v_pusher_origin
    v_puller = v_puller_origin
    tmp = -1
    steps = 0
    while v_puller != v_pusher_origin and steps < nbr.shape[0]:
        steps += 1
        m = 0
        for j in range(nbr.shape[1]):
            u = nbr[v_puller, j]
            if u < 0:
                break
            if not _ignorable(nbr, deg, u, v_pusher, occ_now, goals):
                m += 1
                tmp = u
        if m >= 2:
            return True
        if m <= 0:
            return False
        v_pusher = v_puller
        v_puller = tmp
    return False


@njit(cache=True)
def _swap_agent(i: int, best: int, q_from, q_to, nbr, deg, dist, rows, occ_now, goals) -> int:
    """LaCAM3's swap technique (Okumura, AAMAS 2024): the robot i should pull rather than push,
    or -1. `best` is i's preferred next cell."""
    v = q_from[i]
    if best == v:
        return -1
    j = occ_now[best]
    if j >= 0 and q_to[j] < 0 and _swap_required(i, j, v, best, nbr, deg, dist, rows, occ_now, goals) \
            and _swap_possible(best, v, nbr, deg, occ_now, goals):
        return j
    for m in range(nbr.shape[1]):
        u = nbr[v, m]
        if u < 0:
            break
        k = occ_now[u]
        if k < 0 or best == q_from[k]:
            continue
        if _swap_required(k, i, v, best, nbr, deg, dist, rows, occ_now, goals) \
                and _swap_possible(best, v, nbr, deg, occ_now, goals):
            return k
    return -1


@njit(cache=True)
def _open_frame(d: int, i: int, nbr, deg, dist, rows, goals, q_from, q_to, occ_now, st_agent, st_pos, st_nc,
                st_cand, st_swap, rng, swap: bool, pref) -> None:
    st_agent[d] = i
    st_pos[d] = 0
    m = _candidates(nbr, dist[rows[i]], q_from[i], occ_now, st_cand[d], rng, pref[i])
    st_nc[d] = m
    st_swap[d] = -1
    if swap:
        j = _swap_agent(i, st_cand[d, 0], q_from, q_to, nbr, deg, dist, rows, occ_now, goals)
        if j >= 0:
            st_swap[d] = j
            for a in range(m // 2):    # move away from the robot to pull
                tmp = st_cand[d, a]
                st_cand[d, a] = st_cand[d, m - 1 - a]
                st_cand[d, m - 1 - a] = tmp


@njit(cache=True)
def _pibt(root: int, nbr, deg, dist, rows, goals, q_from, q_to, occ_now, occ_nxt, xs, ys, index, width: int,
          diagonal: bool, swap: bool, st_agent, st_pos, st_nc, st_cand, st_swap, rng, pref) -> bool:
    """PIBT's recursive call for `root`, written with an explicit stack (recursion depth can reach n)."""
    _open_frame(0, root, nbr, deg, dist, rows, goals, q_from, q_to, occ_now, st_agent, st_pos, st_nc, st_cand,
                st_swap, rng, swap, pref)
    d = 1
    result = -1          # -1: nothing returned yet, 0: child failed, 1: child succeeded
    while d > 0:
        top = d - 1
        i = st_agent[top]
        if result == 0:
            st_pos[top] += 1
        if result != 1:
            result = -1
            pushed = False
            while st_pos[top] < st_nc[top]:
                v = st_cand[top, st_pos[top]]
                if occ_nxt[v] >= 0:
                    st_pos[top] += 1
                    continue
                j = occ_now[v]
                if j >= 0 and j != i and q_to[j] == q_from[i]:
                    st_pos[top] += 1
                    continue  # would swap with j
                if diagonal and _crosses(q_from[i], v, q_to, occ_now, xs, ys, index, width):
                    st_pos[top] += 1
                    continue
                q_to[i] = v
                occ_nxt[v] = i
                if j >= 0 and j != i and q_to[j] < 0:
                    _open_frame(d, j, nbr, deg, dist, rows, goals, q_from, q_to, occ_now, st_agent, st_pos,
                                st_nc, st_cand, st_swap, rng, swap, pref)
                    d += 1
                    pushed = True
                break
            if pushed:
                continue
            if st_pos[top] >= st_nc[top]:
                q_to[i] = q_from[i]
                occ_nxt[q_from[i]] = i
                result = 0
                d -= 1
                continue
        # success for i: pull the swap partner into the cell i leaves
        s = st_swap[top]
        if st_pos[top] == 0 and s >= 0 and q_to[s] < 0 and occ_nxt[q_from[i]] < 0 \
                and not (diagonal and _crosses(q_from[s], q_from[i], q_to, occ_now, xs, ys, index, width)):
            q_to[s] = q_from[i]
            occ_nxt[q_from[i]] = s
        result = 1
        d -= 1
    return result == 1


@njit(cache=True)
def pibt_step(nbr, deg, dist, rows, goals, q_from, q_to, order, occ_now, occ_nxt, xs, ys, index, width: int,
              diagonal: bool, swap: bool, st_agent, st_pos, st_nc, st_cand, st_swap, rng, pref) -> bool:
    """Fills q_to (entries already >= 0 are fixed constraints, with occ_nxt set for them).

    pref[i] >= 0 is a cell robot i tries first (a guide path's next cell).
    occ_now must map q_from's cells to their robots; occ_now and occ_nxt are
    restored to all -1 before returning. False when a robot cannot move.
    """
    ok = True
    for r in range(order.shape[0]):
        i = order[r]
        if q_to[i] < 0:
            if not _pibt(i, nbr, deg, dist, rows, goals, q_from, q_to, occ_now, occ_nxt, xs, ys, index, width,
                         diagonal, swap, st_agent, st_pos, st_nc, st_cand, st_swap, rng, pref):
                ok = False
                break
    for i in range(q_from.shape[0]):
        if q_to[i] >= 0:
            occ_nxt[q_to[i]] = -1
    return ok


@njit(cache=True)
def update_priorities(prio: np.ndarray, q: np.ndarray, goals: np.ndarray) -> None:
    for i in range(prio.shape[0]):
        if q[i] == goals[i]:
            prio[i] -= np.floor(prio[i])
        else:
            prio[i] += 1.0


@njit(cache=True)
def _run(nbr, deg, dist, rows, starts, goals, prio, xs, ys, index, width: int, diagonal: bool, swap: bool,
         max_steps: int, deadline: float, seed: int):
    """PIBT until every robot is on its goal: (status, configurations [steps+1, n]); status 0 ok,
    1 step cap, 2 time limit."""
    n = nbr.shape[0]
    na = starts.shape[0]
    hist = np.empty((64, na), dtype=np.int32)
    for i in range(na):
        hist[0, i] = starts[i]
    order = np.empty(na, dtype=np.int32)
    occ_now = np.full(n, -1, dtype=np.int32)
    occ_nxt = np.full(n, -1, dtype=np.int32)
    k = nbr.shape[1] + 1
    st_agent = np.empty(na, dtype=np.int32)
    st_pos = np.empty(na, dtype=np.int32)
    st_nc = np.empty(na, dtype=np.int32)
    st_cand = np.empty((na, k), dtype=np.int32)
    st_swap = np.empty(na, dtype=np.int32)
    pref = np.full(na, -1, dtype=np.int32)
    rng = np.array([np.uint64(seed) * np.uint64(2654435761) + np.uint64(88172645463325252)], dtype=np.uint64)
    q_to = np.empty(na, dtype=np.int32)
    t = 0
    while True:
        q_from = hist[t]
        done = True
        for i in range(na):
            if q_from[i] != goals[i]:
                done = False
                break
        if done:
            return 0, hist[:t + 1]
        if t >= max_steps:
            return 1, hist[:t + 1]
        if (t & 63) == 0 and now() > deadline:
            return 2, hist[:t + 1]
        for i in range(na):
            occ_now[q_from[i]] = i
        for i in range(na):
            q_to[i] = -1
        order_by_priority(prio, order)
        pibt_step(nbr, deg, dist, rows, goals, q_from, q_to, order, occ_now, occ_nxt, xs, ys, index, width,
                  diagonal, swap, st_agent, st_pos, st_nc, st_cand, st_swap, rng, pref)
        for i in range(na):
            occ_now[q_from[i]] = -1
        if t + 1 == hist.shape[0]:
            bigger = np.empty((2 * hist.shape[0], na), dtype=np.int32)
            for r in range(t + 1):
                for i in range(na):
                    bigger[r, i] = hist[r, i]
            hist = bigger
        for i in range(na):
            hist[t + 1, i] = q_to[i]
        update_priorities(prio, q_to, goals)
        t += 1


def degrees(nbr: np.ndarray) -> np.ndarray:
    return (nbr >= 0).sum(axis=1).astype(np.int32)


def initial_priorities(inst: Instance) -> np.ndarray:
    """Fractional start priorities: farther robots first, all below 1 so progress dominates."""
    d = inst.start_distances().astype(np.float64)
    return (d / (d.max() + 1.0) if d.size else d).astype(np.float32)


def history_to_paths(inst: Instance, hist: np.ndarray) -> list[Path]:
    """Configurations [steps, n] -> per-robot paths, cut after each robot's last arrival."""
    away = hist != inst.goals[None, :]
    # last step at which each robot is not on its goal; the path runs one step further
    last = np.where(away.any(axis=0), hist.shape[0] - np.argmax(away[::-1], axis=0), 0)
    return inst.to_paths([hist[:last[i] + 1, i] for i in range(inst.n)])


def step_cap(inst: Instance) -> int:
    d = inst.start_distances()
    return int(max(1000, 20 * (int(d.max()) if d.size else 0) + 4 * inst.n))


def pibt(problem: Problem, limits: Limits, swap: bool = True) -> list[Path]:
    """PIBT (with LaCAM3's swap technique unless swap=False); PlanningError when robots are not
    all home after the step cap or time limit."""
    inst = compile_problem(problem)
    if inst.n == 0:
        return []
    nbr, xs, ys, index, width = kernel_args(inst)
    cap = step_cap(inst)
    status, hist = _run(nbr, degrees(nbr), inst.table.dist, inst.rows, inst.starts, inst.goals,
                        initial_priorities(inst), xs, ys, index, width, problem.connectivity == 8, swap, cap,
                        time.perf_counter() + limits.remaining(), problem.seed)
    if status != 0:
        home = int((hist[-1] == inst.goals).sum())
        why = f"{cap} steps" if status == 1 else f"the time limit of {limits.seconds:g} s"
        raise PlanningError(f"pibt: {inst.n - home} of {inst.n} robots not on their goals after {why}"
                            " (PIBT can cycle; use lacam, which is complete)")
    return history_to_paths(inst, hist)
