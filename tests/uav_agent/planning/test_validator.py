"""The independent plan validator: every kind of violation, and agreement with a naive checker."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocol.errors import PlanningError
from uav_agent.planning.types import Problem
from uav_agent.planning.validator import Violation, check, validate


def problem(paths, free=None, connectivity=4, goals=None):
    free = np.ones((6, 6), dtype=bool) if free is None else free
    return Problem(free, [p[0] for p in paths], goals or [p[-1] for p in paths], connectivity)


def kinds(found: list[Violation]) -> list[str]:
    return [v.kind for v in found]


def test_a_valid_plan_has_no_violation_and_passes_check():
    paths = [[(0, 0), (1, 0), (2, 0)], [(0, 2), (0, 2), (1, 2), (1, 1)], [(5, 5)]]
    pr = problem(paths)
    assert validate(pr, paths) == []
    check(pr, paths)


def test_following_a_robot_into_the_cell_it_leaves_is_allowed():
    paths = [[(1, 0), (2, 0), (3, 0)], [(0, 0), (1, 0), (2, 0)]]
    assert validate(problem(paths), paths) == []


def test_wrong_number_of_paths():
    paths = [[(0, 0)], [(1, 1)]]
    found = validate(problem(paths), paths[:1])
    assert kinds(found) == ["length"] and "1 paths for 2 robots" in found[0].text


def test_missing_and_malformed_paths():
    paths = [[(0, 0), (1, 0)], [(2, 2)], [(3, 3)]]
    pr = problem(paths)
    found = validate(pr, [paths[0], [], [(3, 3, 1)]])
    assert kinds(found) == ["length", "length"]
    assert {v.robots for v in found} == {(1,), (2,)}
    assert "no path" in found[0].text and "not a list of (x, y)" in found[1].text


def test_wrong_start_and_wrong_goal():
    paths = [[(0, 0), (1, 0)]]
    pr = Problem(np.ones((4, 4), bool), [(0, 1)], [(2, 0)])
    found = validate(pr, paths)
    assert kinds(found) == ["length", "length"]
    assert "not at its start (0, 1)" in found[0].text
    assert "ends at (1, 0), not at its goal (2, 0)" in found[1].text


def test_off_grid_and_obstacle():
    free = np.ones((3, 3), dtype=bool)
    free[1, 1] = False
    paths = [[(0, 1), (1, 1), (2, 1)], [(2, 2), (3, 2), (2, 2)]]
    found = validate(problem(paths, free), paths)
    assert ("obstacle", (0,), 1, (1, 1)) in [(v.kind, v.robots, v.step, v.cell) for v in found]
    assert ("off-grid", (1,), 1, (3, 2)) in [(v.kind, v.robots, v.step, v.cell) for v in found]


def test_jumps_diagonals_in_4_connectivity_and_corner_cuts():
    paths = [[(0, 0), (2, 0)]]
    assert kinds(validate(problem(paths), paths)) == ["jump"]
    diag = [[(0, 0), (1, 1)]]
    assert kinds(validate(problem(diag, connectivity=4), diag)) == ["jump"]
    assert validate(problem(diag, connectivity=8), diag) == []
    free = np.ones((3, 3), dtype=bool)
    free[0, 1] = False                      # (1, 0) blocked: (0, 0) -> (1, 1) cuts its corner
    found = validate(problem(diag, free, connectivity=8), diag)
    assert kinds(found) == ["jump"] and "corner cut" in found[0].text


def test_vertex_conflict():
    paths = [[(0, 0), (1, 0), (2, 0)], [(1, 1), (1, 0), (1, 1)]]
    found = validate(problem(paths), paths)
    assert [(v.kind, v.robots, v.step, v.cell) for v in found] == [("vertex", (0, 1), 1, (1, 0))]


def test_robots_starting_on_one_cell_conflict_at_step_0():
    paths = [[(0, 0), (1, 0)], [(0, 0), (0, 1)]]
    found = validate(problem(paths), paths)
    assert [(v.kind, v.step) for v in found] == [("vertex", 0)]


def test_swap_conflict():
    paths = [[(0, 0), (1, 0), (2, 0)], [(2, 0), (2, 0), (1, 0), (0, 0)]]
    found = validate(problem(paths), paths)
    assert ("swap", (0, 1), 2) in [(v.kind, v.robots, v.step) for v in found]
    # a diagonal swap in 8-connectivity too
    paths = [[(0, 0), (1, 1)], [(1, 1), (0, 0)]]
    found = validate(problem(paths, connectivity=8), paths)
    assert kinds(found) == ["swap"]


def test_crossing_diagonals_in_8_connectivity():
    paths = [[(0, 0), (1, 1)], [(1, 0), (0, 1)]]
    found = validate(problem(paths, connectivity=8), paths)
    assert [(v.kind, v.robots, v.step, v.cell) for v in found] == [("crossing", (0, 1), 1, (0, 0))]
    parallel = [[(0, 0), (1, 1)], [(1, 0), (2, 1)]]
    assert validate(problem(parallel, connectivity=8), parallel) == []


def test_passing_through_a_robot_parked_on_its_goal():
    # robot 0 arrives on (1, 0) at step 1 and stays; robot 1 drives through it at step 3
    paths = [[(0, 0), (1, 0)], [(1, 2), (1, 2), (1, 1), (1, 0), (2, 0)]]
    found = validate(problem(paths), paths)
    assert [(v.kind, v.robots, v.step, v.cell) for v in found] == [("goal-occupied", (0, 1), 3, (1, 0))]
    assert "robot 0 already sits on its goal" in found[0].text


def test_check_names_the_first_violation_and_the_count():
    paths = [[(0, 0), (1, 0), (2, 0)], [(2, 0), (2, 0), (1, 0), (0, 0)], [(1, 1), (1, 0), (1, 1)]]
    with pytest.raises(PlanningError, match=r"invalid plan: robots 0, 2 share \(1, 0\) at step 1 \(2 violations in all\)"):
        check(problem(paths), paths)


def test_bad_connectivity_is_refused():
    with pytest.raises(PlanningError, match="connectivity"):
        validate(problem([[(0, 0)]], connectivity=6), [[(0, 0)]])


def test_a_big_valid_plan_is_valid_and_one_conflict_in_it_is_found():
    n = t = 1000
    free = np.ones((n, t), dtype=bool)
    paths = [[(x, i) for x in range(t)] for i in range(n)]
    pr = Problem(free, [p[0] for p in paths], [p[-1] for p in paths], 8)
    assert validate(pr, paths) == []
    paths[7] = paths[7][:500] + [(500, 8)] + paths[7][501:]   # steps into robot 8's row
    found = validate(pr, paths)
    assert [(v.kind, v.robots, v.step) for v in found] == [("vertex", (7, 8), 500)]


# --- agreement with a naive, loop-by-loop reference checker -------------------------------------

def reference(free, starts, goals, paths, connectivity):
    """Loop-by-loop restatement of the rules; the validator must find exactly the same set."""
    h, w = free.shape
    out = set()
    T = max(len(p) for p in paths)
    at = [[p[min(t, len(p) - 1)] for t in range(T)] for p in paths]
    settled = []
    for p in paths:
        s = len(p) - 1
        while s > 0 and p[s - 1] == p[-1]:
            s -= 1
        settled.append(s)
    for i, p in enumerate(paths):
        if p[0] != starts[i]:
            out.add(("length", (i,), 0))
        if p[-1] != goals[i]:
            out.add(("length", (i,), len(p) - 1))
        for t, (x, y) in enumerate(p):
            if not (0 <= x < w and 0 <= y < h):
                out.add(("off-grid", (i,), t))
            elif not free[y, x]:
                out.add(("obstacle", (i,), t))
        for t in range(1, len(p)):
            (x0, y0), (x1, y1) = p[t - 1], p[t]
            dx, dy = x1 - x0, y1 - y0
            if max(abs(dx), abs(dy)) > 1 or (connectivity == 4 and abs(dx) + abs(dy) == 2):
                out.add(("jump", (i,), t))
            elif abs(dx) + abs(dy) == 2:
                inside = all(0 <= a < w and 0 <= b < h for a, b in ((x0, y0), (x1, y1)))
                if inside and not (free[y0, x1] and free[y1, x0]):
                    out.add(("jump", (i,), t))
    n = len(paths)
    for t in range(T):
        groups: dict = {}
        for i in range(n):
            x, y = at[i][t]
            if 0 <= x < w and 0 <= y < h:
                groups.setdefault((x, y), []).append(i)
        for members in groups.values():
            if len(members) > 1:
                parked = any(t > settled[i] for i in members)
                out.add(("goal-occupied" if parked else "vertex", tuple(members), t))
        if t == 0:
            continue
        for i in range(n):
            for j in range(i + 1, n):
                a0, a1, b0, b1 = at[i][t - 1], at[i][t], at[j][t - 1], at[j][t]
                if not all(0 <= c[0] < w and 0 <= c[1] < h for c in (a0, a1, b0, b1)):
                    continue
                step_a = max(abs(a1[0] - a0[0]), abs(a1[1] - a0[1]))
                if a0 != a1 and step_a == 1 and a0 == b1 and a1 == b0:
                    out.add(("swap", (i, j), t))
                da = (a1[0] - a0[0], a1[1] - a0[1])
                db = (b1[0] - b0[0], b1[1] - b0[1])
                if abs(da[0]) == abs(da[1]) == 1 and abs(db[0]) == abs(db[1]) == 1:
                    sq_a = (min(a0[0], a1[0]), min(a0[1], a1[1]))
                    sq_b = (min(b0[0], b1[0]), min(b0[1], b1[1]))
                    if sq_a == sq_b and (da[0] == da[1]) != (db[0] == db[1]):
                        out.add(("crossing", (i, j), t))
    return out


cell = st.tuples(st.integers(-1, 4), st.integers(-1, 4))


@st.composite
def plans(draw):
    free = np.array(draw(st.lists(st.lists(st.booleans(), min_size=4, max_size=4), min_size=4, max_size=4)))
    n = draw(st.integers(1, 4))
    paths = []
    for _ in range(n):
        start = draw(cell)
        steps = draw(st.lists(st.sampled_from([(0, 0), (1, 0), (-1, 0), (0, 1), (0, -1), (1, 1),
                                                (-1, -1), (1, -1), (-1, 1), (2, 0)]), max_size=6))
        p = [start]
        for dx, dy in steps:
            p.append((p[-1][0] + dx, p[-1][1] + dy))
        paths.append(p)
    starts = [p[0] if draw(st.booleans()) else draw(cell) for p in paths]
    goals = [p[-1] if draw(st.booleans()) else draw(cell) for p in paths]
    return free, starts, goals, paths, draw(st.sampled_from([4, 8]))


@settings(max_examples=300, deadline=None)
@given(plans())
def test_validator_agrees_with_the_reference_checker(case):
    free, starts, goals, paths, connectivity = case
    found = validate(Problem(free, starts, goals, connectivity), paths)
    assert {(v.kind, v.robots, v.step) for v in found} == reference(free, starts, goals, paths, connectivity)
