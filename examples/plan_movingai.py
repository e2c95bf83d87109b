"""Plan a MovingAI benchmark instance through the Python API, then check the plan independently.

    python3 examples/plan_movingai.py                      # warehouse-10-20-10-2-1, random-1, 50 agents
    python3 examples/plan_movingai.py --map room-64-64-8 --scen even-2 --agents 30 --planner prioritized

The same steps as `uav-robots plan --map MAP --scen SCEN --agents N` (uav_robots/plan_cli.py):
read the shipped map and scenario (scenarios/data/movingai), plan with the pipeline every planner
goes through (uav_agent/planning/pipeline.py: distances, assignment, the planner, the validator),
then run the independent validator (uav_agent/planning/validator.py) once more ourselves.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))   # the checkout, even without `pip install -e .`

from protocol.errors import UavRobotsError
from protocol.mapfile import read_scen
from scenarios.maps import resolve_map, shipped_movingai
from uav_agent.planning.build import warm
from uav_agent.planning.build.interpreted import fits, plan_interpreted
from uav_agent.planning.pipeline import plan_mission
from uav_agent.planning.registry import PLANNERS
from uav_agent.planning.types import Problem, makespan, sum_of_costs
from uav_agent.planning.validator import validate


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--map", default="warehouse-10-20-10-2-1", help="a MovingAI map that ships with the project")
    p.add_argument("--scen", default="random-1", help="its scenario: random-1..5 or even-1..5")
    p.add_argument("--agents", type=int, default=50, help="the scenario's first N agents")
    p.add_argument("--planner", default="lacam", choices=list(PLANNERS))
    args = p.parse_args()

    # 1. The instance: the map's free cells (free[y, x]) and each agent's start and goal, as (x, y).
    name, free = resolve_map(args.map)
    scen = shipped_movingai(name, args.scen)
    if scen is None:
        raise UavRobotsError(f"no shipped scenario {args.scen!r} for the map {name!r} (see scenarios/data/movingai)")
    agents = read_scen(scen, free, args.agents)
    starts, goals = [a.start for a in agents], [a.goal for a in agents]
    print(f"{name} ({free.shape[1]}x{free.shape[0]}), scenario {args.scen}: {len(agents)} agents, "
          f"planner {args.planner}")

    # 2. Plan. assign="none": a MovingAI scenario pairs each start with its goal already.
    options = dict(planner=args.planner, assign="none", connectivity=4, time_limit=30.0)
    t0 = time.perf_counter()
    result = None
    if not warm.is_warm() and fits(free, len(starts), len(goals)):
        # A fresh clone has not compiled the planners' numba kernels yet (about 45 s): as the CLI does,
        # run the very same pipeline with the kernels interpreted, in a child process (same plan).
        print("(the planners' kernels are not compiled yet: planning with them interpreted)")
        try:
            result = plan_interpreted(free, starts, goals, **options)
        except RuntimeError:          # the child could not run: the compiled kernels will
            pass
    if result is None:
        result = plan_mission(free, starts, goals, **options)
    seconds = time.perf_counter() - t0

    # 3. Check it ourselves. The pipeline validated it already; the validator shares no code with
    #    any planner, so a planner's bug cannot hide in it. An empty list means a valid plan.
    problem = Problem(free=free, starts=result.starts, goals=result.goals, connectivity=result.connectivity)
    violations = validate(problem, result.paths)
    if violations:
        raise UavRobotsError(f"the plan is invalid: {violations[0].text} ({len(violations)} violations)")
    print(f"validated: {len(result.paths)} paths, no vertex, swap or obstacle conflict")
    print(f"planner {result.planner}{' (fell back from ' + result.requested + ')' if result.fell_back else ''}: "
          f"makespan {makespan(result.paths, result.goals)}, sum of costs {sum_of_costs(result.paths, result.goals)} "
          f"(lower bound {result.metrics['lower_bound']}), planned in {seconds:.2f} s")
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except UavRobotsError as exc:     # bad input, no plan found, an invalid plan: one line, exit 1
        sys.exit(f"plan_movingai: {exc}")
