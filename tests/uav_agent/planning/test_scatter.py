"""Scatter's routes (`scatter.py`): what they are, what they cost, and what they buy LaCAM."""
from __future__ import annotations

import numpy as np
import pytest

from protocol.mapfile import read_map, read_scen
from scenarios.benchmarks import movingai_map, movingai_scen
from uav_agent.planning.mapf.distances import compile_problem
from uav_agent.planning.mapf.grid_kernels import grid_of
from uav_agent.planning.mapf.lacam import search
from uav_agent.planning.portfolio import lacam, warm_up
from uav_agent.planning.mapf.pibt import history_to_paths
from uav_agent.planning.mapf.scatter import MARGIN, _scatter, routes
from uav_agent.planning.mapf.sipp import hm_slot
from uav_agent.planning.types import Limits, Problem, sum_of_costs
from uav_agent.planning.validator import check

W10 = "warehouse-10-20-10-2-1"


@pytest.fixture(scope="module", autouse=True)
def compiled_kernels():
    warm_up(parts=("search",))


def _problem(name: str, scen: str, n: int) -> Problem:
    free = read_map(movingai_map(name))
    agents = read_scen(movingai_scen(name, scen), free, n)
    return Problem(free, [a.start for a in agents], [a.goal for a in agents])


def _meetings_from_scratch(routes: list[list[int]]) -> int:
    """Pairs of routes on one cell at one step (after the start), pairs of opposite moves at one
    step (swaps), and steps a route spends on another robot's goal after that robot arrived."""
    on: dict[tuple[int, int], int] = {}
    moves: dict[tuple[int, int, int], int] = {}
    for r in routes:
        for t, v in enumerate(r):
            on[t, v] = on.get((t, v), 0) + 1
            if t > 0:
                moves[t - 1, r[t - 1], v] = moves.get((t - 1, r[t - 1], v), 0) + 1
    vertex = sum(k * (k - 1) // 2 for (t, _), k in on.items() if t > 0)
    swaps = sum(k * moves.get((t, v, u), 0) for (t, u, v), k in moves.items() if u < v)
    goal = {r[-1]: len(r) - 1 for r in routes}
    parked = sum(1 for r in routes for t, v in enumerate(r) if v in goal and v != r[-1] and t > goal[v])
    return vertex + swaps + parked


def test_routes_are_near_shortest_walks_from_start_to_goal():
    problem = _problem(W10, "random-1", 300)
    inst = compile_problem(problem)
    g = grid_of(inst)
    d0 = inst.start_distances().astype(np.int64)
    buf, off, length, met, rounds = _scatter(g, d0, MARGIN, 1e12, 0, 100)
    assert rounds >= 2 and met >= 0
    nbr = {v: set(int(u) for u in g.nbr[v] if u >= 0) for v in range(g.nbr.shape[0])}
    for a in range(inst.n):
        r = buf[off[a]:off[a] + length[a]]
        assert r[0] == inst.starts[a] and r[-1] == inst.goals[a]
        assert d0[a] + 1 <= len(r) <= d0[a] + MARGIN + 1                 # no waits, at most MARGIN longer
        assert len(set(r.tolist())) == len(r)                            # no cell twice
        assert all(int(r[t + 1]) in nbr[int(r[t])] for t in range(len(r) - 1))
    # what the rounds counted is what the routes meet, counted from scratch
    assert _meetings_from_scratch([buf[off[a]:off[a] + length[a]].tolist() for a in range(inst.n)]) == met


def test_rounds_and_detours_lower_the_meetings():
    problem = _problem(W10, "random-2", 600)
    inst = compile_problem(problem)
    g = grid_of(inst)
    d0 = inst.start_distances().astype(np.int64)
    first = _scatter(g, d0, MARGIN, 1e12, 0, 1)
    settled = _scatter(g, d0, MARGIN, 1e12, 0, 100)
    assert first[4] == 1 and settled[4] >= 2 and settled[3] < first[3]
    shortest = _scatter(g, d0, 0, 1e12, 0, 100)     # margin 0: shortest paths only, the fewest meetings among them
    assert all(length == d0[a] + 1 for a, length in enumerate(shortest[2]))
    assert settled[3] < shortest[3]


def test_the_next_cell_map_follows_every_route():
    problem = _problem(W10, "random-3", 200)
    inst = compile_problem(problem)
    keys, vals, info = routes(inst, 60.0)
    assert info["rounds"] >= 2 and info["route_steps"] >= inst.lower_bound()
    g = grid_of(inst)
    d0 = inst.start_distances().astype(np.int64)
    buf, off, length, _, _ = _scatter(g, d0, MARGIN, 1e12, int(problem.seed), 100)   # the same seed: the same routes
    for a in range(inst.n):
        r = buf[off[a]:off[a] + length[a]]
        for t in range(len(r) - 1):
            key = (a << 32) | int(r[t])
            s = hm_slot(keys, key)
            assert keys[s] == key and vals[s] == r[t + 1]
        s = hm_slot(keys, (a << 32) | int(r[-1]))
        assert keys[s] != (a << 32) | int(r[-1])                          # nothing after the goal


def test_routes_make_lacam_plan_a_crowded_warehouse_cheaper():
    """1,000 robots on warehouse-10-20-10-2-1 (13 % of its cells): too crowded for the prioritized
    guides, so LaCAM runs on scatter's routes; unguided, the same search costs far more."""
    problem = _problem(W10, "random-1", 1000)
    inst = compile_problem(problem)
    paths = lacam(problem, Limits(60))
    check(problem, paths)
    bare = history_to_paths(inst, search(inst, Limits(60)))
    check(problem, bare)
    routed, plain = sum_of_costs(paths, problem.goals), sum_of_costs(bare, problem.goals)
    assert routed < 0.85 * plain, (routed, plain)


def test_a_floor_too_large_for_the_tables_gets_no_routes(monkeypatch):
    from uav_agent.planning.mapf import scatter

    free = np.ones((6, 6), bool)
    starts = [(x, 0) for x in range(6)] + [(x, 5) for x in range(6)]
    problem = Problem(free, starts, starts[6:] + starts[:6])    # 12 robots on 36 cells: crowded
    assert routes(compile_problem(problem), 10.0) is not None
    monkeypatch.setattr(scatter, "MAX_TABLE_BYTES", 1000)
    assert routes(compile_problem(problem), 10.0) is None
    check(problem, lacam(problem, Limits(10)))                  # LaCAM then runs unguided
