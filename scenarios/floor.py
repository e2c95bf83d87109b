"""A mission's floor and where its robots start and must go: the map resolved, the starts and goals
from a MovingAI scenario or placed by the seed. The run's checks and the world build it alike."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocol.mapfile import Cell, read_scen

from .limits import check_floor
from .maps import place, resolve_map


@dataclass(frozen=True)
class Floor:
    name: str
    free: np.ndarray
    starts: list[Cell]
    goals: list[Cell]


def setup_floor(map_spec: str, seed: int, robots: int, scen: str | None = None) -> Floor:
    """One line (MapError) for a map, scenario or fleet that cannot make a mission."""
    name, free = resolve_map(map_spec, seed, check_floor)
    if scen:
        agents = read_scen(scen, free, robots)
        return Floor(name, free, [a.start for a in agents], [a.goal for a in agents])
    placement = place(free, robots, seed)
    return Floor(name, free, list(placement.starts), list(placement.goals))
