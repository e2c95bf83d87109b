"""PIBT, Priority Inheritance with Backtracking (Okumura, Machida, Défago & Tamura,
"Priority Inheritance with Backtracking for Iterative Multi-agent Path Finding",
IJCAI 2019 / Artificial Intelligence 2022), with LaCAM3's swap technique (Okumura,
"Engineering LaCAM*: Towards Real-Time, Large-Scale, and Near-Optimal Multi-Agent
Pathfinding", AAMAS 2024).

One step at a time, robots in priority order pick their next cell by distance
to goal; a robot that wants an occupied cell lends its priority to the
occupant, which must then move away first (recursively), or the move is
dropped (backtracking). Vertex and swap conflicts (and crossing diagonals in
8-connectivity) are excluded by construction. A robot's priority grows while
it is away from its goal and falls back to its fractional start value once
there. Without the swap technique robots meeting head-on in 1-wide aisles
livelock; with it a robot that would have to push another back down a
corridor pulls it through instead. PIBT alone can still cycle forever, so
`pibt` gives up with a PlanningError after a step cap or the time limit;
`lacam.py` uses `pibt_step` as its configuration generator and is complete.

A plain-Python reading copy of PIBT, without the swap technique: `planning/reference/pibt.py`.
"""
from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
from ..compile.jit import njit

from protocol.errors import PlanningError

from .distances import Instance, compile_problem
from .grid_kernels import (
    Geometry,
    Grid,
    corners,
    grid_of,
    grow_rows,
    is_diagonal,
    now,
    order_by_priority,
    rand_next,
)
from ..types import Limits, Path, Problem


class Pibt(NamedTuple):
    """PIBT's working arrays, kept from step to step."""
    occ_now: np.ndarray       # int32 [n]: the robot on each cell of Q_from, or -1
    occ_nxt: np.ndarray       # int32 [n]: the robot that has taken each cell in Q_to, or -1
    # funcPIBT's calls on an explicit stack (a chain of pushes can involve every robot):
    agent: np.ndarray         # int64 [robots]: the robot of each frame,
    pos: np.ndarray           # int32 [robots]: which of its candidates it tries,
    ncand: np.ndarray         # int32 [robots]: how many it has,
    cand: np.ndarray          # int32 [robots, k + 1]: its candidate cells, best first,
    swap: np.ndarray          # int64 [robots]: the robot it pulls along (LaCAM3's swap), or -1
    pref: np.ndarray          # int32 [robots]: a cell the robot tries first (a guide path's next), or -1
    rng: np.ndarray           # uint64 [1]: xorshift state for the tie-breaking
    use_swap: bool


@njit(cache=True, inline='always')
def new_pibt(g: Grid, seed: int, use_swap: bool) -> Pibt:
    n = g.nbr.shape[0]
    na = g.starts.shape[0]
    # the maps per cell are int32 to stay in cache; robot ids elsewhere are int64, as in the
    # other kernels: a callee that sees an argument as int32 here and int64 there is compiled twice
    return Pibt(np.full(n, -1, dtype=np.int32), np.full(n, -1, dtype=np.int32), np.empty(na, dtype=np.int64),
                np.empty(na, dtype=np.int32), np.empty(na, dtype=np.int32),
                np.empty((na, g.nbr.shape[1] + 1), dtype=np.int32), np.empty(na, dtype=np.int64),
                np.full(na, -1, dtype=np.int32),
                np.array([np.uint64(seed) * np.uint64(2654435761) + np.uint64(88172645463325252)], dtype=np.uint64),
                use_swap)


# The helpers below run per candidate cell or per corridor step, so they take arrays rather
# than structures (see grid_kernels on why).

@njit(cache=True)
def crosses(geo: Geometry, u: int, v: int, q_to, occ_now) -> bool:
    """Whether the diagonal move u -> v crosses an already chosen diagonal move (callers test
    geo.diagonal first: on a 4-connected grid the call per candidate cell would be wasted)."""
    if not is_diagonal(geo, u, v):
        return False
    p, q = corners(geo, u, v)
    j = occ_now[p]
    if j >= 0 and q_to[j] == q:
        return True
    j = occ_now[q]
    return bool(j >= 0 and q_to[j] == p)


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


# ---- LaCAM3's swap: walk the corridor ahead to see whether pushing can work ----

@njit(cache=True)
def _escapes(nbr, goals, occ_now, v: int, v_pusher: int) -> tuple:
    """How many neighbours of v a robot driven on from v_pusher could step into, and the last
    of them. The pusher's cell does not count, nor a dead end where a robot sits on its goal
    (a cell whose neighbour list, padded with -1 at the end, stops after one)."""
    m = 0
    last = np.int32(-1)     # a cell id, int32 like the others (see new_pibt)
    for j in range(nbr.shape[1]):
        u = nbr[v, j]
        if u < 0:
            break
        if u == v_pusher:
            continue
        a = occ_now[u]
        if nbr[u, 1] < 0 and a >= 0 and goals[a] == u:     # u's only neighbour is v
            continue
        m += 1
        last = u
    return m, last


@njit(cache=True)
def _swap_required(nbr, goals, occ_now, dp, dq, v_pusher: int, v_puller: int) -> bool:
    """Simulates the pusher (distances to its goal dp) driving the puller (dq) ahead along a
    corridor: True when they would have to exchange places (no side cell to step aside into
    before the pusher's way ends)."""
    steps = 0
    while dp[v_puller] < dp[v_pusher] and steps < nbr.shape[0]:
        steps += 1
        m, nxt = _escapes(nbr, goals, occ_now, v_puller, v_pusher)
        if m >= 2:
            return False   # room to step aside
        if m <= 0:
            break
        v_pusher = v_puller
        v_puller = nxt
    return dq[v_pusher] < dq[v_puller] and (dp[v_pusher] == 0 or dp[v_puller] < dp[v_pusher])


@njit(cache=True)
def _swap_possible(nbr, goals, occ_now, v_pusher_origin: int, v_puller_origin: int) -> bool:
    """Simulates pulling: True when the corridor behind opens onto a cell with a side exit."""
    v_pusher = v_pusher_origin
    v_puller = v_puller_origin
    steps = 0
    while v_puller != v_pusher_origin and steps < nbr.shape[0]:
        steps += 1
        m, nxt = _escapes(nbr, goals, occ_now, v_puller, v_pusher)
        if m >= 2:
            return True
        if m <= 0:
            return False
        v_pusher = v_puller
        v_puller = nxt
    return False


@njit(cache=True)
def _must_swap(nbr, goals, occ_now, dp, dq, v: int, best: int) -> bool:
    """The swap technique's test for a robot (distances dp) at v heading for `best`, where the
    other robot (dq) is in the way or behind: pushing fails, pulling works."""
    return _swap_required(nbr, goals, occ_now, dp, dq, v, best) \
        and _swap_possible(nbr, goals, occ_now, best, v)


@njit(cache=True)
def _swap_agent(nbr, goals, dist, rows, occ_now, i: int, best: int, q_from, q_to) -> int:
    """The robot that i should pull rather than push, or -1. `best` is i's preferred next cell."""
    v = q_from[i]
    if best == v:
        return -1
    j = occ_now[best]
    if j >= 0 and q_to[j] < 0 and _must_swap(nbr, goals, occ_now, dist[rows[i]], dist[rows[j]], v, best):
        return j
    for m in range(nbr.shape[1]):
        u = nbr[v, m]
        if u < 0:
            break
        k = occ_now[u]
        if k < 0 or best == q_from[k]:
            continue
        if _must_swap(nbr, goals, occ_now, dist[rows[k]], dist[rows[i]], v, best):
            return k
    return -1


# ---- funcPIBT ----

@njit(cache=True)
def _pibt(g: Grid, w: Pibt, root: int, q_from, q_to) -> bool:
    """funcPIBT(root, ⊥): robot i takes its best candidate v that is free in Q_to and neither
    swaps with nor crosses a chosen move; a robot j on v that has no next cell yet inherits
    i's priority and must move first (funcPIBT(j, i)); if it cannot, i tries its next
    candidate; with none left i stays and fails."""
    # the arrays as locals, and helpers that take arrays: this loop runs per frame, and a call
    # with g and w would count references to each of their arrays (see grid_kernels)
    nbr, geo, goals, dist, rows = g.nbr, g.geo, g.goals, g.dist, g.rows
    agent, pos, ncand, cand, swap = w.agent, w.pos, w.ncand, w.cand, w.swap
    occ_now, occ_nxt, pref, rng = w.occ_now, w.occ_nxt, w.pref, w.rng
    d = 0
    call = root          # the robot whose call opens next, or -1
    result = -1          # of the frame just closed: -1 none, 0 failed, 1 succeeded
    while True:
        if call >= 0:
            # open frame d: the candidate cells, reversed (to move away from the robot to
            # pull) when the swap technique says so
            agent[d] = call
            pos[d] = 0
            m = _candidates(nbr, dist[rows[call]], q_from[call], occ_now, cand[d], rng, pref[call])
            ncand[d] = m
            swap[d] = -1
            if w.use_swap:
                j = _swap_agent(nbr, goals, dist, rows, occ_now, call, cand[d, 0], q_from, q_to)
                if j >= 0:
                    swap[d] = j
                    for a in range(m // 2):
                        tmp = cand[d, a]
                        cand[d, a] = cand[d, m - 1 - a]
                        cand[d, m - 1 - a] = tmp
            d += 1
            call = -1
            result = -1
        if d == 0:
            return result == 1
        top = d - 1
        i = agent[top]
        if result == 0:
            pos[top] += 1
        if result != 1:
            v = -1
            j = -1
            while pos[top] < ncand[top]:
                v = cand[top, pos[top]]
                j = occ_now[v]
                if occ_nxt[v] < 0 and not (j >= 0 and j != i and q_to[j] == q_from[i]) \
                        and not (geo.diagonal and crosses(geo, q_from[i], v, q_to, occ_now)):
                    break
                pos[top] += 1
            if pos[top] >= ncand[top]:
                q_to[i] = q_from[i]
                occ_nxt[q_from[i]] = i
                result = 0
                d -= 1
                continue
            q_to[i] = v
            occ_nxt[v] = i
            if j >= 0 and j != i and q_to[j] < 0:
                call = j
                continue
        # i succeeded; if with its first choice, it pulls its swap partner into the cell it leaves
        s = swap[top]
        if pos[top] == 0 and s >= 0 and q_to[s] < 0 and occ_nxt[q_from[i]] < 0 \
                and not (geo.diagonal and crosses(geo, q_from[s], q_from[i], q_to, occ_now)):
            q_to[s] = q_from[i]
            occ_nxt[q_from[i]] = s
        result = 1
        d -= 1


@njit(cache=True)
def pibt_step(g: Grid, w: Pibt, q_from, q_to, order) -> bool:
    """Fills q_to by funcPIBT for each robot in `order` that has no cell yet (entries already
    >= 0 are fixed constraints, with occ_nxt set for them).

    w.occ_now must map q_from's cells to their robots; w.occ_nxt is restored to all -1
    before returning. False when a robot cannot move.
    """
    ok = True
    for r in range(order.shape[0]):
        i = order[r]
        if q_to[i] < 0 and not _pibt(g, w, i, q_from, q_to):
            ok = False
            break
    for i in range(q_from.shape[0]):
        if q_to[i] >= 0:
            w.occ_nxt[q_to[i]] = -1
    return ok


@njit(cache=True, inline='always')
def at_goals(q, goals) -> bool:
    for i in range(q.shape[0]):
        if q[i] != goals[i]:
            return False
    return True


@njit(cache=True)
def update_priorities(prio: np.ndarray, q: np.ndarray, goals: np.ndarray) -> None:
    for i in range(prio.shape[0]):
        if q[i] == goals[i]:
            prio[i] -= np.floor(prio[i])
        else:
            prio[i] += 1.0


@njit(cache=True)
def _run(g: Grid, prio, swap: bool, max_steps: int, deadline: float, seed: int):
    """PIBT until every robot is on its goal: (status, configurations [steps+1, n]); status 0 ok,
    1 step cap, 2 time limit."""
    na = g.starts.shape[0]
    hist = np.empty((64, na), dtype=np.int32)
    for i in range(na):
        hist[0, i] = g.starts[i]
    order = np.empty(na, dtype=np.int64)
    w = new_pibt(g, seed, swap)
    q_to = np.empty(na, dtype=np.int32)
    t = 0
    while True:
        q_from = hist[t]
        if at_goals(q_from, g.goals):
            return 0, hist[:t + 1]
        if t >= max_steps:
            return 1, hist[:t + 1]
        if (t & 63) == 0 and now() > deadline:
            return 2, hist[:t + 1]
        for i in range(na):
            w.occ_now[q_from[i]] = i
            q_to[i] = -1
        order_by_priority(prio, order)
        pibt_step(g, w, q_from, q_to, order)
        for i in range(na):
            w.occ_now[q_from[i]] = -1
        if t + 1 == hist.shape[0]:
            hist = grow_rows(hist, t + 1)
        for i in range(na):
            hist[t + 1, i] = q_to[i]
        update_priorities(prio, q_to, g.goals)
        t += 1


def initial_priorities(inst: Instance) -> np.ndarray:
    """Fractional start priorities: farther robots first, all below 1 so progress dominates."""
    d = inst.start_distances().astype(np.float64)
    return (d / (d.max() + 1.0) if d.size else d).astype(np.float32)


def arrivals(inst: Instance, hist: np.ndarray) -> np.ndarray:
    """The step of each robot's last arrival on its goal in configurations [steps, n]."""
    away = hist != inst.goals[None, :]
    # one after the last step at which the robot is not on its goal
    return np.where(away.any(axis=0), hist.shape[0] - np.argmax(away[::-1], axis=0), 0)


def history_to_paths(inst: Instance, hist: np.ndarray) -> list[Path]:
    """Configurations [steps, n] -> per-robot paths, cut after each robot's last arrival."""
    last = arrivals(inst, hist)
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
    cap = step_cap(inst)
    status, hist = _run(grid_of(inst), initial_priorities(inst), swap, cap, time.perf_counter() + limits.remaining(),
                        problem.seed)
    if status != 0:
        home = int((hist[-1] == inst.goals).sum())
        why = f"{cap} steps" if status == 1 else f"the time limit of {limits.seconds:g} s"
        raise PlanningError(f"pibt: {inst.n - home} of {inst.n} robots not on their goals after {why}"
                            " (PIBT can cycle; use lacam, which is complete)")
    return history_to_paths(inst, hist)
