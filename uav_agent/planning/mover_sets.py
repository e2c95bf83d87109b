"""Where the movers may be, as sets of cells: what the forecast closes when the UAV sees only part
of the floor at a time.

One set per kind (a person, a forklift, a pallet): the cells a mover of that kind may stand on
after the last tick. Between images each set grows by the kind's speed every tick, in 4-connected
steps over free cells (a mover never enters a shelf). An image rules out what it shows: in the
cells it saw, a kind's set becomes exactly the cells it saw that kind on, and outside them the
set stays as it was. No sighting has to be matched to a track, so a partial view is exact: a mover
that walked out of view is still somewhere in the grown set, and a region looked at again is
cleared of every mover it does not show, however long ago the floor was seen whole. The tracks
(`forecast.Tracker`) say who is who and how fast it went; these sets say where nobody can be.

A kind that perception could not tell is taken as the fastest (`forecast.UNKNOWN`). Everything
rests on the camera seeing what is there: a mover missed in an image is ruled out where it
stands (the perception's tests find every mover at 6.6 px per cell and more).
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.ndimage import binary_dilation

from .forecast import SPEED, Forecast, Reach, speed_of
from .types import Cell

CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool)


def grown(mask: np.ndarray, free: np.ndarray, steps: int) -> np.ndarray:
    """`mask` and every free cell within `steps` 4-connected steps of it over free cells."""
    if steps <= 0 or not mask.any():
        return mask.copy()
    return binary_dilation(mask, structure=CROSS, iterations=steps, mask=free) | mask


@dataclass
class MoverSets:
    free: np.ndarray
    speeds: Mapping[str, int] = field(default_factory=lambda: dict(SPEED))
    tick: int = 0
    sets: dict[str, np.ndarray] = field(default_factory=dict)      # kind -> bool [h, w] after `tick`
    seen_on: dict[Cell, tuple[str, int]] = field(default_factory=dict)   # the last look's movers: cell -> (kind, tick)

    def __post_init__(self) -> None:
        self.free = np.asarray(self.free, dtype=bool)
        for kind in self.speeds:
            self.sets.setdefault(kind, np.zeros_like(self.free))

    def advance(self, tick: int) -> None:
        """The sets after `tick`: each grown by its kind's speed for every tick since the last."""
        if tick < self.tick:
            raise ValueError(f"tick {tick} is before tick {self.tick}: the sets only go forward")
        for kind, s in self.sets.items():
            self.sets[kind] = grown(s, self.free, (tick - self.tick) * self.speeds[kind])
        self.tick = tick

    def look(self, tick: int, sightings: Iterable[Any], seen: np.ndarray | None = None) -> None:
        """An image taken after `tick`: the cells it `seen` (bool [h, w]; None: the whole floor) hold
        exactly the movers it shows (anything with .kind and .cell, or (kind, cell) pairs)."""
        self.advance(tick)
        shown = seen if seen is not None else np.ones_like(self.free)
        for kind in self.sets:
            self.sets[kind] &= ~shown
        fastest = max(self.speeds, key=lambda k: self.speeds[k])
        self.seen_on = {}
        for s in sightings:
            kind, cell = (s.kind, s.cell) if hasattr(s, "kind") else (s[0], s[1])
            kind = kind if kind in self.sets else fastest      # UNKNOWN, or a kind without a speed: the fastest
            x, y = int(cell[0]), int(cell[1])
            self.sets[kind][y, x] = True
            self.seen_on[(x, y)] = (kind, tick)

    def possible(self) -> np.ndarray:
        """bool [h, w]: the cells some mover may stand on now."""
        out = np.zeros_like(self.free)
        for s in self.sets.values():
            out |= s
        return out

    def forecast(self, until: int) -> Forecast:
        """The cells a mover may occupy or pass during each tick up to `until`, for the repair: a cell
        closes at the first tick after `self.tick` a mover may be on it, and stays closed."""
        h, w = self.free.shape
        first = np.full((h, w), np.iinfo(np.int64).max, dtype=np.int64)
        for kind, s in self.sets.items():
            first[s] = np.minimum(first[s], self.tick)
            if self.speeds[kind] == 0:
                continue
            cur = s
            for t in range(self.tick + 1, until + 1):
                nxt = grown(cur, self.free, self.speeds[kind])
                new = nxt & ~cur
                first[new] = np.minimum(first[new], t)
                cur = nxt
        flat = np.flatnonzero(first <= until).astype(np.int64)
        # The movers the last look showed, their speeds: the repair keeps each one's own cell closed a
        # while past the window (a pallet, a parked forklift), as a preference.
        reaches = tuple(Reach(i, kind, cell, seen, speed_of(kind, self.speeds), cell, np.zeros((0, 0), np.int32))
                        for i, (cell, (kind, seen)) in enumerate(sorted(self.seen_on.items())))
        return Forecast((h, w), int(until), reaches, flat, first.ravel()[flat])

