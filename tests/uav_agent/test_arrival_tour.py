"""Where and when arrivals are confirmed during execution: pure functions, no network."""
from hypothesis import given, strategies as st

import itertools
import math

from uav_agent.arrival_tour import Stop, arrival_ticks, next_stop, route, stops
from uav_agent.survey import SurveyPose


def test_arrival_is_the_last_move_not_the_first_visit():
    paths = {
        0: [(0, 0), (1, 0), (2, 0)],                    # straight there: tick 2
        1: [(5, 5), (5, 6), (5, 5), (5, 6), (5, 6)],    # passes its goal, leaves, comes back: tick 3
        2: [(7, 7)],                                    # starts on its goal
        3: [(3, 3), (3, 3), (3, 4)],                    # waits, then moves: tick 2
    }
    assert arrival_ticks(paths, 0) == {0: 2, 1: 3, 2: 0, 3: 2}
    assert arrival_ticks(paths, 40) == {0: 42, 1: 43, 2: 40, 3: 42}


@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 3)), min_size=1, max_size=30), st.integers(0, 500))
def test_a_robot_holds_its_last_cell_from_its_arrival_on(path, start):
    k = arrival_ticks({0: path}, start)[0]
    assert start <= k <= start + len(path) - 1
    assert all(c == path[-1] for c in path[k - start:])
    assert k == start or path[k - start - 1] != path[-1]


POSES = [SurveyPose(-5.0, 5.0, 20.0), SurveyPose(-5.0, 15.0, 20.0), SurveyPose(-15.0, 5.0, 20.0)]


def test_each_goal_is_confirmed_by_its_nearest_pose_once_all_its_robots_have_arrived():
    goals = {0: (4, 4), 1: (6, 3), 2: (14, 5), 3: (3, 14)}    # (x, y) cells of 1 m: east = x, north = -y
    arrivals = {0: 10, 1: 30, 2: 5, 3: 70}
    got = {s.pose: s for s in stops(POSES, goals, arrivals, 1.0)}
    assert got[POSES[0]] == Stop(POSES[0], 30, frozenset({0, 1}))
    assert got[POSES[1]] == Stop(POSES[1], 5, frozenset({2}))
    assert got[POSES[2]] == Stop(POSES[2], 70, frozenset({3}))
    assert stops(POSES, {}, {}, 1.0) == []


def test_the_next_stop_is_the_one_shot_soonest():
    near_late = Stop(POSES[0], 100, frozenset({0}))
    far_ready = Stop(POSES[2], 0, frozenset({1}))
    here = (-5.0, 5.0)
    # 10 m at 10 m/s is 1 s; 90 ticks of 0.05 s are 4.5 s: the far stop that is ready goes first.
    assert next_stop([near_late, far_ready], here, 10, 0.05, 10.0) is far_ready
    # Ticks ten times faster: the near one is ready in 0.45 s, before the vehicle would reach the far one.
    assert next_stop([near_late, far_ready], here, 10, 0.005, 10.0) is near_late
    assert next_stop([], here, 0, 0.05, 10.0) is None


def _finish(order, here, tick, tick_s, speed):
    t, at = 0.0, here
    for s in order:
        t = max(t + math.dist(at, s.pose[:2]) / speed, (s.ready_tick - tick) * tick_s)
        at = s.pose[:2]
    return t


def test_the_route_looks_past_the_nearest_stop():
    # Ready now 1 m east and 10 m west, and one 20 m east ready at 30 s: the nearest first
    # (1 + 11, then 31 m to the last: 43 s) loses to west first (10 + 11 + 19 = 40 s).
    here = (0.0, 0.0)
    east, west = Stop(SurveyPose(0.0, 1.0, 20.0), 0, frozenset({0})), Stop(SurveyPose(0.0, -10.0, 20.0), 0, frozenset({1}))
    late = Stop(SurveyPose(0.0, 20.0, 20.0), 300, frozenset({2}))
    order = route([east, west, late], here, 0, 0.1, 1.0)
    assert order == [west, east, late]
    assert next_stop([east, west, late], here, 0, 0.1, 1.0) is west


@given(st.lists(st.tuples(st.integers(-50, 50), st.integers(-50, 50), st.integers(0, 200)), min_size=1, max_size=6,
                unique_by=lambda t: t[:2]),
       st.integers(0, 100), st.floats(0.01, 0.2))
def test_a_route_through_a_few_stops_is_the_best_order(points, tick, tick_s):
    remaining = [Stop(SurveyPose(float(n), float(e), 20.0), r, frozenset({i})) for i, (n, e, r) in enumerate(points)]
    order = route(remaining, (0.0, 0.0), tick, tick_s, 10.0)
    assert len(order) == len(remaining) and set(order) == set(remaining)
    best = min(_finish(p, (0.0, 0.0), tick, tick_s, 10.0) for p in itertools.permutations(remaining))
    assert _finish(order, (0.0, 0.0), tick, tick_s, 10.0) <= best + 1e-9


@given(st.lists(st.tuples(st.integers(-300, 300), st.integers(-300, 300), st.integers(0, 250)), min_size=11,
                max_size=16, unique_by=lambda t: t[:2]),
       st.floats(0.01, 0.1))
def test_a_route_through_many_stops_beats_both_simple_orders(points, tick_s):
    remaining = [Stop(SurveyPose(float(n), float(e), 85.0), r, frozenset({i})) for i, (n, e, r) in enumerate(points)]
    order = route(remaining, (0.0, 0.0), 0, tick_s, 150.0)
    assert len(order) == len(remaining) and set(order) == set(remaining)
    by_readiness = sorted(remaining, key=lambda s: (s.ready_tick, s.pose))
    greedy, left, t = [], list(by_readiness), 0.0   # always the stop that can be shot soonest (the nearest of equals)
    while left:
        at = greedy[-1].pose[:2] if greedy else (0.0, 0.0)
        greedy.append(min(left, key=lambda s: (max(t + math.dist(at, s.pose[:2]) / 150.0, s.ready_tick * tick_s),
                                               math.dist(at, s.pose[:2]))))
        t = max(t + math.dist(at, greedy[-1].pose[:2]) / 150.0, greedy[-1].ready_tick * tick_s)
        left.remove(greedy[-1])
    assert _finish(order, (0.0, 0.0), 0, tick_s, 150.0) <= min(
        _finish(by_readiness, (0.0, 0.0), 0, tick_s, 150.0), _finish(greedy, (0.0, 0.0), 0, tick_s, 150.0)) + 1e-9
