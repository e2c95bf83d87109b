"""The plain-Python reference planners (uav_agent/planning/reference/) against the numba kernels,
each an oracle of the other on tiny instances: what the algorithms guarantee is compared, not
the tie-breaking they leave open.

- SIPP is optimal: every robot the prioritized kernel routes arrives exactly when the
  reference SIPP, given the robots routed before it, says it can arrive first.
- LaCAM is complete: the reference and the kernel's search find a plan on the same instances
  and report none on the same others, and both plans pass the validator.
- PIBT: where no robot's shortest path is in another's way, both move every robot straight to
  its goal (sum of costs = the lower bound); elsewhere both give valid plans or none.
"""
from __future__ import annotations

import time

import numpy as np
import pytest

from protocol.errors import MapError, PlanningError
from scenarios.maps import place, random_map
from uav_agent.planning.mapf.distances import compile_problem
from uav_agent.planning.mapf.grid_kernels import grid_of
from uav_agent.planning.mapf.lacam import search
from uav_agent.planning.mapf.pibt import history_to_paths
from uav_agent.planning.mapf.pibt import pibt as kernel_pibt
from uav_agent.planning.mapf.prioritized import _plan_in_order, max_expansions, split_paths
from uav_agent.planning.reference.grid import distances_to
from uav_agent.planning.reference.lacam import lacam as reference_lacam
from uav_agent.planning.reference.pibt import pibt as reference_pibt
from uav_agent.planning.reference.sipp import sipp as reference_sipp
from uav_agent.planning.types import Limits, Problem, arrival, makespan, sum_of_costs
from uav_agent.planning.validator import check


def rows(*lines: str) -> np.ndarray:
    return np.array([[c == "." for c in line] for line in lines], dtype=bool)


def tiny_instances(count: int, connectivity: int):
    """Seeded random floors of 2-5 x 2-4 cells with 2-3 robots, skipping those without room for them."""
    rng = np.random.default_rng(connectivity)
    out = []
    while len(out) < count:
        w, h = int(rng.integers(2, 6)), int(rng.integers(2, 5))
        seed = int(rng.integers(0, 10_000))
        free = random_map(w, h, float(rng.uniform(0.0, 0.4)), seed)
        try:
            pl = place(free, int(rng.integers(2, 4)), seed)
        except MapError:
            continue
        out.append(Problem(free, pl.starts, pl.goals, connectivity=connectivity, seed=seed))
    return out


def kernel_search(problem: Problem):
    """LaCAM's search kernel alone: a validated plan, or None when it proves there is none."""
    inst = compile_problem(problem)
    try:
        paths = history_to_paths(inst, search(inst, Limits(30.0)))
    except PlanningError as exc:
        assert "no solution exists" in str(exc)
        return None
    check(problem, paths)
    return paths


@pytest.mark.parametrize("connectivity", [4, 8])
def test_lacam_reference_and_kernel_agree_on_which_instances_have_a_plan(connectivity):
    verdicts = []
    for problem in tiny_instances(40, connectivity):
        ours = reference_lacam(problem, seed=problem.seed)
        if ours is not None:
            check(problem, ours)
        theirs = kernel_search(problem)
        assert (ours is None) == (theirs is None), (problem.free.tolist(), problem.starts, problem.goals)
        verdicts.append(ours is None)
    assert any(verdicts) and not all(verdicts)      # the sample holds instances of both kinds


def test_lacam_reference_passes_a_side_pocket_and_gives_up_in_a_dead_end():
    pocket = Problem(rows(".......", "###.###"), [(0, 0), (6, 0)], [(6, 0), (0, 0)])
    paths = reference_lacam(pocket)
    check(pocket, paths)
    dead_end = Problem(rows("....."), [(0, 0), (4, 0)], [(4, 0), (0, 0)])
    assert reference_lacam(dead_end) is None and kernel_search(dead_end) is None


def kernel_prioritized(problem: Problem, order: list[int]):
    """The prioritized kernel's one pass in `order`: (first robot it could not route or -1, paths)."""
    inst = compile_problem(problem)
    failed, paths = _plan_in_order(grid_of(inst), np.asarray(order, dtype=np.int64), max_expansions(inst),
                                   time.perf_counter() + 30.0, False)
    if failed != -1:
        return failed, None
    return -1, split_paths(inst, paths.buf, paths.off, paths.length)


@pytest.mark.parametrize("connectivity", [4, 8])
@pytest.mark.parametrize("seed", range(6))
def test_every_sipp_arrival_of_the_kernel_is_the_earliest(connectivity, seed):
    free = random_map(12, 9, 0.2, seed)
    pl = place(free, 10, seed)
    problem = Problem(free, pl.starts, pl.goals, connectivity=connectivity, seed=seed)
    order = list(np.random.default_rng(seed).permutation(problem.n))
    failed, paths = kernel_prioritized(problem, order)
    assert failed == -1
    check(problem, paths)
    waited = 0
    for k, a in enumerate(order):
        before = [paths[b] for b in order[:k]]
        ours = reference_sipp(free, pl.starts[a], pl.goals[a], connectivity, before)
        assert ours is not None and ours[0] == pl.starts[a] and ours[-1] == pl.goals[a]
        # the reference's path, among the paths it was planned around, obeys every rule too
        sub = Problem(free, [pl.starts[b] for b in order[:k + 1]], [pl.goals[b] for b in order[:k + 1]],
                      connectivity=connectivity)
        check(sub, before + [ours])
        assert arrival(ours, pl.goals[a]) == arrival(paths[a], pl.goals[a]), (seed, k, a)
        waited += arrival(ours, pl.goals[a]) - distances_to(free, pl.goals[a], connectivity)[pl.starts[a]]
    assert waited >= 0


def test_sipp_reference_waits_for_a_robot_crossing_its_way():
    free = rows(".....", ".....", ".....")
    crossing = [[(2, 0), (2, 1), (2, 2)]]          # down the middle column, parked at its foot
    path = reference_sipp(free, (0, 1), (4, 1), 4, crossing)
    assert path is not None and arrival(path, (4, 1)) == 4   # no wait: the robot has left (2, 1) by step 2
    blocked = [[(2, 0), (2, 1), (2, 1), (2, 1), (2, 2)]]     # stays in the way until step 3
    path = reference_sipp(free, (0, 1), (4, 1), 4, blocked)
    assert arrival(path, (4, 1)) == 6                 # waiting for it and walking round it cost the same
    wall = rows(".....", "##.##", ".....")
    path = reference_sipp(wall, (2, 0), (2, 2), 4, [[(2, 1), (2, 1), (2, 1), (2, 2), (1, 2)]])
    assert path is not None and arrival(path, (2, 2)) == 4      # waits for the gap to clear
    assert reference_sipp(wall, (2, 0), (2, 2), 4, [[(2, 1)]]) is None   # parked in the only gap


def lanes(connectivity: int) -> Problem:
    """Robots on separate rows of an open floor, each going straight along its own row."""
    free = np.ones((6, 8), dtype=bool)
    starts = [(0, 0), (7, 2), (0, 4), (3, 5)]
    goals = [(7, 0), (0, 2), (5, 4), (7, 5)]
    return Problem(free, starts, goals, connectivity=connectivity)


@pytest.mark.parametrize("connectivity", [4, 8])
def test_pibt_reference_and_kernel_move_robots_out_of_each_others_way_straight_home(connectivity):
    problem = lanes(connectivity)
    lower = sum(distances_to(problem.free, g, connectivity)[s] for s, g in zip(problem.starts, problem.goals))
    ours = reference_pibt(problem)
    theirs = kernel_pibt(problem, Limits(30.0))
    for paths in (ours, theirs):
        check(problem, paths)
    assert sum_of_costs(ours, problem.goals) == sum_of_costs(theirs, problem.goals) == lower
    assert makespan(ours, problem.goals) == makespan(theirs, problem.goals) == 7


@pytest.mark.parametrize("connectivity", [4, 8])
def test_pibt_reference_plans_are_valid_where_it_finds_them(connectivity):
    found = 0
    for problem in tiny_instances(30, connectivity):
        ours = reference_pibt(problem, max_steps=200, seed=problem.seed)
        if ours is not None:
            check(problem, ours)
            found += 1
            # whatever PIBT finds, a plan exists: LaCAM's kernel must find one too
            assert kernel_search(problem) is not None
    assert found
