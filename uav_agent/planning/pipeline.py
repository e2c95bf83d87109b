"""The planning pipeline: checked input -> distances -> assignment -> paths -> validated plan.

`plan_mission` is what the UAV agent, `uav-robots plan` and the benchmark call;
every result it returns has passed the independent validator.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from protocol.errors import PlanningError
from protocol.grid import on_grid

from .assignment import DEFAULT_ASSIGNMENT, check_mode
from .assignment import assign as assign_goals
from .mapf.distances import cost_matrix
from .registry import DEFAULT_PLANNER, SPECS, check_name, get_planner, is_complete
from .types import Cell, Limits, Path, Problem, makespan, sum_of_costs
from .validator import check


@dataclass
class PlanResult:
    starts: list[Cell]                 # robot i starts at starts[i]
    goals: list[Cell]                  # the goal assigned to robot i
    assignment: list[int]              # goals[i] == input goals[assignment[i]]
    paths: list[Path]                  # validated; paths[i][t] = cell of robot i at step t
    planner: str                       # the planner whose paths these are
    requested: str                     # the planner asked for (differs after a fallback)
    assign: str
    connectivity: int
    fell_back: bool = False
    notes: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)   # seconds per phase and "total"
    metrics: dict[str, float] = field(default_factory=dict)   # sum_of_costs, makespan, lower_bound, ...


def _check_cells(free: np.ndarray, cells: list[Cell], what: str) -> list[Cell]:
    h, w = free.shape
    out: list[Cell] = []
    seen: dict[Cell, int] = {}
    for i, c in enumerate(cells):
        try:
            x, y = (int(v) for v in c)
        except (TypeError, ValueError):
            raise PlanningError(f"{what} {i} is {c!r}, not an (x, y) cell") from None
        if not on_grid(x, y, w, h):
            raise PlanningError(f"{what} {i} ({x}, {y}) is off the {w}x{h} grid")
        if not free[y, x]:
            raise PlanningError(f"{what} {i} ({x}, {y}) is on an obstacle")
        if (x, y) in seen:
            raise PlanningError(f"{what}s {seen[(x, y)]} and {i} are both at ({x}, {y})")
        seen[(x, y)] = i
        out.append((x, y))
    return out


def _check_input(free, starts, goals, planner, assign, connectivity, time_limit):
    if not isinstance(free, np.ndarray) or free.ndim != 2 or free.size == 0:
        raise PlanningError("the grid must be a non-empty 2-D array free[y, x]")
    check_mode(assign)
    if connectivity not in (4, 8):
        raise PlanningError(f"connectivity must be 4 or 8, got {connectivity!r}")
    if not time_limit > 0:
        raise PlanningError(f"the time limit must be positive, got {time_limit!r}")
    check_name(planner)
    free = np.asarray(free, dtype=bool)
    starts = _check_cells(free, starts, "start")
    goals = _check_cells(free, goals, "goal")
    if not starts:
        raise PlanningError("no robots to plan for")
    if len(goals) < len(starts) or (len(goals) != len(starts) and assign == "none"):
        raise PlanningError(f"{len(starts)} robots but {len(goals)} goals: " + (
            "every robot needs its own goal" if len(goals) < len(starts) else "with --assign none the counts must match"))
    return free, starts, goals


# Refinement keeps every robot's start and goal and only shortens arrivals: any planner's
# conflict-free plan is a valid start, but the paper's pipelines are meant to be shown as they are.
REFINABLE = frozenset(s.name for s in SPECS if s.refinable)


def _run(name: str, problem: Problem, limits: Limits) -> list[Path]:
    paths = get_planner(name)(problem, limits)
    return [[(int(x), int(y)) for x, y in p] for p in paths]


def plan_mission(free: np.ndarray, starts: list[Cell], goals: list[Cell], *,
                 planner: str = DEFAULT_PLANNER, assign: str = DEFAULT_ASSIGNMENT, connectivity: int = 4,
                 time_limit: float = 60.0, fallback: bool = True, seed: int = 0,
                 refine_s: float = 0.0) -> PlanResult:
    """Assign goals to robots and plan collision-free paths, within `time_limit` seconds in all.

    assign: "optimal" (min sum of true distances), "bottleneck" (min longest, then min sum),
    "bruteforce" (the paper: all permutations, Euclidean costs, n <= 9), "none" (robot i -> goals[i]).
    fallback: when a planner other than the default fails (the paper's priority waits
    cannot resolve a conflict, PIBT livelocks, ...) or returns an invalid plan, the default
    planner solves the same assignment and a note says why; False re-raises.
    refine_s: then up to this many seconds (within the time limit) of large-neighbourhood search
    (`mapf/refine.py`) on the plan, which is validated again; done at once when nothing is delayed.
    """
    limits = Limits(time_limit)
    t0 = time.perf_counter()
    timings: dict[str, float] = {}
    free, starts, goals = _check_input(free, starts, goals, planner, assign, connectivity, time_limit)
    n = len(starts)

    t = time.perf_counter()
    cost = np.asarray(cost_matrix(free, starts, goals, connectivity), dtype=float)
    timings["distances"] = time.perf_counter() - t
    limits.check("distances")

    t = time.perf_counter()
    order = assign_goals(assign, cost, starts, goals)
    timings["assignment"] = time.perf_counter() - t
    assigned = [goals[j] for j in order]
    lower_bound = float(cost[np.arange(n), order].sum())
    limits.check("assignment")

    problem = Problem(free=free, starts=starts, goals=assigned, connectivity=connectivity, seed=seed)
    notes: list[str] = []
    used, fell_back = planner, False
    t = time.perf_counter()
    validation = 0.0
    try:
        paths = _run(planner, problem, limits)
        tv = time.perf_counter()
        try:
            check(problem, paths)
        finally:
            validation += time.perf_counter() - tv
    except PlanningError as exc:
        # A time-out is not the method's fault and leaves no time for another planner.
        may_fall_back = fallback and not is_complete(planner) and not limits.expired()
        if not may_fall_back:
            raise
        notes.append(f"{planner} failed ({exc}); fell back to {DEFAULT_PLANNER}")
        used, fell_back = DEFAULT_PLANNER, True
        paths = _run(DEFAULT_PLANNER, problem, limits)
        tv = time.perf_counter()
        check(problem, paths)
        validation += time.perf_counter() - tv
    timings["planning"] = time.perf_counter() - t - validation
    refined: dict[str, float] = {}
    if refine_s > 0 and used in REFINABLE:
        from .mapf.refine import improve

        t = time.perf_counter()
        before = sum_of_costs(paths, assigned)
        better, rounds = improve(problem, paths, min(refine_s, limits.remaining()))
        tv = time.perf_counter()
        check(problem, better)   # a refinement is checked like any plan
        validation += time.perf_counter() - tv
        timings["refinement"] = tv - t
        if sum_of_costs(better, assigned) <= before:
            paths = better
        refined = {"initial_sum_of_costs": before, "refine_rounds": rounds}
    timings["validation"] = validation
    timings["total"] = time.perf_counter() - t0

    soc = sum_of_costs(paths, assigned)
    metrics = {
        **refined,
        "robots": n,
        "sum_of_costs": soc,
        "makespan": makespan(paths, assigned),
        "lower_bound": int(lower_bound) if lower_bound.is_integer() else lower_bound,
        "soc_over_lb": soc / lower_bound if lower_bound > 0 else 1.0,
    }
    return PlanResult(starts=starts, goals=assigned, assignment=order, paths=paths, planner=used,
                      requested=planner, assign=assign, connectivity=connectivity, fell_back=fell_back,
                      notes=notes, timings=timings, metrics=metrics)
