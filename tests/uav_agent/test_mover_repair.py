"""The rolling-horizon repair around the movers' forecast (uav_agent/planning/avoid.py, its SIPP in
mapf/dynamic.py) and the closed loop of tracker, forecast and repair among the world's movers
(uav_agent/planning/mover_loop.py with sim_world/movers.py), without a network.

- the SIPP with cells closed to entry arrives exactly when a brute-force space-time search says
  a robot can arrive first, and never enters a closed cell in its stretch;
- the repair replans only the robots whose next steps meet the forecast (and those a held
  robot's cell is in the way of), holds those it cannot route, passes the validator and never
  enters a cell the forecast closes within the window;
- run tick by tick among people, forklifts and pallets seen every few ticks, no robot touches
  a mover and every robot reaches its goal.
"""
from __future__ import annotations

import time
from collections import deque

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from protocol.errors import MapError, PlanningError
from scenarios.maps import place, random_map, resolve_map, warehouse
from sim_world.movers import (
    FORKLIFT,
    PALLET,
    PERSON,
    contacts,
    place_movers,
    step_movers,
)
from uav_agent.planning.avoid import geometry_of, repair
from uav_agent.planning.forecast import Track, forecast
from uav_agent.planning.mapf.distances import distance_fields, grid_graph
from uav_agent.planning.mapf.dynamic import OPEN, plan_around
from uav_agent.planning.mapf.grid_kernels import Grid, new_visits
from uav_agent.planning.mapf.reservations import new_reservations, reserve
from uav_agent.planning.mover_loop import run_among_movers
from uav_agent.planning.pipeline import plan_mission
from uav_agent.planning.types import Problem
from uav_agent.planning.validator import validate

KINDS = [PERSON, PERSON, FORKLIFT, PALLET]
SLACK = 60.0        # a budget no repair here needs, but a first one that compiles the kernels


def rows(*lines: str) -> np.ndarray:
    return np.array([[c != "#" for c in line] for line in lines], dtype=bool)


def valid(free, paths: dict, connectivity: int = 4) -> list:
    robots = sorted(paths)
    problem = Problem(free, [paths[r][0] for r in robots], [paths[r][-1] for r in robots], connectivity)
    return validate(problem, [paths[r] for r in robots])


def entries_into_forecast(paths: dict, fc, tick: int, window: int) -> list:
    return [(r, t, p[t]) for r, p in paths.items() for t in range(1, min(window, len(p) - 1) + 1)
            if p[t] != p[t - 1] and fc.closed(p[t], tick + t)]


# ---- the SIPP with cells closed to entry, against a brute-force space-time search ----

def _neighbours(free, c, connectivity):
    h, w = free.shape
    x, y = c
    steps = [(1, 0), (0, 1), (-1, 0), (0, -1)]
    if connectivity == 8:
        steps += [(1, 1), (-1, 1), (-1, -1), (1, -1)]
    for dx, dy in steps:
        u = (x + dx, y + dy)
        if 0 <= u[0] < w and 0 <= u[1] < h and free[u[1], u[0]]:
            if dx and dy and not (free[y, x + dx] and free[y + dy, x]):
                continue
            yield u


def earliest_arrival(free, start, goal, others, closed, until, hold, connectivity) -> int | None:
    """Breadth-first over (cell, step): the first step the robot can be on its goal for good."""
    def at(p, t):
        return p[min(t, len(p) - 1)]

    horizon = max([len(p) for p in others] + [1]) + max([u for u in until.values()] + [0]) + hold + 2
    limit = horizon + 2 * int(free.sum()) + 2
    parked_from = {}
    for p in others:
        parked_from[p[-1]] = len(p) - 1

    def settled(c, t):
        return all(at(p, s) != c for p in others for s in range(t, horizon + 1))

    seen = {(start, 0)}
    todo = deque([(start, 0)])
    while todo:
        c, t = todo.popleft()
        if c == goal and t >= hold and settled(c, t):
            return t
        if t >= limit:
            continue
        moves = [c] if t < hold else [c, *_neighbours(free, c, connectivity)]
        for u in moves:
            if any(at(p, t + 1) == u for p in others):
                continue
            if u != c:
                if any(at(p, t) == u and at(p, t + 1) == c for p in others):
                    continue
                if closed.get(u, OPEN) <= t + 1 <= until.get(u, -1):
                    continue
                if connectivity == 8 and u[0] != c[0] and u[1] != c[1]:
                    p1, p2 = (u[0], c[1]), (c[0], u[1])
                    if any((at(p, t) == p1 and at(p, t + 1) == p2) or (at(p, t) == p2 and at(p, t + 1) == p1)
                           for p in others):
                        continue
            if (u, t + 1) not in seen:
                seen.add((u, t + 1))
                todo.append((u, t + 1))
    return None


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(w=st.integers(3, 6), h=st.integers(2, 5), density=st.floats(0.0, 0.3), robots=st.integers(1, 3),
       seed=st.integers(0, 10_000), conn=st.sampled_from([4, 8]), hold=st.integers(0, 3), data=st.data())
def test_the_kernel_arrives_when_a_brute_force_search_says_it_can(w, h, density, robots, seed, conn, hold, data):
    free = random_map(w, h, density, seed)
    try:
        pl = place(free, robots + 1, seed)
    except MapError:
        return
    try:
        others = plan_mission(free, pl.starts[1:], pl.goals[1:], assign="none", connectivity=conn).paths
    except PlanningError:
        return      # the others have no plan: nothing to route around
    start, goal = pl.starts[0], pl.goals[0]
    if any(start in p[: hold + 1] for p in others):
        hold = 0
    cells = [(int(x), int(y)) for y, x in zip(*np.nonzero(free))]
    closed, until = {}, {}
    for c in data.draw(st.lists(st.sampled_from(cells), max_size=4, unique=True)):
        closed[c] = data.draw(st.integers(0, 4))
        until[c] = closed[c] + data.draw(st.integers(0, 5))

    graph = grid_graph(free, conn)
    table = distance_fields(free, [goal], conn)
    ids = {c: int(graph.index[c[1] * w + c[0]]) for c in cells}
    g = Grid(graph.nbr, geometry_of(graph), table.dist, table.rows, int(table.unreachable),
             np.array([ids[start]], dtype=np.int32), np.array([ids[goal]], dtype=np.int32))
    res = new_reservations(graph.n, 1024)
    for b, p in enumerate(others):
        res = reserve(res, np.array([ids[c] for c in p], dtype=np.int32), b + 1)
    shut = np.full(graph.n, OPEN, dtype=np.int32)
    opens = np.full(graph.n, -1, dtype=np.int32)
    for c, at in closed.items():
        shut[ids[c]], opens[ids[c]] = at, until[c]
    got = plan_around(g, res, 0, shut, opens, hold, 100_000, new_visits(graph.n))
    want = earliest_arrival(free, start, goal, others, closed, until, hold, conn)
    if want is None:
        assert got.size == 0
        return
    assert got.size == want + 1, (got, want)
    path = [graph.cell_of(int(v)) for v in got]
    assert path[0] == start and path[-1] == goal and set(path[: hold + 1]) == {start}
    assert not valid(free, {0: path, **{b + 1: p for b, p in enumerate(others)}}, conn)
    for t in range(1, len(path)):
        if path[t] != path[t - 1]:
            assert not closed.get(path[t], OPEN) <= t <= until.get(path[t], -1)


# ---- the repair ----

def plan(free, starts, goals, connectivity=4) -> dict:
    return dict(enumerate(plan_mission(free, starts, goals, assign="none", connectivity=connectivity).paths))


def test_nothing_in_the_way_changes_nothing():
    free = np.ones((8, 12), dtype=bool)
    paths = plan(free, [(0, 0), (0, 7)], [(11, 0), (11, 7)])
    fc = forecast(free, [Track(0, PERSON, (5, 4), 0)], 3)
    rep = repair(free, paths, fc, 0, 3, budget_s=SLACK)
    assert rep.paths == paths and all(rep.paths[r] is paths[r] for r in paths)
    assert not (rep.met or rep.replanned or rep.held or rep.frozen)


def test_only_the_robot_whose_next_steps_meet_the_forecast_is_replanned():
    free = np.ones((9, 14), dtype=bool)
    paths = plan(free, [(0, 0), (0, 4), (0, 8)], [(13, 0), (13, 4), (13, 8)])
    assert paths[1][1:4] == [(1, 4), (2, 4), (3, 4)]
    fc = forecast(free, [Track(0, PERSON, (3, 5), 0)], 2)   # may be on (2, 4) at tick 2
    rep = repair(free, paths, fc, 0, 2, budget_s=SLACK)
    assert rep.met == {1} and rep.replanned == {1} and not rep.held
    assert rep.paths[0] is paths[0] and rep.paths[2] is paths[2]
    assert rep.paths[1][0] == (0, 4) and rep.paths[1][-1] == (13, 4)
    assert not valid(free, rep.paths) and not entries_into_forecast(rep.paths, fc, 0, 2)


def test_a_robot_may_stay_on_a_cell_the_forecast_covers():
    # the person next to the robot could step anywhere around it, but never onto it
    free = np.ones((5, 9), dtype=bool)
    paths = plan(free, [(4, 2)], [(8, 2)])
    fc = forecast(free, [Track(0, FORKLIFT, (3, 2), 0)], 1)
    rep = repair(free, paths, fc, 0, 1, budget_s=SLACK)
    assert rep.replanned == {0} and not rep.held
    assert rep.paths[0][:2] == [(4, 2), (4, 2)]       # it waits on its own cell, then goes


CORRIDOR = rows(
    "########",
    "........",
    "########",
)


def test_a_robot_that_cannot_be_given_a_safe_step_is_held_and_the_one_behind_it_makes_way():
    # B follows A along a corridor; a person ahead closes A's next cell, and B was to step into A's
    free = CORRIDOR
    paths = {0: [(2, 1), (3, 1), (4, 1), (5, 1), (6, 1)], 1: [(1, 1), (2, 1), (3, 1), (4, 1), (5, 1)]}
    assert not valid(free, paths)
    fc = forecast(free, [Track(0, PERSON, (4, 1), 0)], 1)
    rep = repair(free, paths, fc, 0, 1, budget_s=SLACK)
    assert rep.met == {0} and rep.held == {0} and rep.replanned == {1} and not rep.frozen
    assert rep.paths[0][:2] == [(2, 1)] * 2 and rep.paths[0][-1] == (6, 1)
    assert rep.paths[1][:2] == [(1, 1)] * 2 and rep.paths[1][-1] == (5, 1)
    assert not valid(free, rep.paths) and not entries_into_forecast(rep.paths, fc, 0, 1)


def test_out_of_budget_every_robot_waits_out_the_window():
    free = np.ones((6, 10), dtype=bool)
    paths = plan(free, [(0, 0), (0, 3), (9, 5)], [(9, 0), (9, 3), (0, 5)])
    fc = forecast(free, [Track(0, PERSON, (3, 3), 0)], 3)
    rep = repair(free, paths, fc, 0, 3, budget_s=0.0)
    assert rep.frozen and rep.held == {0, 1, 2}
    assert all(rep.paths[r] == [paths[r][0]] * 3 + paths[r] for r in paths)
    assert not valid(free, rep.paths)


def test_a_pallet_is_planned_around_rather_than_waited_for():
    free = np.ones((4, 9), dtype=bool)
    paths = plan(free, [(3, 1)], [(8, 1)])
    fc = forecast(free, [Track(0, PALLET, (4, 1), 0)], 1)
    rep = repair(free, paths, fc, 0, 1, budget_s=SLACK)
    assert (4, 1) not in rep.paths[0] and len(rep.paths[0]) == len(paths[0]) + 2


def test_the_window_and_the_forecast_must_cover_the_next_tick():
    free = np.ones((3, 3), dtype=bool)
    paths = {0: [(0, 0), (1, 0)]}
    with pytest.raises(ValueError):
        repair(free, paths, forecast(free, [], 5), 0, 0)
    with pytest.raises(ValueError):
        repair(free, paths, forecast(free, [], 2), 1, 2)


@settings(max_examples=40, deadline=None)
@given(w=st.integers(5, 14), h=st.integers(4, 12), density=st.floats(0.0, 0.25), robots=st.integers(1, 8),
       seed=st.integers(0, 10_000), conn=st.sampled_from([4, 8]), movers=st.integers(1, 5),
       window=st.integers(1, 4), ages=st.lists(st.integers(0, 3), min_size=5, max_size=5))
@example(w=10, h=4, density=0.125, robots=8, seed=4173, conn=4, movers=1, window=1, ages=[3, 0, 0, 0, 0])
def test_repairs_on_random_floors_are_valid_and_enter_no_forecast_cell(w, h, density, robots, seed, conn, movers,
                                                                        window, ages):
    free = random_map(w, h, density, seed)
    try:
        pl = place(free, robots, seed)
    except MapError:
        return
    try:
        paths = plan(free, pl.starts, pl.goals, conn)
    except PlanningError:
        return
    rng = np.random.default_rng(seed)
    tick = int(rng.integers(0, 4))
    taken = set(pl.starts)
    cells = [(int(x), int(y)) for y, x in zip(*np.nonzero(free)) if (int(x), int(y)) not in taken]
    if not cells:
        return
    picks = rng.choice(len(cells), size=min(movers, len(cells)), replace=False)
    tracks = [Track(i, KINDS[i % len(KINDS)], cells[p], tick - ages[i]) for i, p in enumerate(picks)]
    fc = forecast(free, tracks, tick + window)
    rep = repair(free, paths, fc, tick, window, conn, budget_s=SLACK)
    assert not valid(free, rep.paths, conn)
    assert not entries_into_forecast(rep.paths, fc, tick, window)
    assert {r: p[0] for r, p in rep.paths.items()} == {r: p[0] for r, p in paths.items()}
    assert {r: p[-1] for r, p in rep.paths.items()} == {r: p[-1] for r, p in paths.items()}
    if rep.frozen:
        assert rep.held == set(paths) and all(rep.paths[r] == [p[0]] * window + p for r, p in paths.items())
        return
    assert not rep.replanned & rep.held and rep.met <= rep.replanned | rep.held
    for r, p in rep.paths.items():
        if r not in rep.replanned | rep.held:
            assert p is paths[r]
        elif r not in rep.met:
            # the cascade: only robots a held robot needed out of its cell or its old way (that robot may
            # itself have been displaced and replanned later, so it need not be held in the end)
            assert r in rep.displaced, (r, p, paths[r])
    if rep.displaced:
        assert rep.held or rep.replanned - rep.met
    for r in rep.held:
        assert rep.paths[r][: window + 1] == [paths[r][0]] * (window + 1)


# ---- the closed loop: the tracker, the forecast and the repair among the world's movers ----

class SimFloor:
    """`mover_loop.Floor` over the world's movers: an image shows all of them where they are."""

    def __init__(self, free, movers, seed: int):
        self.free, self.movers, self.rng = free, list(movers), np.random.default_rng(seed)

    def look(self):
        return [(m.kind, m.cell) for m in self.movers]

    def step(self, tick, before, after):
        self.movers, ways = step_movers(self.free, self.movers, set(before.values()), self.rng)
        return contacts(tick, before, after, ways)


FLOOR_40 = warehouse(3, 9, shelf_w=8, shelf_h=2, aisle=2, dock=5)      # 40 x 38, 936 free cells


def run_loop(free, robots, kinds, seed, look_every, connectivity=4, window=None):
    pl = place(free, robots, seed)
    planned = plan_mission(free, pl.starts, pl.goals, connectivity=connectivity, seed=seed)
    movers = place_movers(free, kinds, set(pl.starts) | set(planned.goals), np.random.default_rng(seed))
    report = run_among_movers(free, dict(enumerate(planned.paths)), SimFloor(free, movers, seed + 100),
                              look_every=look_every, window=window, connectivity=connectivity, budget_s=1.0)
    assert report.planned_makespan == planned.metrics["makespan"]
    return report


@pytest.fixture(scope="module")
def warm():
    """The kernels compiled (or loaded from numba's cache) before anything is timed."""
    run_loop(FLOOR_40, 4, [PERSON, FORKLIFT], 0, 1)


@pytest.mark.parametrize("floor, name", [(FLOOR_40, "warehouse 40x38"), (None, "warehouse-small")])
@pytest.mark.parametrize("look_every", [1, 2, 4])
def test_among_movers_no_robot_touches_one_and_all_arrive(warm, floor, name, look_every, capsys):
    free = resolve_map(name)[1] if floor is None else floor
    kinds = [PERSON] * 4 + [FORKLIFT] * 2 + ([PALLET] if floor is None else [PERSON, FORKLIFT, PALLET, PALLET])
    lines = []
    for seed in range(3):
        rep = run_loop(free, 20, kinds, seed, look_every)
        assert not rep.contacts, rep.contacts[:3]
        assert not rep.robot_conflicts
        assert rep.makespan is not None, f"seed {seed}: not every robot reached its goal in {rep.ticks} ticks"
        assert not rep.frozen
        lines.append(f"{name}, {len(kinds)} movers, an image every {look_every}: seed {seed} makespan "
                     f"{rep.makespan}/{rep.planned_makespan} = {rep.ratio:.2f}, held {rep.held}, replans "
                     f"{rep.replans} ({rep.replanned} robots), repair median {np.median(rep.repair_ms):.2f} ms")
    with capsys.disabled():
        print("\n" + "\n".join(lines))


def test_among_movers_with_diagonal_moves(warm):
    rep = run_loop(FLOOR_40, 20, [PERSON] * 4 + [FORKLIFT] * 3 + [PALLET], 5, 2, connectivity=8)
    assert not rep.contacts and not rep.robot_conflicts and rep.makespan is not None


@pytest.mark.parametrize("window", [1, 6])
def test_a_window_shorter_or_longer_than_the_images_is_as_safe(warm, window):
    rep = run_loop(FLOOR_40, 20, [PERSON] * 4 + [FORKLIFT] * 3 + [PALLET], 1, 3, window=window)
    assert not rep.contacts and not rep.robot_conflicts and rep.makespan is not None and rep.window == window


# ---- the targets on the paper's 450x450 warehouse (about a second each: in the developer lane) ----

@pytest.fixture(scope="module")
def floor_450():
    return resolve_map("warehouse-450")[1]


def test_a_repair_for_ten_movers_among_fifty_robots_on_the_450_floor_takes_under_50_ms(warm, floor_450, capsys):
    free = floor_450
    times, replanned = [], []
    for seed in range(3):
        pl = place(free, 50, seed)
        paths = dict(enumerate(plan_mission(free, pl.starts, pl.goals, seed=seed).paths))
        rng = np.random.default_rng(seed)
        for trial in range(10):
            # ten movers each seen a few cells ahead of a different robot: ten mover events at once
            taken = {p[0] for p in paths.values()}
            tracks = []
            for i, r in enumerate(rng.choice(50, 10, replace=False)):
                p = paths[int(r)]
                c = p[min(len(p) - 1, int(rng.integers(2, 6)))]
                if c not in taken:
                    taken.add(c)
                    tracks.append(Track(i, (KINDS * 3)[i], c, -int(rng.integers(0, 3))))
            fc = forecast(free, tracks, 4)
            repair(free, paths, fc, 0, 4, budget_s=SLACK)           # warm-up
            rep = repair(free, paths, fc, 0, 4, budget_s=SLACK)
            assert not rep.frozen and rep.met
            assert not entries_into_forecast(rep.paths, fc, 0, 4)
            if trial == 0:
                assert not valid(free, rep.paths)
            times.append(1e3 * rep.seconds)
            replanned.append(len(rep.replanned) + len(rep.held))
    with capsys.disabled():
        print(f"\nrepair, 50 robots, 10 movers, 450 floor: median {np.median(times):.2f} ms, max {max(times):.2f} ms, "
              f"{np.mean(replanned):.1f} robots replanned on average")
    # the 95th percentile rather than the maximum: one preemption of this process on a busy machine
    # is not the repair's time
    assert np.median(times) <= 50.0 and np.percentile(times, 95) <= 50.0


@pytest.mark.parametrize("look_every", [1, 4])
def test_on_the_450_floor_ten_movers_lengthen_the_makespan_by_at_most_30_percent(warm, floor_450, look_every, capsys):
    kinds = [PERSON] * 5 + [FORKLIFT] * 3 + [PALLET] * 2
    t = time.perf_counter()
    rep = run_loop(floor_450, 50, kinds, 0, look_every)
    with capsys.disabled():
        print(f"\n450 floor, 50 robots, 10 movers, an image every {look_every}: makespan {rep.makespan}/"
              f"{rep.planned_makespan} = {rep.ratio:.3f}, held {rep.held}, replans {rep.replans}, repair median "
              f"{np.median(rep.repair_ms):.2f} ms max {max(rep.repair_ms):.2f} ms, {time.perf_counter() - t:.1f} s")
    assert not rep.contacts and not rep.robot_conflicts and rep.makespan is not None and rep.ratio <= 1.3
