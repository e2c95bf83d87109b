"""The ground truth a world starts from: the floor, where every robot stands, the goals."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocol.mapfile import Cell
from scenarios.floor import setup_floor

from .config import WorldConfig

@dataclass(frozen=True)
class Truth:
    name: str
    free: np.ndarray
    starts: dict[int, Cell]
    goals: list[Cell]


def build_truth(cfg: WorldConfig) -> Truth:
    floor = setup_floor(cfg.map, cfg.seed, cfg.robots, cfg.scen)
    return Truth(floor.name, floor.free, dict(enumerate(floor.starts)), floor.goals)
