"""A new multi-robot planner in about 30 lines: prioritized planning with a space-time A*, checked by the validator.

    python3 examples/new_planner.py                       # 20 agents of MovingAI random-32-32-20, random-1
    python3 examples/new_planner.py --agents 40 --scen random-2

A planner is a plain function `planner(problem: Problem, limits: Limits) -> list[Path]`
(uav_agent/planning/types.py): one path per robot, paths[i][t] the cell (x, y) of robot i at step t,
from its start to its goal, where it then stays. It calls `limits.check(...)` in its loops so it never
hangs and raises PlanningError (one line) when it finds no plan. Registering it is one row in `SPECS`
of uav_agent/planning/registry.py (`PlannerSpec("my-planner", "mapf.my_module", "my_function")`, the
module under uav_agent/planning/); from then on `--planner my-planner` works in `uav-robots plan` and `run`. Here it
stays a function of its own, called as the registry's planners are and checked by the same validator.
"""
from __future__ import annotations

import argparse
import heapq
import sys
import time
from pathlib import Path as FsPath

sys.path.insert(0, str(FsPath(__file__).resolve().parents[1]))   # the checkout, even without `pip install -e .`

from protocol.errors import PlanningError, UavRobotsError
from protocol.mapfile import read_scen
from scenarios.maps import resolve_map, shipped_movingai
from uav_agent.planning.build import warm
from uav_agent.planning.registry import get_planner
from uav_agent.planning.types import Cell, Limits, Path, Problem, makespan, sum_of_costs
from uav_agent.planning.validator import validate


def space_time_astar(problem: Problem, start: Cell, goal: Cell, at: dict, parked: dict, last_visit: dict,
                     horizon: int, limits: Limits) -> Path:
    """A* over (cell, step): moves to the 4 neighbours or waits, never where or when a planned robot is
    (`at`: (cell, step) -> robot; `parked`: cell -> step from which a robot stays there for good), never
    swapping with one, and ends on `goal` only once no planned robot passes there later (`last_visit`)."""
    h, w = problem.free.shape
    dist = lambda c: abs(c[0] - goal[0]) + abs(c[1] - goal[1])             # admissible: Manhattan distance
    frontier, came = [(dist(start), 0, start)], {(start, 0): None}
    while frontier:
        limits.check(f"space-time A* from {start} to {goal}")
        _, t, (x, y) = heapq.heappop(frontier)
        if (x, y) == goal and last_visit.get(goal, -1) < t:
            path, node = [], ((x, y), t)
            while node is not None:                                         # walk back to the start
                path.append(node[0])
                node = came[node]
            return path[::-1]
        for n in ((x, y), (x + 1, y), (x - 1, y), (x, y + 1), (x, y - 1)):
            if (t >= horizon or not (0 <= n[0] < w and 0 <= n[1] < h) or not problem.free[n[1], n[0]]
                    or (n, t + 1) in came or (n, t + 1) in at or parked.get(n, horizon + 1) <= t + 1
                    or (n != (x, y) and (n, t) in at and at.get(((x, y), t + 1)) == at[(n, t)])):   # a swap
                continue
            came[(n, t + 1)] = ((x, y), t)
            heapq.heappush(frontier, (t + 1 + dist(n), t + 1, n))
    raise PlanningError(f"no path from {start} to {goal} around the robots planned before it within {horizon} steps")


def prioritized_astar(problem: Problem, limits: Limits) -> list[Path]:
    """Robots one after another, in id order, each around every robot planned before it."""
    if problem.connectivity != 4:
        raise PlanningError("prioritized_astar moves 4-connected only")
    at, parked, last_visit, paths = {}, {}, {}, []
    for i, (start, goal) in enumerate(zip(problem.starts, problem.goals)):
        horizon = max(map(len, paths), default=0) + int(problem.free.sum())
        try:
            path = space_time_astar(problem, start, goal, at, parked, last_visit, horizon, limits)
        except PlanningError as exc:
            raise PlanningError(f"prioritized_astar: robot {i}: {exc}") from None
        for t, cell in enumerate(path):                                     # reserve its cells, step by step
            at[(cell, t)] = i
            last_visit[cell] = max(last_visit.get(cell, -1), t)
        parked[goal] = len(path) - 1
        paths.append(path)
    return paths


def report(name: str, problem: Problem, paths: list[Path], seconds: float) -> bool:
    """Validate `paths` with the project's independent validator; print the verdict and the costs."""
    violations = validate(problem, paths)
    verdict = "valid" if not violations else f"INVALID, {len(violations)} violations, first: {violations[0].text}"
    print(f"{name:<42} {verdict}; makespan {makespan(paths, problem.goals)}, "
          f"sum of costs {sum_of_costs(paths, problem.goals)}, {seconds:.3f} s")
    return not violations


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--map", default="random-32-32-20", help="a MovingAI map that ships with the project")
    ap.add_argument("--scen", default="random-1")
    ap.add_argument("--agents", type=int, default=20)
    args = ap.parse_args()
    name, free = resolve_map(args.map)
    scen = shipped_movingai(name, args.scen)
    if scen is None:
        raise UavRobotsError(f"no shipped scenario {args.scen!r} for the map {name!r}")
    agents = read_scen(scen, free, args.agents)
    problem = Problem(free=free, starts=[a.start for a in agents], goals=[a.goal for a in agents])
    print(f"{name}, scenario {args.scen}: {problem.n} robots, 4-connected")

    # 1. Each robot alone on the floor (no reservations): shortest paths, which collide. The validator says where.
    t0 = time.perf_counter()
    alone = [space_time_astar(problem, s, g, {}, {}, {}, 10_000, Limits(10)) for s, g in zip(problem.starts, problem.goals)]
    report("each robot alone (not a MAPF plan)", problem, alone, time.perf_counter() - t0)

    # 2. The new planner, called as the registry's planners are: planner(problem, limits).
    t0 = time.perf_counter()
    paths = prioritized_astar(problem, Limits(seconds=20.0))
    ok = report("prioritized_astar (this example)", problem, paths, time.perf_counter() - t0)

    # 3. A registered planner on the same problem, for comparison (once numba's kernels are compiled).
    if warm.is_warm():
        t0 = time.perf_counter()
        theirs = get_planner("prioritized")(problem, Limits(seconds=20.0))
        report("registered 'prioritized' (with its import)", problem, theirs, time.perf_counter() - t0)
    if not ok:
        raise UavRobotsError("the new planner's plan is invalid")
    print("the new planner's plan passed the independent validator")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except UavRobotsError as exc:       # no plan found (PlanningError), bad input, an invalid plan
        sys.exit(f"new_planner: {exc}")
