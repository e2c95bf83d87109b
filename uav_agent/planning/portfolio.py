"""The default planner: prioritized planning first, then LaCAM guided by its paths, then LaCAM on scatter's routes.

`lacam(problem, limits)` is the fast default: on sparse instances it first
tries prioritized planning (near-optimal and cheap when robots rarely meet),
in a few orders if the first leaves robots unrouted; if none routes them all,
LaCAM (`mapf/lacam.py`) runs with the first pass's paths as guides for PIBT, and on a floor too
crowded for that, with scatter's routes (`mapf/scatter.py`). `refine` (`mapf/refine.py`)
can improve a plan further; it is not part of `lacam` because, measured on
LaCAM's plans for crowded warehouses, it won under 1 % of the sum of costs for
as much time again as the search.
"""
from __future__ import annotations

import time

import numpy as np

from protocol.errors import PlanningError, PlanningTimeout

from .mapf.distances import Instance, compile_problem
from .mapf.lacam import search
from .mapf.pibt import history_to_paths, pibt
from .mapf.prioritized import first_then_shortest, guide_paths, max_expansions, plan_prioritized, split_paths
from .mapf.refine import refine, trimmed
from .mapf.scatter import routes
from .types import Limits, Path, Problem


# Robots are first routed one by one (prioritized planning, skipping those it cannot route)
# when they are sparse enough for that to pay: on warehouse-10-20-10-2-1, 400 robots (7 % of
# the cells) take 0.3-0.7 s that way for a sum of costs 8-30 % above the lower bound, against
# 0.1-0.2 s and 80 % for LaCAM alone; at 600 robots (10 %) it takes 3 s and gains nothing.
GUIDE_DENSITY = 0.075
GUIDE_SHARE = 0.1              # at most this share of the time limit goes to the guide paths
# A pass that leaves robots unrouted is tried again with them first, a few orders at most:
# where that routes everyone, its plan costs less than LaCAM's guided by the first pass (on
# the crowded MovingAI floors 0.3-14 % less, 1.12 against 1.31 SoC/LB at worst).
RETRY_ORDERS = 8
RETRY_FACTOR = 2.0             # ... within this many times the first pass's time, GUIDED_MIN at least
GUIDED_FACTOR = 2.0            # a guided LaCAM search gets this many times the guides' time ...
GUIDED_MIN = 0.5               # ... but at least this many seconds, before LaCAM runs on scatter's routes
# Scatter's routes settle in about a second up to a thousand robots; 10,000 on
# warehouse-20-40-10-2-2 take about 7 s a round: its share of the time limit keeps the search's.
SCATTER_SHARE = 0.4


def lacam(problem: Problem, limits: Limits) -> list[Path]:
    """The default planner: complete, fast, near-optimal on sparse instances.

    1. guide paths: one prioritized pass (with local repairs) when robots are sparse; when
       it routes every robot, that is the plan; when not, a few more orders with the robots it
       left unrouted first, and the first that routes everyone is the plan;
    2. otherwise LaCAM, its PIBT steered by the guide paths of the robots that were routed,
       or, when too dense for them (or they led nowhere), by scatter's routes (`scatter.py`);
       either way LaCAM stays complete.
    The result depends only on the problem and its seed, not on the machine's speed (unless
    a time budget runs out: scatter's too, on a large crowded instance). `refine` can
    improve a LaCAM plan further, given time.
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
            routed = _reordered(inst, np.flatnonzero(plen == 0), limits,
                                max(GUIDED_MIN, RETRY_FACTOR * (time.perf_counter() - began)))
            if routed is not None:
                return routed
            # guides can also lead PIBT astray: give the guided search a bounded try
            budget = min(limits.remaining() / 2, max(GUIDED_MIN, GUIDED_FACTOR * (time.perf_counter() - began)))
            try:
                return history_to_paths(inst, search(inst, Limits(budget), guides=(buf, poff, plen)))
            except PlanningError:
                if limits.expired():
                    raise
    found = routes(inst, SCATTER_SHARE * min(limits.seconds, limits.remaining()))
    return history_to_paths(inst, search(inst, limits, routes=None if found is None else found[:2]))


def _reordered(inst: Instance, unrouted: np.ndarray, limits: Limits, seconds: float) -> list[Path] | None:
    """Prioritized planning from the order that puts the `unrouted` robots first (then its
    restarts), within `seconds`: the plan, or None."""
    try:
        ok, buf, poff, plen, _, _ = plan_prioritized(inst, Limits(min(limits.remaining() / 2, seconds)),
                                                     RETRY_ORDERS, first_then_shortest(inst, unrouted))
    except PlanningTimeout:
        return None
    return split_paths(inst, buf, poff, plen) if ok else None


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
            buf, poff, plen = trimmed(inst, search(inst, Limits(600.0), routes=routes(inst, 600.0)[:2]))
            if "refine" in parts:
                refine(inst, buf, poff, plen, 0.001)
        if "pibt" in parts:
            pibt(problem, Limits(600.0))
    return time.perf_counter() - began
