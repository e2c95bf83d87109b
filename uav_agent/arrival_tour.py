"""Where and when to confirm arrivals while the fleet still moves.

A robot's Done is believed only once an image taken after its last planned move shows it
on its goal. Such an image need not wait for the whole fleet: each goal lies whole inside
its nearest survey pose's footprint (as `survey.covering` picks it), and that pose is worth
an image as soon as every robot whose goal it holds has made its last move. The UAV flies to
the stop it can shoot soonest while the ticks go on, so that most of the look that used to
follow execution is over when the last robot arrives.
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


def next_stop(remaining: Iterable[Stop], here: tuple[float, float], tick: int, tick_s: float,
              speed_m_s: float) -> Stop | None:
    """The stop whose image can be taken soonest: flying there and its robots' last moves go on
    together, so a stop counts the longer of the two (then the nearer, then the earlier)."""
    def soonest(stop: Stop) -> tuple[float, float, int]:
        fly = math.dist(here, stop.pose[:2]) / speed_m_s
        return max(fly, (stop.ready_tick - tick) * tick_s), fly, stop.ready_tick

    return min(remaining, key=soonest, default=None)
