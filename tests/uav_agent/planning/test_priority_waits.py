"""The paper's collision avoidance by priority (Section 3.2.2): its two examples, its limits, and safety."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.errors import PlanningError
from scenarios.maps import place, random_map
from uav_agent.planning.paper.astar import astar
from uav_agent.planning.paper.priority_waits import IncompleteError, priority_waits
from uav_agent.planning.types import Limits, Problem
from uav_agent.planning.validator import validate

# The paper writes points as (x, y) pairs like ours. Its figures cannot settle whether it meant
# (x, y) or (row, col), and here it does not matter: on an all-free grid swapping the two
# coordinates is a symmetry of 8-connected motion, so each example is also run transposed and
# must give the transposed plan. The examples move diagonally, so they are 8-connected; the
# 5x5 free grid holds every cell they use.
FREE = np.ones((5, 5), dtype=bool)


def transpose(paths):
    return [[(y, x) for x, y in p] for p in paths]


def solve(paths, connectivity=8, free=FREE):
    pr = Problem(free, [p[0] for p in paths], [p[-1] for p in paths], connectivity)
    out = priority_waits(pr, paths, Limits(10))
    assert validate(pr, out) == []
    return out


@pytest.mark.parametrize("flip", [False, True])
def test_single_point_collision_gives_exactly_the_papers_plan(flip):
    # Fig. 5(a): both paths cross (1, 1) at step 1; equal lengths, so R1 (listed first) has priority
    r1 = [(0, 0), (1, 1), (2, 2)]
    r2 = [(2, 0), (1, 1), (0, 2)]
    expected = [[(0, 0), (1, 1), (2, 2)],
                [(2, 0), (2, 0), (1, 1), (0, 2)]]        # R2 waits 1 step at (2, 0)
    f = transpose if flip else (lambda p: p)
    assert solve(f([r1, r2])) == f(expected)


def test_the_papers_multiple_point_plan_as_printed_has_a_vertex_conflict():
    # Section 3.2.2 prints R2 waiting 3 steps at (3, 1): then R2 enters (3, 2) at step 5, the very
    # step R1 reaches it. The printed plan is off by one, as the validator shows.
    r1 = [(0, 0), (1, 0), (1, 1), (1, 2), (2, 2), (3, 2), (4, 2)]
    r2_printed = [(4, 0), (3, 0), (3, 1), (3, 1), (3, 1), (3, 2), (2, 2), (1, 2), (0, 2)]
    pr = Problem(FREE, [r1[0], r2_printed[0]], [r1[-1], r2_printed[-1]], 8)
    found = validate(pr, [r1, r2_printed])
    assert [(v.kind, v.robots, v.step, v.cell) for v in found] == [("vertex", (0, 1), 5, (3, 2))]


@pytest.mark.parametrize("flip", [False, True])
def test_multiple_point_collision_gives_the_conflict_free_version_of_the_papers_plan(flip):
    # Fig. 5(b): the two robots run along (1,2)-(2,2)-(3,2) in opposite directions. R2 must wait
    # at (3, 1) until R1 has left (3, 2), at step 6: four steps at (3, 1), one more than printed.
    r1 = [(0, 0), (1, 0), (1, 1), (1, 2), (2, 2), (3, 2), (4, 2)]
    r2 = [(4, 0), (3, 0), (3, 1), (3, 2), (2, 2), (1, 2), (0, 2)]
    expected = [r1, [(4, 0), (3, 0), (3, 1), (3, 1), (3, 1), (3, 1), (3, 2), (2, 2), (1, 2), (0, 2)]]
    f = transpose if flip else (lambda p: p)
    assert solve(f([r1, r2])) == f(expected)


def test_the_longer_path_has_priority():
    # robot 1 has the longer path, so robot 0 (shorter) is the one that waits
    r0 = [(2, 3), (2, 2), (2, 1), (2, 0)]                 # both reach (2, 1) at step 2
    r1 = [(0, 1), (1, 1), (2, 1), (3, 1), (4, 1)]
    out = solve([r0, r1], connectivity=4)
    assert out[1] == r1
    assert out[0] == [(2, 3), (2, 2), (2, 2), (2, 1), (2, 0)]


def test_a_robot_leaves_its_start_when_a_higher_one_passes_through_it():
    # robot 1 (longer) drives through robot 0's start; robot 0 must get out of the way in time
    r0 = [(2, 2), (2, 3)]
    r1 = [(0, 2), (1, 2), (2, 2), (3, 2), (4, 2)]
    out = solve([r0, r1], connectivity=4)
    assert out == [r0, r1]


def test_a_robot_arrives_only_once_no_higher_robot_needs_its_goal():
    # robot 0's goal (2, 1) lies on robot 1's path at step 3: robot 0 must not park there before
    r0 = [(2, 0), (2, 1)]
    r1 = [(0, 1), (0, 1), (1, 1), (2, 1), (3, 1), (4, 1)]
    out = solve([r0, r1], connectivity=4)
    assert out[1] == r1
    assert out[0][-1] == (2, 1) and len(out[0]) - 1 == 4       # arrives at step 4, after robot 1 left


def test_head_on_in_a_corridor_is_incomplete():
    free = np.zeros((3, 7), dtype=bool)
    free[1, :] = True
    a = [(x, 1) for x in range(0, 6)]
    b = [(x, 1) for x in range(6, 0, -1)]
    pr = Problem(free, [a[0], b[0]], [a[-1], b[-1]], 4)
    with pytest.raises(IncompleteError) as info:
        priority_waits(pr, [a, b], Limits(10))
    assert info.value.robots == (1, 0)
    assert info.value.cell in a and info.value.cell in b
    assert "priority waits cannot resolve robot 1" in str(info.value)
    assert isinstance(info.value, PlanningError)


def test_a_robot_parked_on_anothers_path_is_incomplete():
    # robot 0 steps down onto its goal (3, 1) at step 1 and stays (its path ends with two waits,
    # which count towards its length: a tie with robot 1, so robot 0 goes first). Robot 1 has to
    # cross (3, 1) and no wait can get it past a robot that never leaves.
    free = np.zeros((3, 7), dtype=bool)
    free[1, :] = True
    free[0, 3] = True
    r0 = [(3, 0), (3, 1), (3, 1), (3, 1)]
    r1 = [(5, 1), (4, 1), (3, 1), (2, 1)]
    pr = Problem(free, [r0[0], r1[0]], [r0[-1], r1[-1]], 4)
    with pytest.raises(IncompleteError) as info:
        priority_waits(pr, [r0, r1], Limits(10))
    assert info.value.robots == (1, 0) and info.value.cell == (3, 1)
    assert "robot 0 sits on its goal (3, 1), on robot 1's path" in str(info.value)


def test_same_goal_or_start_and_bad_input_are_refused():
    with pytest.raises(IncompleteError, match="same goal"):
        solve([[(0, 0), (1, 0)], [(2, 0), (1, 0)]], connectivity=4)
    with pytest.raises(IncompleteError, match="both start"):
        solve([[(0, 0), (1, 0)], [(0, 0), (0, 1)]], connectivity=4)
    pr = Problem(FREE, [(0, 0)], [(1, 0)], 4)
    with pytest.raises(PlanningError, match="2 paths for 1 robots"):
        priority_waits(pr, [[(0, 0), (1, 0)], [(2, 2)]])
    with pytest.raises(PlanningError, match="does not run from its start to its goal"):
        priority_waits(pr, [[(0, 0), (0, 1)]])
    with pytest.raises(PlanningError, match="time limit"):
        priority_waits(pr, [[(0, 0), (1, 0)]], Limits(0.0))


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 100_000), st.integers(2, 8), st.sampled_from([4, 8]), st.floats(0.0, 0.3))
def test_the_result_is_always_valid_or_an_incomplete_error(seed, n, connectivity, density):
    free = random_map(8, 7, density, seed)
    try:
        pl = place(free, n, seed)
    except Exception:
        return                                  # too few connected free cells for n robots
    pr = Problem(free, pl.starts, pl.goals, connectivity)
    paths = [astar(free, s, g, connectivity) for s, g in zip(pl.starts, pl.goals)]
    try:
        out = priority_waits(pr, paths, Limits(10))
    except IncompleteError as exc:
        assert len(exc.robots) == 2 and exc.cell is not None
        return
    assert validate(pr, out) == []
    for mine, timed in zip(paths, out):        # only waits were added: same cells, same order
        assert [c for k, c in enumerate(timed) if k == 0 or c != timed[k - 1]] == \
               [c for k, c in enumerate(mine) if k == 0 or c != mine[k - 1]]
