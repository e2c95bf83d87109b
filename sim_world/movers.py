"""People, forklifts and dropped pallets on the floor: the world's uncooperative movers.

They speak no protocol and announce nothing; they move by their own rules, seeded. A person walks
about one cell per tick along the aisles and stops now and then; a forklift drives up to two cells
per tick and parks in an aisle for a while; a pallet, once dropped, stays where it fell. A mover may
also follow a scripted route (`read_routes`: waypoints walked by the shortest way, dwelling at each).
People and drivers see what stands on the floor (a shelf, a robot, another mover) and never step into it;
they do not see a robot's plan, so a robot that moves into a mover's way meets it. That contact,
and a swap of cells, is the robots' collision, the world's to count (`contacts`).

Pure functions over the floor's free cells: the world steps them once per tick and records them.
"""
from __future__ import annotations

import json
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path

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
    route: tuple[Cell, ...] = ()     # scripted: the waypoints it walks to in turn (empty: its own walk)
    leg: int = 0                     # the waypoint it walks to now
    loop: bool = True                # after the last waypoint, the first again (else it stays there)
    dwell: int = 0                   # ticks it stays at each waypoint
    appears: int = 0                 # the tick it comes onto the floor (a pallet dropped mid-mission)


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


@dataclass
class Fields:
    """Distance fields to waypoints over the free cells, each computed once (a BFS of the floor)."""
    free: np.ndarray
    cache: dict[Cell, np.ndarray] = field(default_factory=dict)

    def to(self, goal: Cell) -> np.ndarray:
        if goal not in self.cache:
            h, w = self.free.shape
            dist = np.full((h, w), -1, np.int32)
            dist[goal[1], goal[0]] = 0
            todo = deque([goal])
            while todo:
                x, y = todo.popleft()
                for dx, dy in STEPS:
                    nx, ny = x + dx, y + dy
                    if 0 <= nx < w and 0 <= ny < h and self.free[ny, nx] and dist[ny, nx] < 0:
                        dist[ny, nx] = dist[y, x] + 1
                        todo.append((nx, ny))
            self.cache[goal] = dist
        return self.cache[goal]


def _scripted(m: Mover, blocked: set[Cell], fields: Fields) -> tuple[Mover, list[Cell]]:
    """A tick of a scripted mover: up to its speed along the shortest way to its waypoint, waiting
    where that way is blocked; at a waypoint it dwells, then takes the next."""
    cur, way = m, []
    for _ in range(SPEED[m.kind]):
        goal = cur.route[cur.leg]
        if cur.cell == goal:
            nxt = cur.leg + 1
            if nxt == len(cur.route) and not cur.loop:
                break
            cur = replace(cur, leg=nxt % len(cur.route), idle=cur.dwell)
            if cur.dwell:
                break
            goal = cur.route[cur.leg]
        dist = fields.to(goal)
        x, y = cur.cell
        here = dist[y, x]
        options = [(x + dx, y + dy) for dx, dy in STEPS
                   if 0 <= y + dy < dist.shape[0] and 0 <= x + dx < dist.shape[1]
                   and dist[y + dy, x + dx] == here - 1 and (x + dx, y + dy) not in blocked]
        if here <= 0 or not options:
            break
        cell = options[0]
        cur = replace(cur, cell=cell, heading=(cell[0] - x, cell[1] - y))
        way.append(cell)
    return cur, way


def step_movers(free: np.ndarray, movers: list[Mover], robots: set[Cell], rng: np.random.Generator,
                rules: MoverRules = MoverRules(), tick: int | None = None, fields: Fields | None = None
                ) -> tuple[list[Mover], dict[int, list[Cell]]]:
    """One tick (`tick`, the one being made; None: every mover is on the floor): the movers after it, and each one's cells on the way (its
    start first) for those on the floor. No mover enters a shelf, a cell a robot stands on at the
    tick's start, or a cell another mover holds. One still to appear comes onto the floor at its tick
    unless a mover holds its cell or a robot stands on it or next to it (then it waits a tick): goods
    never fall onto a robot nor into the cell a robot steps into."""
    held = {m.cell for m in movers if tick is None or m.appears < tick}
    out: list[Mover] = []
    ways: dict[int, list[Cell]] = {}
    for m in movers:
        if tick is not None and m.appears >= tick:
            x, y = m.cell
            near = any((x + dx, y + dy) in robots for dx in (-1, 0, 1) for dy in (-1, 0, 1))
            if m.appears == tick and (m.cell in held or near):
                m = replace(m, appears=tick + 1)
            elif m.appears == tick:
                held.add(m.cell)
                ways[m.id] = [m.cell]
            out.append(m)
            continue
        way = [m.cell]
        if m.kind == PALLET:
            out.append(m)
        elif m.idle > 0:
            out.append(replace(m, idle=m.idle - 1))
        elif m.route:
            cur, more = _scripted(m, (held - {m.cell}) | robots, fields or Fields(free))
            held.discard(m.cell)
            held.add(cur.cell)
            way += more
            out.append(cur)
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


def read_routes(path: str | Path, free: np.ndarray, first_id: int = 0) -> list[Mover]:
    """The scripted movers of a routes file (docs/movers.md): `{"movers": [{"kind": "person", "route":
    [[x, y], ...], "loop": true, "dwell": 0, "tick": 0}, {"kind": "pallet", "at": [x, y], "tick": 40}]}`;
    a mover stands on its first waypoint (a pallet at `at`) from `tick` on. One line naming the file
    and the entry for anything a floor cannot take."""
    name = Path(path).name
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise MapError(f"routes {name}: not a JSON file ({str(exc)[:80]})") from None
    entries = data.get("movers") if isinstance(data, dict) else None
    if not isinstance(entries, list):
        raise MapError(f"routes {name}: expected {{\"movers\": [...]}}")
    h, w = free.shape

    def cell(v: object, where: str) -> Cell:
        if not (isinstance(v, list) and len(v) == 2 and all(isinstance(c, int) and not isinstance(c, bool) for c in v)):
            raise MapError(f"routes {name}: {where} is not [x, y] of whole numbers")
        c = (int(v[0]), int(v[1]))
        if not _free(free, c):
            raise MapError(f"routes {name}: {where} {list(c)} is {'off the %dx%d floor' % (w, h) if not on_grid(*c, w, h) else 'a shelf'}")
        return c

    def whole(v: object, where: str, lo: int = 0) -> int:
        if not isinstance(v, int) or isinstance(v, bool) or v < lo:
            raise MapError(f"routes {name}: {where} is not a whole number >= {lo}")
        return int(v)

    out: list[Mover] = []
    for i, e in enumerate(entries):
        where = f"mover {i}"
        if not isinstance(e, dict) or e.get("kind") not in SPEED:
            raise MapError(f"routes {name}: {where} needs a kind, one of {', '.join(SPEED)}")
        kind, tick = e["kind"], whole(e.get("tick", 0), f"{where}'s tick")
        if kind == PALLET:
            out.append(Mover(first_id + i, kind, cell(e.get("at"), f"{where}'s at"), appears=tick))
            continue
        route = e.get("route")
        if not isinstance(route, list) or not route:
            raise MapError(f"routes {name}: {where} needs a route of waypoints [[x, y], ...]")
        cells = tuple(cell(c, f"{where}'s waypoint {j}") for j, c in enumerate(route))
        fields = Fields(free)
        for j in range(1, len(cells)):
            if fields.to(cells[j])[cells[j - 1][1], cells[j - 1][0]] < 0:
                raise MapError(f"routes {name}: {where}'s waypoint {j} {list(cells[j])} cannot be reached from "
                               f"{list(cells[j - 1])}")
        out.append(Mover(first_id + i, kind, cells[0], route=cells, leg=min(1, len(cells) - 1),
                         loop=bool(e.get("loop", True)), dwell=whole(e.get("dwell", 0), f"{where}'s dwell"),
                         appears=tick))
    starts = [m.cell for m in out if m.appears == 0]
    if len(set(starts)) < len(starts):
        raise MapError(f"routes {name}: two movers start on one cell")
    return out
