"""Where and when to confirm arrivals while the fleet still moves.

A robot's Done is believed only once an image taken after its last planned move shows it
on its goal. Such an image need not wait for the whole fleet: each goal lies whole inside
its nearest survey pose's footprint (as `survey.covering` picks it), and that pose is worth
an image as soon as every robot whose goal it holds has made its last move. The UAV flies the
`route` through these stops that confirms the last of them soonest while the ticks go on, so
that most of the look that used to follow execution is over when the last robot arrives (a
stop shot merely soonest can leave an early one for after the last tick, one more hop).
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from protocol.grid import Cell

from .survey import SurveyPose


@dataclass(frozen=True)
class Stop:
    pose: SurveyPose
    ready_tick: int            # the first tick after which every robot in `robots` stays on its goal
    robots: frozenset[int]


def arrival_ticks(paths: Mapping[int, Sequence[Cell]], start_tick: int) -> dict[int, int]:
    """Robot -> the tick of its last move: from then on it holds its path's last cell.
    A robot may pass its goal and come back (to let another by): only the last arrival counts."""
    out = {}
    for r, path in paths.items():
        last = tuple(path[-1])
        i = len(path) - 1
        while i > 0 and tuple(path[i - 1]) == last:
            i -= 1
        out[r] = start_tick + i
    return out


def stops(poses: Sequence[SurveyPose], goals: Mapping[int, Cell], arrivals: Mapping[int, int],
          cell_size_m: float) -> list[Stop]:
    """The poses that hold the `goals` (robot -> cell), each with the robots it confirms."""
    held: dict[int, set[int]] = {}
    for r, (x, y) in goals.items():
        north, east = -(y + 0.5) * cell_size_m, (x + 0.5) * cell_size_m
        i = min(range(len(poses)), key=lambda j: math.hypot(poses[j][0] - north, poses[j][1] - east))
        held.setdefault(i, set()).add(r)
    return [Stop(poses[i], max(arrivals[r] for r in robots), frozenset(robots)) for i, robots in sorted(held.items())]


EXACT_STOPS = 10            # up to this many stops the route is the best one (10 * 2**10 states, ~15 ms)
ROUTE_EVALUATIONS = 4000    # beyond, orders tried by local search: a survey's poses settle in a few hundred


def route(remaining: Iterable[Stop], here: tuple[float, float], tick: int, tick_s: float,
          speed_m_s: float) -> list[Stop]:
    """The order to shoot `remaining` in that confirms the last of them soonest: flying and the
    robots' last moves go on together, so a stop is shot at the later of arriving there and its
    `ready_tick`. A tour with release times: solved exactly over subsets for a few stops, by
    local search (moving one stop, reversing a stretch) from the order of readiness and the
    greedy order for more."""
    stops = sorted(remaining, key=lambda s: (s.ready_tick, s.pose))
    if len(stops) < 2:
        return stops
    ready = [(s.ready_tick - tick) * tick_s for s in stops]
    where = [s.pose[:2] for s in stops]
    if len(stops) <= EXACT_STOPS:
        return [stops[i] for i in _best_order(here, where, ready, speed_m_s)]
    return _improved(stops, here, tick, tick_s, speed_m_s)


def _best_order(here, where, ready, speed_m_s: float) -> list[int]:
    """Held-Karp over (stops shot, last one): the earliest time each state can be reached."""
    n = len(where)
    fly = [[math.dist(a, b) / speed_m_s for b in where] for a in where]
    best: dict[tuple[int, int], tuple[float, int]] = {}
    for i in range(n):
        best[1 << i, i] = (max(math.dist(here, where[i]) / speed_m_s, ready[i]), -1)
    for mask in range(1, 1 << n):
        for last in range(n):
            got = best.get((mask, last))
            if got is None:
                continue
            t = got[0]
            for j in range(n):
                if mask & (1 << j):
                    continue
                key, tj = (mask | 1 << j, j), max(t + fly[last][j], ready[j])
                if key not in best or tj < best[key][0]:
                    best[key] = (tj, last)
    full = (1 << n) - 1
    last = min(range(n), key=lambda i: best[full, i][0])
    order, mask = [], full
    while last >= 0:
        order.append(last)
        last, mask = best[mask, last][1], mask & ~(1 << last)
    return order[::-1]


def _improved(stops: list[Stop], here: tuple[float, float], tick: int, tick_s: float,
              speed_m_s: float) -> list[Stop]:
    def cost(order: Sequence[Stop]) -> tuple[float, float]:
        t, total, at = 0.0, 0.0, here
        for s in order:
            t = max(t + math.dist(at, s.pose[:2]) / speed_m_s, (s.ready_tick - tick) * tick_s)
            total += t
            at = s.pose[:2]
        return t, total   # then the earlier confirmations: less for an estimate's error to spoil

    greedy, at, t, left = [], here, 0.0, list(stops)
    while left:   # the stop that can be shot soonest; of those ready alike (waiting for it), the nearest
        s = min(left, key=lambda s: (max(t + math.dist(at, s.pose[:2]) / speed_m_s, (s.ready_tick - tick) * tick_s),
                                     math.dist(at, s.pose[:2])))
        t = max(t + math.dist(at, s.pose[:2]) / speed_m_s, (s.ready_tick - tick) * tick_s)
        at = s.pose[:2]
        greedy.append(s)
        left.remove(s)
    best = min((stops, greedy), key=cost)
    best_cost, budget, n = cost(best), ROUTE_EVALUATIONS, len(stops)
    improved = True
    while improved and budget > 0:
        improved = False
        for i in range(n):
            for j in range(n):
                if i == j or budget <= 0:
                    continue
                moved = best[:i] + best[i + 1:]
                moved.insert(j, best[i])
                reversed_ = best[:min(i, j)] + best[min(i, j):max(i, j) + 1][::-1] + best[max(i, j) + 1:]
                for order in (moved, reversed_):
                    budget -= 1
                    c = cost(order)
                    if c < best_cost:
                        best, best_cost, improved = order, c, True
    return best


def next_stop(remaining: Iterable[Stop], here: tuple[float, float], tick: int, tick_s: float,
              speed_m_s: float) -> Stop | None:
    """The first stop of the `route` through the stops left."""
    order = route(remaining, here, tick, tick_s, speed_m_s)
    return order[0] if order else None
