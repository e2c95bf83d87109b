"""The movers of one world through its ticks: stepped with the robots' moves, recorded, and every
robot-mover contact and near miss counted. The judge (`moves.py`) calls `step` once per tick it
resolves; the camera draws `on_floor()`; the record carries `as_dict()`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from protocol.grid import Cell
from protocol.run_spec import SceneSpec

from protocol.bounds import MAX_MOVERS
from protocol.errors import MapError

from .movers import (FORKLIFT, PALLET, PERSON, Contact, Fields, Mover, MoverRules, contacts, near_misses, place_movers,
                     read_routes, step_movers)


@dataclass
class Traffic:
    free: np.ndarray
    movers: list[Mover]
    seed: int = 0
    rules: MoverRules = field(default_factory=MoverRules)
    trace: dict[int, list[Cell]] = field(default_factory=dict)   # mover -> its cell after every tick from 0
    touched: list[Contact] = field(default_factory=list)
    near_misses: int = 0          # a robot coming within one cell of a mover (each approach once)
    near_miss_ticks: int = 0      # (robot, mover) pairs within one cell, summed over the ticks
    tick: int = 0

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng([self.seed, 32])   # its own stream: the robots' slips stay as they were
        self._fields = Fields(self.free)
        self._near: set[tuple[int, int]] = set()
        self.trace = {m.id: [m.cell] for m in self.movers}

    def on_floor(self, tick: int | None = None) -> list[Mover]:
        """The movers standing on the floor after `tick` (the last stepped)."""
        t = self.tick if tick is None else tick
        return [m for m in self.movers if m.appears <= t]

    def step(self, tick: int, before: dict[int, Cell], after: dict[int, Cell]) -> list[Contact]:
        """Tick `tick`: the movers step while the robots go from `before` to `after` (ticks skipped
        since the last one are ticks the robots stood still). Returns the tick's contacts."""
        out: list[Contact] = []
        for t in range(self.tick + 1, tick + 1):
            robots_after = after if t == tick else before
            self.movers, ways = step_movers(self.free, self.movers, set(before.values()), self._rng, self.rules, t,
                                            self._fields)
            out += contacts(t, before, robots_after, ways)
            for m in self.movers:
                self.trace[m.id].append(m.cell)
            near = set(near_misses(robots_after, self.on_floor(t)))
            self.near_misses += len(near - self._near)
            self.near_miss_ticks += len(near)
            self._near = near
            self.tick = t
        self.touched += out
        return out

    def as_dict(self) -> dict[str, Any]:
        return {"movers": [{"id": m.id, "kind": m.kind, "appears": m.appears, "scripted": bool(m.route)}
                           for m in self.movers],
                "trace": {str(i): [list(c) for c in cells] for i, cells in sorted(self.trace.items())},
                "contacts": [{"tick": c.tick, "robot": c.robot, "mover": c.mover, "cell": list(c.cell), "how": c.how}
                             for c in self.touched],
                "near_misses": self.near_misses, "near_miss_ticks": self.near_miss_ticks}


def build_traffic(scene: SceneSpec, free: np.ndarray, starts: list[Cell], goals: list[Cell], seed: int) -> Traffic | None:
    """The scene's movers (None: it has none): the seeded ones on free cells no robot starts on and
    no goal is, then the routes file's (MapError: one line)."""
    if not scene.movers:
        return None
    kinds = [PERSON] * scene.people + [FORKLIFT] * scene.forklifts + [PALLET] * scene.pallets
    scripted = read_routes(scene.routes, free, len(kinds)) if scene.routes else []
    for m in scripted:
        if m.appears == 0 and m.cell in set(starts):
            raise MapError(f"routes: mover {m.id - len(kinds)} starts on {list(m.cell)}, where robot "
                           f"{starts.index(m.cell)} starts")
    if len(kinds) + len(scripted) > MAX_MOVERS:
        raise MapError(f"{len(kinds) + len(scripted)} movers: at most {MAX_MOVERS} on one floor")
    taken = set(starts) | set(goals) | {m.cell for m in scripted}
    movers = place_movers(free, kinds, taken, np.random.default_rng([seed, 31])) + scripted
    return Traffic(free, movers, seed)
