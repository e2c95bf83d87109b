"""People, forklifts and dropped pallets on the floor: the world's uncooperative movers.

They speak no protocol and announce nothing; they move by their own rules, seeded. A person walks
about one cell per tick along the aisles and stops now and then; a forklift drives up to two cells
per tick and parks in an aisle for a while; a pallet, once dropped, stays where it fell. People and
drivers see what stands on the floor (a shelf, a robot, another mover) and never step into it;
they do not see a robot's plan, so a robot that moves into a mover's way meets it. That contact,
and a swap of cells, is the robots' collision, the world's to count (`contacts`).

Pure functions over the floor's free cells: the world steps them once per tick and records them.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from protocol.errors import MapError
from protocol.grid import Cell, on_grid

PERSON, FORKLIFT, PALLET = "person", "forklift", "pallet"
SPEED = {PERSON: 1, FORKLIFT: 2, PALLET: 0}          # cells per tick, at most
STEPS: tuple[Cell, ...] = ((1, 0), (0, 1), (-1, 0), (0, -1))


@dataclass(frozen=True)
class MoverRules:
    keep_heading: float = 0.85       # a walk goes on straight when it can: aisles are walked along
    pause: float = 0.05              # per tick, a person stops for a few ticks (a look at a shelf)
    pause_ticks: tuple[int, int] = (2, 6)
    park: float = 0.02               # per tick, a forklift parks in the aisle it is in
    park_ticks: tuple[int, int] = (10, 40)


@dataclass(frozen=True)
class Mover:
    id: int
    kind: str
    cell: Cell
    heading: Cell = (1, 0)           # its last step's direction
    idle: int = 0                    # ticks it still stays where it is (a pause, a parked forklift)


@dataclass(frozen=True)
class Contact:
    tick: int
    robot: int
    mover: int
    cell: Cell
    how: str                         # "same cell" or "swap"


def _free(free: np.ndarray, c: Cell) -> bool:
    h, w = free.shape
    return on_grid(c[0], c[1], w, h) and bool(free[c[1], c[0]])


def _step(free: np.ndarray, m: Mover, blocked: set[Cell], rng: np.random.Generator,
          rules: MoverRules) -> tuple[Cell, Cell]:
    """One cell of a walk from `m.cell`: straight on with `keep_heading` when open, else a random open
    neighbour (back only when nothing else is open); (cell, heading), the same cell when boxed in."""
    x, y = m.cell
    def open_(d: Cell) -> bool:
        return _free(free, (x + d[0], y + d[1])) and (x + d[0], y + d[1]) not in blocked
    if open_(m.heading) and rng.random() < rules.keep_heading:
        d = m.heading
    else:
        back = (-m.heading[0], -m.heading[1])
        options = [d for d in STEPS if open_(d) and d != back] or [d for d in STEPS if open_(d)]
        if not options:
            return m.cell, m.heading
        d = options[int(rng.integers(len(options)))]
    return (x + d[0], y + d[1]), d


def step_movers(free: np.ndarray, movers: list[Mover], robots: set[Cell], rng: np.random.Generator,
                rules: MoverRules = MoverRules()) -> tuple[list[Mover], dict[int, list[Cell]]]:
    """One tick: the movers after it, and each one's cells on the way (its start first). No mover
    enters a shelf, a cell a robot stands on at the tick's start, or a cell another mover holds."""
    held = {m.cell for m in movers}
    out: list[Mover] = []
    ways: dict[int, list[Cell]] = {}
    for m in movers:
        way = [m.cell]
        if m.kind == PALLET:
            out.append(m)
        elif m.idle > 0:
            out.append(replace(m, idle=m.idle - 1))
        elif m.kind == PERSON and rng.random() < rules.pause:
            out.append(replace(m, idle=int(rng.integers(*rules.pause_ticks))))
        elif m.kind == FORKLIFT and rng.random() < rules.park:
            out.append(replace(m, idle=int(rng.integers(*rules.park_ticks))))
        else:
            cur = m
            blocked = (held - {m.cell}) | robots
            for _ in range(SPEED[m.kind]):
                cell, heading = _step(free, cur, blocked, rng, rules)
                if cell == cur.cell:
                    break
                cur = replace(cur, cell=cell, heading=heading)
                way.append(cell)
            held.discard(m.cell)
            held.add(cur.cell)
            out.append(cur)
        ways[m.id] = way
    return out, ways


def contacts(tick: int, before: dict[int, Cell], after: dict[int, Cell], ways: dict[int, list[Cell]]) -> list[Contact]:
    """The tick's robot-mover contacts: a robot ending on a cell a mover passed through or stopped on,
    or a robot and a mover trading cells (either way along the mover's path)."""
    out = []
    for r, cell in after.items():
        for mid, way in ways.items():
            if cell in way[1:] or cell == way[0] == way[-1]:
                out.append(Contact(tick, r, mid, cell, "same cell"))
            elif before.get(r) in way[1:] and cell in way[:-1]:
                out.append(Contact(tick, r, mid, cell, "swap"))
    return out


def near_misses(robots: dict[int, Cell], movers: list[Mover]) -> list[tuple[int, int]]:
    """(robot, mover) pairs within one cell of each other (8 neighbours) without touching."""
    return [(r, m.id) for r, (x, y) in robots.items() for m in movers
            if max(abs(x - m.cell[0]), abs(y - m.cell[1])) == 1]


def place_movers(free: np.ndarray, kinds: list[str], taken: set[Cell], rng: np.random.Generator) -> list[Mover]:
    """Movers of `kinds` on distinct free cells that no robot or goal holds (seeded)."""
    cells = [c for c in zip(*np.nonzero(free.T)) if (int(c[0]), int(c[1])) not in taken]
    if len(cells) < len(kinds):
        raise MapError(f"{len(kinds)} movers need {len(kinds)} free cells besides the robots' and goals'; "
                         f"the floor has {len(cells)}")
    picks = rng.choice(len(cells), size=len(kinds), replace=False)
    return [Mover(i, k, (int(cells[p][0]), int(cells[p][1]))) for i, (k, p) in enumerate(zip(kinds, picks))]
