"""The planning pipeline, the planner registry and plan files, on small real maps."""
from __future__ import annotations

import itertools
import json
from collections import deque

import numpy as np
import pytest

from protocol.errors import MapError, PlanningError
from scenarios.maps import NAMED, place, warehouse
from uav_agent.planning.assignment import ASSIGNERS
from uav_agent.planning.pipeline import PlanResult, plan_mission
from uav_agent.planning.plan_io import FORMAT, plan_from_dict, plan_to_dict, read_plan, write_plan
from uav_agent.planning.registry import DEFAULT_PLANNER, PLANNERS, get_planner, is_complete
from uav_agent.planning.types import Problem, makespan, sum_of_costs
from uav_agent.planning.validator import validate


def bfs(free: np.ndarray, src, connectivity: int = 4) -> dict:
    """The test's own shortest-path distances, independent of the planning package."""
    h, w = free.shape
    moves = [(1, 0), (-1, 0), (0, 1), (0, -1)]
    if connectivity == 8:
        moves += [(1, 1), (1, -1), (-1, 1), (-1, -1)]
    dist = {src: 0}
    q = deque([src])
    while q:
        x, y = q.popleft()
        for dx, dy in moves:
            nx, ny = x + dx, y + dy
            if not (0 <= nx < w and 0 <= ny < h) or not free[ny, nx] or (nx, ny) in dist:
                continue
            if dx and dy and not (free[y, nx] and free[ny, x]):
                continue
            dist[(nx, ny)] = dist[(x, y)] + 1
            q.append((nx, ny))
    return dist


def true_costs(free, starts, goals, connectivity=4) -> np.ndarray:
    fields = [bfs(free, g, connectivity) for g in goals]
    return np.array([[fields[j].get(s, np.inf) for j in range(len(goals))] for s in starts], dtype=float)


@pytest.fixture(scope="module")
def small():
    free = warehouse(**NAMED["warehouse-small"])
    pl = place(free, 6, 3)
    return free, pl.starts, pl.goals


def corridor():
    """A 1-wide corridor with one side pocket: head-on robots need the pocket to pass."""
    free = np.zeros((2, 7), dtype=bool)
    free[0, :] = True
    free[1, 3] = True
    return free, [(0, 0), (6, 0)], [(6, 0), (0, 0)]


def assert_sound(free, starts, goals, result: PlanResult, connectivity=4):
    problem = Problem(free, result.starts, result.goals, connectivity)
    assert validate(problem, result.paths) == []
    assert result.starts == list(starts)
    assert sorted(result.goals) == sorted(goals)
    assert [goals[j] for j in result.assignment] == result.goals
    cost = true_costs(free, starts, goals, connectivity)
    lb = sum(cost[i, j] for i, j in enumerate(result.assignment))
    m = result.metrics
    assert m["lower_bound"] == lb
    assert m["sum_of_costs"] == sum_of_costs(result.paths, result.goals) >= lb
    assert m["makespan"] == makespan(result.paths, result.goals)
    assert m["soc_over_lb"] == pytest.approx(m["sum_of_costs"] / lb)
    for phase in ("distances", "assignment", "planning", "validation", "total"):
        assert result.timings[phase] >= 0.0
    assert result.timings["total"] >= result.timings["planning"]
    return cost


def test_registry_names_and_default():
    assert set(PLANNERS) == {"paper-astar", "paper-prm", "prioritized", "pibt", "lacam"}
    assert DEFAULT_PLANNER == "lacam" and is_complete(DEFAULT_PLANNER)
    assert not is_complete("paper-astar")
    with pytest.raises(PlanningError, match="unknown planner 'nope'.*lacam"):
        get_planner("nope")


@pytest.mark.parametrize("planner", sorted(PLANNERS))
@pytest.mark.parametrize("assign", list(ASSIGNERS))
def test_every_planner_and_assignment(small, planner, assign):
    free, starts, goals = small
    r = plan_mission(free, starts, goals, planner=planner, assign=assign, time_limit=30.0)
    cost = assert_sound(free, starts, goals, r)
    assert r.requested == planner and r.assign == assign
    assert r.planner == planner or (r.fell_back and r.planner == DEFAULT_PLANNER and r.notes)
    n = len(starts)
    if assign == "none":
        assert r.assignment == list(range(n))
    best = min(sum(cost[i, p[i]] for i in range(n)) for p in itertools.permutations(range(n)))
    if assign == "optimal":
        assert r.metrics["lower_bound"] == best
    if assign == "bottleneck":
        worst = min(max(cost[i, p[i]] for i in range(n)) for p in itertools.permutations(range(n)))
        assert max(cost[i, j] for i, j in enumerate(r.assignment)) == worst
        assert r.metrics["lower_bound"] == min(
            sum(cost[i, p[i]] for i in range(n)) for p in itertools.permutations(range(n))
            if max(cost[i, p[i]] for i in range(n)) == worst)
    if assign == "bruteforce":
        # The paper's criterion: the least sum of straight-line distances.
        eu = lambda p: sum(np.hypot(starts[i][0] - goals[p[i]][0], starts[i][1] - goals[p[i]][1]) for i in range(n))
        assert eu(r.assignment) == pytest.approx(min(eu(p) for p in itertools.permutations(range(n))))


@pytest.mark.parametrize("seed", range(4))
def test_optimal_assignment_matches_brute_force_on_tiny_random_maps(seed):
    from scenarios.maps import random_map
    free = random_map(9, 7, 0.2, seed)
    pl = place(free, 5, seed)
    r = plan_mission(free, pl.starts, pl.goals, assign="optimal")
    cost = assert_sound(free, pl.starts, pl.goals, r)
    best = min(sum(cost[i, p[i]] for i in range(5)) for p in itertools.permutations(range(5)))
    assert r.metrics["lower_bound"] == best


@pytest.mark.parametrize("planner", ["paper-astar", DEFAULT_PLANNER])
def test_eight_connected(small, planner):
    free, starts, goals = small
    r = plan_mission(free, starts, goals, planner=planner, connectivity=8)
    assert_sound(free, starts, goals, r, connectivity=8)
    assert r.connectivity == 8


@pytest.mark.parametrize("planner", ["paper-astar", "paper-prm"])
def test_paper_pipeline_falls_back_on_head_on_corridor(planner):
    free, starts, goals = corridor()
    r = plan_mission(free, starts, goals, planner=planner, assign="none")
    assert r.fell_back and r.planner == DEFAULT_PLANNER and r.requested == planner
    assert any(planner in n and DEFAULT_PLANNER in n for n in r.notes)
    assert_sound(free, starts, goals, r)
    with pytest.raises(PlanningError):
        plan_mission(free, starts, goals, planner=planner, assign="none", fallback=False)


def test_default_planner_never_falls_back():
    free, starts, goals = corridor()
    r = plan_mission(free, starts, goals, assign="none")
    assert not r.fell_back and r.notes == []
    assert r.metrics["sum_of_costs"] > r.metrics["lower_bound"]  # one robot had to step aside


@pytest.mark.parametrize("assign", list(ASSIGNERS))
def test_unreachable_goal_is_a_planning_error(assign):
    free = np.ones((4, 7), dtype=bool)
    free[:, 3] = False   # a wall: two rooms
    starts, goals = [(0, 0), (1, 2)], [(2, 3), (6, 1)]
    with pytest.raises(PlanningError, match="robot|goal"):
        plan_mission(free, starts, goals, assign=assign)


def test_more_goals_than_robots_leaves_the_farthest_unserved():
    free = np.ones((5, 5), dtype=bool)
    r = plan_mission(free, [(0, 0), (4, 4)], [(4, 3), (0, 1), (2, 2)])
    assert sorted(r.goals) == [(0, 1), (4, 3)] and r.metrics["sum_of_costs"] == 2


@pytest.mark.parametrize("kwargs, match", [
    (dict(starts=[(0, 0), (0, 0)]), "starts 0 and 1 are both at"),
    (dict(starts=[(9, 0), (1, 0)]), "off the"),
    (dict(goals=[(2, 1), (4, 4)]), "obstacle"),
    (dict(goals=[(4, 4)]), "every robot needs its own goal"),
    (dict(goals=[(4, 4), (3, 4), (2, 4)], assign="none"), "the counts must match"),
    (dict(starts=[], goals=[]), "no robots"),
    (dict(planner="astar9"), "unknown planner"),
    (dict(assign="greedy"), "unknown assignment"),
    (dict(connectivity=6), "connectivity"),
    (dict(time_limit=0), "time limit"),
    (dict(starts=[(0, 0), "ab"]), "not an"),
])
def test_bad_input_is_one_line_planning_error(kwargs, match):
    free = np.ones((5, 5), dtype=bool)
    free[1, 2] = False
    args = dict(starts=[(0, 0), (1, 0)], goals=[(4, 4), (3, 4)])
    args.update(kwargs)
    with pytest.raises(PlanningError, match=match) as e:
        plan_mission(free, args.pop("starts"), args.pop("goals"), **args)
    assert "\n" not in str(e.value)


# ---------------------------------------------------------------------------- plan files

def test_plan_file_round_trip(small, tmp_path):
    free, starts, goals = small
    r = plan_mission(free, starts, goals)
    ids = [10 + i for i in range(len(starts))]
    path = tmp_path / "sub" / "plan.json"
    write_plan(path, r, free, ids=ids, map_name="warehouse-small")
    raw = json.loads(path.read_text())      # plain JSON, no project code needed
    assert raw["format"] == FORMAT and raw["planner"] == r.planner and raw["connectivity"] == 4
    assert raw["map"]["width"] == free.shape[1] and len(raw["map"]["rows"]) == free.shape[0]
    assert set(raw["metrics"]) >= {"sum_of_costs", "makespan", "lower_bound"}
    assert set(raw["timings"]) >= {"total", "distances", "assignment", "planning", "validation"}
    assert sum(rb["cost"] for rb in raw["robots"]) == r.metrics["sum_of_costs"]
    assert raw["robots"][0]["path"][0] == list(r.starts[0])
    loaded = read_plan(path)
    assert np.array_equal(loaded.free, free)
    assert loaded.ids == ids and loaded.starts == r.starts and loaded.goals == r.goals
    assert loaded.paths == r.paths and loaded.connectivity == 4 and loaded.map_name == "warehouse-small"
    assert loaded.metrics["sum_of_costs"] == r.metrics["sum_of_costs"]


def _good_dict():
    free, starts, goals = corridor()
    r = plan_mission(free, starts, goals, assign="none")
    return plan_to_dict(r, free)


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(format="uav-robots-plan/0"), "format"),
    (lambda d: d.pop("robots"), "robots"),
    (lambda d: d["robots"][0].pop("path"), "lacks"),
    (lambda d: d["robots"][0].update(id="a"), "not an integer"),
    (lambda d: d["robots"][1].update(id=0), "not distinct"),
    (lambda d: d["robots"][0].update(start=[1]), r"not \[x, y\]"),
    (lambda d: d["robots"][0]["path"].append([99, 0]), "off the"),
    (lambda d: d["robots"][0]["path"].insert(0, [1, 0]), "from its start"),
    (lambda d: d["map"]["rows"].append(".."), "row 2 has"),
    (lambda d: d["map"].update(width=3), "map says"),
    (lambda d: d.update(connectivity=5), "connectivity"),
    (lambda d: d.update(map=[]), "rows"),
])
def test_malformed_plan_dicts(mutate, match):
    d = _good_dict()
    mutate(d)
    with pytest.raises((PlanningError, MapError), match=match) as e:
        plan_from_dict(d)
    assert "\n" not in str(e.value)


def test_malformed_plan_files(tmp_path):
    with pytest.raises(PlanningError, match="not found"):
        read_plan(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{ not json")
    with pytest.raises(PlanningError, match="not JSON"):
        read_plan(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(PlanningError, match="not a JSON object"):
        read_plan(bad)
    # Well-formed but colliding: read with validation refuses it.
    d = _good_dict()
    d["robots"][0]["path"] = [[0, 0], [1, 0], [2, 0], [3, 0], [4, 0], [5, 0], [6, 0]]
    d["robots"][1]["path"] = [[6, 0], [5, 0], [4, 0], [3, 0], [2, 0], [1, 0], [0, 0]]
    bad.write_text(json.dumps(d))
    with pytest.raises(PlanningError, match="invalid plan"):
        read_plan(bad)
    assert read_plan(bad, validate=False).paths[0][-1] == (6, 0)
