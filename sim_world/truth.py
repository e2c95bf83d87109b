"""The ground truth a world starts from: the floor, where every robot stands, the goals."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocol.mapfile import Cell, read_scen
from scenarios.limits import check_floor
from scenarios.maps import place, resolve_map

from .config import WorldConfig

@dataclass(frozen=True)
class Truth:
    name: str
    free: np.ndarray
    starts: dict[int, Cell]
    goals: list[Cell]


def build_truth(cfg: WorldConfig) -> Truth:
    name, free = resolve_map(cfg.map, cfg.seed, check_floor)
    if cfg.scen:
        agents = read_scen(cfg.scen, free, cfg.robots)
        starts, goals = [a.start for a in agents], [a.goal for a in agents]
    else:
        placement = place(free, cfg.robots, cfg.seed)
        starts, goals = placement.starts, placement.goals
    return Truth(name, free, {i: c for i, c in enumerate(starts)}, list(goals))
