"""Robot-goal assignment: the paper's Table 1, brute force against scipy, bottleneck, infeasible inputs."""
from __future__ import annotations

import math
from itertools import permutations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.errors import PlanningError
from uav_agent.planning.assignment import (assign_bottleneck, assign_bruteforce, assign_optimal,
                                           euclidean_costs)

# Table 1 of the paper, exactly as printed: rows are goals G0..G2, columns robots R0..R2.
TABLE_1 = np.array([[6, 7, 8],
                    [7, 14, 7],
                    [9, 10, 5]], dtype=float)


def total(cost, assignment):
    return sum(cost[i, j] for i, j in enumerate(assignment))


def test_table_1_gives_the_papers_assignment_and_cost():
    # Our matrices are cost[robot, goal]; the printed table is cost[goal, robot], so it is
    # transposed first. (The text's "a_ij between R_i and G_j" also reads robot-major.)
    # Column R0 of the table is (6, 7, 9): R0 -> G1 costs 7; column R1 (7, 14, 10): R1 -> G0
    # costs 7; column R2 (8, 7, 5): R2 -> G2 costs 5; 7 + 7 + 5 = 19, the paper's answer.
    # This optimum is its own inverse (a swap of G0/G1 plus a fixed point), so the untransposed
    # table happens to give the same pairs; the test below shows the orientation still matters.
    cost = TABLE_1.T
    assert assign_bruteforce(cost) == [1, 0, 2]          # R0->G1, R1->G0, R2->G2
    assert total(cost, assign_bruteforce(cost)) == 19
    assert assign_optimal(cost) == [1, 0, 2]


def test_orientation_matters_when_the_optimum_is_not_its_own_inverse():
    cost = np.array([[1, 0, 9], [9, 1, 0], [0, 9, 1]], dtype=float)   # best: 0->1, 1->2, 2->0
    assert assign_bruteforce(cost) == [1, 2, 0]
    assert assign_bruteforce(cost.T) == [2, 0, 1]


def test_euclidean_costs_are_straight_line_distances_robot_by_goal():
    cost = euclidean_costs([(0, 0), (3, 4)], [(3, 4), (0, 0), (6, 8)])
    assert cost.shape == (2, 3)
    assert cost[0].tolist() == [5.0, 0.0, 10.0]
    assert cost[1].tolist() == [0.0, 5.0, 5.0]


def test_bruteforce_refuses_more_than_max_n_robots():
    with pytest.raises(PlanningError, match="refused for 10 robots .at most 9."):
        assign_bruteforce(np.ones((10, 10)))
    assert len(assign_bruteforce(np.random.default_rng(0).random((9, 9)))) == 9
    with pytest.raises(PlanningError, match="at most 3"):
        assign_bruteforce(np.ones((4, 4)), max_n=3)


def test_more_robots_than_goals_and_bad_matrices_are_refused():
    for f in (assign_bruteforce, assign_optimal, assign_bottleneck):
        with pytest.raises(PlanningError, match="3 robots but only 2 goals"):
            f(np.ones((3, 2)))
        with pytest.raises(PlanningError, match="2-D"):
            f(np.ones(3))
        with pytest.raises(PlanningError, match="NaN"):
            f(np.array([[np.nan]]))
        assert f(np.zeros((0, 0))) == []


def test_more_goals_than_robots_each_robot_gets_a_distinct_goal():
    cost = np.array([[5, 1, 7, 3], [2, 1, 8, 9]], dtype=float)
    for f in (assign_bruteforce, assign_optimal, assign_bottleneck):
        a = f(cost)
        assert len(set(a)) == 2 and total(cost, a) == 3.0


def test_a_robot_that_reaches_no_goal_is_named():
    inf = np.inf
    cost = np.array([[1, 2, 3], [inf, inf, inf], [1, 1, 1]])
    for f in (assign_bruteforce, assign_optimal, assign_bottleneck):
        with pytest.raises(PlanningError, match="robot 1 can reach no goal"):
            f(cost)


def test_a_robot_whose_goals_are_all_taken_is_named():
    inf = np.inf
    cost = np.array([[1, inf, inf], [2, inf, inf], [1, 1, 1]])     # robots 0 and 1 need goal 0
    for f in (assign_bruteforce, assign_optimal, assign_bottleneck):
        with pytest.raises(PlanningError, match=r"robot [01] can reach no remaining goal"):
            f(cost)


def test_unreachable_pairs_are_avoided_when_a_complete_assignment_exists():
    inf = np.inf
    cost = np.array([[1, inf], [1, 50]])
    for f in (assign_bruteforce, assign_optimal, assign_bottleneck):
        assert f(cost) == [0, 1]


def test_bottleneck_trades_total_cost_for_the_worst_robot():
    cost = np.array([[0, 5], [5, 9]], dtype=float)
    assert assign_optimal(cost) == [0, 1]        # total 9, worst 9
    assert assign_bottleneck(cost) == [1, 0]     # total 10, worst 5


matrices = st.integers(1, 7).flatmap(lambda n: st.lists(
    st.lists(st.one_of(st.integers(0, 30).map(float), st.just(math.inf)), min_size=n, max_size=n),
    min_size=n, max_size=n)).map(lambda rows: np.array(rows, dtype=float))


def outcome(f, cost):
    try:
        return f(cost)
    except PlanningError:
        return None


@settings(max_examples=150, deadline=None)
@given(matrices)
def test_bruteforce_and_scipy_agree(cost):
    a, b = outcome(assign_bruteforce, cost), outcome(assign_optimal, cost)
    assert (a is None) == (b is None)
    if a is not None:
        assert sorted(a) == list(range(len(cost))) and sorted(b) == list(range(len(cost)))
        assert total(cost, a) == total(cost, b)
        assert math.isfinite(total(cost, a))


@settings(max_examples=100, deadline=None)
@given(matrices.filter(lambda c: len(c) <= 6))
def test_bottleneck_minimises_the_maximum_then_the_sum(cost):
    n = len(cost)
    feasible = [p for p in permutations(range(n)) if all(math.isfinite(cost[i, p[i]]) for i in range(n))]
    got = outcome(assign_bottleneck, cost)
    if not feasible:
        assert got is None
        return
    best_max = min(max(cost[i, p[i]] for i in range(n)) for p in feasible)
    best_sum = min(total(cost, p) for p in feasible if max(cost[i, p[i]] for i in range(n)) == best_max)
    assert sorted(got) == list(range(n))
    assert max(cost[i, got[i]] for i in range(n)) == best_max
    assert total(cost, got) == best_sum
