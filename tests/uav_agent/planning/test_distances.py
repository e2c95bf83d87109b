"""Distance fields against scipy's graph search, cost matrices, the compact table and input errors."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import shortest_path

from protocol.errors import PlanningError
from scenarios.maps import random_map
from uav_agent.planning.mapf import distances as D
from uav_agent.planning.types import Problem


def reference_field(free: np.ndarray, goal, connectivity: int) -> np.ndarray:
    """Unit-cost shortest paths with scipy on an explicitly built grid graph (-1 = unreachable)."""
    h, w = free.shape
    moves = [(1, 0), (-1, 0), (0, 1), (0, -1)]
    if connectivity == 8:
        moves += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
    src, dst = [], []
    for y in range(h):
        for x in range(w):
            if not free[y, x]:
                continue
            for dx, dy in moves:
                nx, ny = x + dx, y + dy
                if not (0 <= nx < w and 0 <= ny < h) or not free[ny, nx]:
                    continue
                if dx and dy and not (free[y, nx] and free[ny, x]):
                    continue
                src.append(y * w + x)
                dst.append(ny * w + nx)
    graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(h * w, h * w)).tocsr()
    d = shortest_path(graph, unweighted=True, indices=goal[1] * w + goal[0])
    return np.where(np.isinf(d), -1, d).astype(np.int64).reshape(h, w)


@settings(max_examples=25, deadline=None)
@given(w=st.integers(2, 14), h=st.integers(2, 14), density=st.floats(0.0, 0.45),
       seed=st.integers(0, 10_000), conn=st.sampled_from([4, 8]))
def test_field_matches_scipy(w, h, density, seed, conn):
    free = random_map(w, h, density, seed)
    cells = np.argwhere(free)
    if cells.size == 0:
        return
    y, x = cells[seed % len(cells)]
    goal = (int(x), int(y))
    field = D.distance_field(free, goal, conn)
    assert field.dtype == np.int32 and field.shape == free.shape
    np.testing.assert_array_equal(field, reference_field(free, goal, conn))


def test_eight_connectivity_does_not_cut_corners():
    free = np.array([[1, 0],
                     [1, 1]], dtype=bool)
    # (0, 0) -> (1, 1) diagonally would cut the corner of the wall at (1, 0): two steps instead
    assert D.distance_field(free, (0, 0), 8)[1, 1] == 2
    assert D.distance_field(np.ones((2, 2), bool), (0, 0), 8)[1, 1] == 1


def test_table_rows_match_single_fields_and_mark_unreachable():
    free = random_map(30, 20, 0.3, 7)
    cells = [(int(x), int(y)) for y, x in np.argwhere(free)[::37]]
    table = D.distance_fields(free, cells, 4)
    assert table.dist.dtype == np.uint16 and table.dist.shape == (len(cells), int(free.sum()))
    for k, c in enumerate(cells):
        np.testing.assert_array_equal(table.field(k), D.distance_field(free, c, 4))
    # at(): inf where the field says -1
    field = table.field(0)
    far = next((int(x), int(y)) for y, x in np.argwhere(free) if field[y, x] < 0)
    assert table.at(0, far) == float("inf")


def test_cost_matrix_matches_fields_and_shares_the_cached_table():
    D.clear_cache()
    free = np.ones((10, 10), bool)
    free[:, 5] = False                      # two halves, no way across
    starts = [(0, 0), (9, 9), (2, 3)]
    goals = [(4, 4), (6, 0)]
    cost = D.cost_matrix(free, starts, goals, 4)
    assert cost.shape == (3, 2) and cost.dtype == np.float64
    assert cost[0, 0] == 8 and cost[2, 0] == 3
    assert np.isinf(cost[0, 1]) and np.isinf(cost[1, 0]) and cost[1, 1] == 12
    first = D.distance_fields(free, goals, 4)
    again = D.distance_fields(free, [goals[1]], 4)      # a subset: no new searches
    assert again.dist is first.dist and again.field(0)[0, 9] == 3


def test_long_maze_switches_to_wide_rows():
    # a serpentine of 1-wide corridors: the far end is more than 65,535 steps away
    h, w = 401, 330
    free = np.zeros((h, w), bool)
    free[::2, :] = True
    for k, y in enumerate(range(1, h, 2)):
        free[y, w - 1 if k % 2 == 0 else 0] = True
    table = D.distance_fields(free, [(0, 0)], 4)
    assert table.dist.dtype == np.int32
    # 201 corridor rows of 329 steps each, 200 connectors of 2 steps; the last row ends on the right
    end = (w - 1, h - 1)
    assert table.at(0, end) == 201 * 329 + 200 * 2
    assert D.distance_field(free, (0, 0), 4)[end[1], end[0]] == 201 * 329 + 200 * 2


@pytest.mark.parametrize("conn", [4, 8])
def test_interpreted_rows_are_the_kernel_rows(conn):
    """An interpreted process's distance rows (SciPy's Dijkstra) are the compiled kernel's, number for
    number: a fresh clone's first plan is the plan of every later run."""
    free = random_map(40, 30, 0.35, 3)       # walled-in pockets: unreachable cells too
    graph = D.grid_graph(free, conn)
    sources = np.arange(0, graph.n, 53, dtype=np.int32)
    for dtype, sentinel in ((np.uint16, D.UNREACHABLE_16), (np.int32, D.UNREACHABLE_32)):
        kernel, scipy = (np.empty((sources.size, graph.n), dtype=dtype) for _ in range(2))
        far = graph.bfs_rows(sources, kernel, sentinel)
        assert D._scipy_rows(graph.nbr, sources, scipy, sentinel) == far
        np.testing.assert_array_equal(scipy, kernel)
        assert (kernel == sentinel).any()


@pytest.mark.parametrize("conn", [4, 8])
def test_neighbour_table_lists_free_neighbours_in_order(conn):
    free = random_map(17, 11, 0.4, 5)
    graph = D.grid_graph(free, conn)
    h, w = free.shape
    for i in range(graph.n):
        x, y = graph.cell_of(i)
        want = []
        for dx, dy in list(zip(D._DX, D._DY))[:conn]:
            nx, ny = x + int(dx), y + int(dy)
            if 0 <= nx < w and 0 <= ny < h and free[ny, nx] and (not (dx and dy) or (free[y, nx] and free[ny, x])):
                want.append(graph.id_of((nx, ny)))
        assert list(graph.nbr[i]) == want + [-1] * (conn - len(want))


@pytest.mark.parametrize("goal, text", [((5, 0), "off the"), ((1, 1), "obstacle"), (("a", 0), "not an")])
def test_bad_cells_are_one_line_errors(goal, text):
    free = np.ones((3, 3), bool)
    free[1, 1] = False
    with pytest.raises(PlanningError, match=text):
        D.distance_field(free, goal, 4)


def test_bad_connectivity_and_grid():
    with pytest.raises(PlanningError, match="connectivity"):
        D.distance_field(np.ones((3, 3), bool), (0, 0), 6)
    with pytest.raises(PlanningError, match="2-D"):
        D.distance_field(np.ones(5, bool), (0, 0), 4)


def test_compile_problem_checks_robots():
    free = np.ones((4, 4), bool)
    free[:, 2] = False
    with pytest.raises(PlanningError, match="share the start"):
        D.compile_problem(Problem(free, [(0, 0), (0, 0)], [(1, 1), (1, 2)]))
    with pytest.raises(PlanningError, match="share the goal"):
        D.compile_problem(Problem(free, [(0, 0), (0, 1)], [(1, 1), (1, 1)]))
    with pytest.raises(PlanningError, match=r"robot 1: goal \(3, 3\) is unreachable from \(0, 1\)"):
        D.compile_problem(Problem(free, [(0, 0), (0, 1)], [(1, 1), (3, 3)]))
    with pytest.raises(PlanningError, match="2 starts but 1 goals"):
        D.compile_problem(Problem(free, [(0, 0), (0, 1)], [(1, 1)]))
    inst = D.compile_problem(Problem(free, [(0, 0), (1, 3)], [(1, 1), (0, 3)]))
    assert inst.start_distances().tolist() == [2, 1] and inst.lower_bound() == 3
