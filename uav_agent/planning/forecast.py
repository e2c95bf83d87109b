"""Where the floor's uncooperative movers (people, forklifts, dropped pallets) may be: tracks
from the camera's sightings, and a forecast of the cells each may reach.

The UAV sees movers only in its images, a few ticks apart, each showing them at the tick it
was taken. Nothing says where a mover goes next, so the forecast is a worst case: a mover
last seen k ticks ago may be on any cell within k x its speed (cells per tick: a person 1,
a forklift 2, a pallet 0; an unknown kind the fastest), counted in 4-connected steps over
the floor's free cells (a mover never enters a shelf; robots, which it does not enter
either, are ignored: fewer cells, so the forecast would only shrink). During tick t a mover
may pass through, or stop on, any cell within (t - seen) x speed of where it was seen, so
"cell c closed at t" is `dist[c] <= (t - seen) * speed`: a cell closes at tick
seen + ceil(dist / speed) and stays closed for the rest of the horizon, one interval per
cell, the shape SIPP's safe intervals take (`mapf/dynamic.py`).

The tracker folds each image's sightings into tracks: a sighting is matched (Hungarian,
`scipy.optimize.linear_sum_assignment`) to a track of a compatible kind that could have
walked there since it was seen (breadth-first distance over the free cells within its
reach), nearest to where the track's velocity puts it; an unmatched sighting starts a
track. A track that an image should have shown and did not (its whole reachable area was
in view) is a miss. What is safe then: keeping it, its area growing, costs only detours;
dropping it trusts the camera. It is kept for one more image and dropped on the second miss
in a row (a person that left the floor, a false sighting), and every drop is reported
(`Update.dropped`, `Tracker.dropped`), never silent. A track outside the image's view is
kept as it is: unseen is not absent.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from .types import Cell

PERSON, FORKLIFT, PALLET, UNKNOWN = "person", "forklift", "pallet", "unknown"
SPEED: Mapping[str, int] = {PERSON: 1, FORKLIFT: 2, PALLET: 0}   # cells per tick, at most
MISS_LIMIT = 2            # misses in a row (images that should have shown a track) before it is dropped
_FAR = 1e9                # the assignment's cost of an impossible match


def speed_of(kind: str, speeds: Mapping[str, int] = SPEED) -> int:
    """Cells per tick: the kind's, the fastest known for a kind nobody told us about."""
    return speeds[kind] if kind in speeds else max(speeds.values())


def reach_field(free: np.ndarray, cell: Cell, radius: int) -> tuple[Cell, np.ndarray]:
    """4-connected steps over free cells from `cell`, up to `radius`, in the window around it:
    ((x0, y0) the window's corner, int32 [rows, cols] with -1 beyond the radius or walled off).

    Grown one ring at a time with array shifts: a window of (2r+1)^2 cells and r rounds, which
    for the few tens of cells a mover covers between two images is cheaper than a queue."""
    h, w = free.shape
    x, y = int(cell[0]), int(cell[1])
    r = max(int(radius), 0)
    x0, x1 = max(0, x - r), min(w, x + r + 1)
    y0, y1 = max(0, y - r), min(h, y + r + 1)
    sub = free[y0:y1, x0:x1]
    dist = np.full(sub.shape, -1, dtype=np.int32)
    if not (0 <= x < w and 0 <= y < h):
        return (x0, y0), dist
    dist[y - y0, x - x0] = 0
    front = np.zeros(sub.shape, dtype=bool)
    front[y - y0, x - x0] = True
    reached = front.copy()
    step = np.empty_like(front)
    for d in range(1, r + 1):
        step[...] = False
        step[1:, :] |= front[:-1, :]
        step[:-1, :] |= front[1:, :]
        step[:, 1:] |= front[:, :-1]
        step[:, :-1] |= front[:, 1:]
        step &= sub
        step &= ~reached
        if not step.any():
            break
        dist[step] = d
        reached |= step
        front, step = step, front
    return (x0, y0), dist


@dataclass(frozen=True)
class Sighting:
    kind: str
    cell: Cell


@dataclass(frozen=True)
class Track:
    id: int
    kind: str
    cell: Cell                        # where it was last seen
    seen: int                         # the tick of that image
    velocity: tuple[float, float] = (0.0, 0.0)   # cells per tick between its last two sightings
    misses: int = 0                   # images in a row that should have shown it and did not


@dataclass(frozen=True)
class Update:
    """What one image did to the tracks."""
    tick: int
    matched: tuple[tuple[int, Cell], ...]     # (track, the cell it was seen on)
    new: tuple[int, ...]                      # tracks started by this image
    missed: tuple[int, ...]                   # tracks it should have shown, kept for now
    dropped: tuple[int, ...]                  # tracks given up after MISS_LIMIT misses in a row
    unseen: tuple[int, ...]                   # tracks (partly) out of its view, kept as they were


@dataclass(frozen=True)
class Reach:
    """One track's forecast: its breadth-first distances in a window of the floor."""
    track: int
    kind: str
    cell: Cell                        # where it was seen
    seen: int
    speed: int
    corner: Cell                      # (x0, y0) of the window
    dist: np.ndarray                  # int32 [rows, cols]; -1 = beyond the horizon's reach

    def radius(self, tick: int) -> int:
        return max(tick - self.seen, 0) * self.speed


@dataclass(frozen=True, eq=False)
class Forecast:
    """The cells the tracked movers may occupy or pass, per tick, up to tick `until`.

    `flat`/`first` list every cell some mover may reach by `until` (y * width + x) and the
    first tick it may be there; a cell is closed from then to `until` (monotone: a mover that
    may be somewhere by t may still be there later). A pallet's cell is closed from the tick
    it was seen."""
    shape: tuple[int, int]
    until: int
    reaches: tuple[Reach, ...]
    flat: np.ndarray                  # int64 [m], sorted, distinct
    first: np.ndarray                 # int64 [m]: the tick from which the cell is closed

    def closed(self, cell: Cell, tick: int) -> bool:
        """Whether a mover may be on `cell` at some point of tick `tick` (tick <= until)."""
        x, y = int(cell[0]), int(cell[1])
        key = y * self.shape[1] + x
        i = int(np.searchsorted(self.flat, key))
        return i < self.flat.size and int(self.flat[i]) == key and int(self.first[i]) <= tick

    def mask(self, tick: int) -> np.ndarray:
        """bool [h, w]: the cells closed at `tick`."""
        out = np.zeros(self.shape[0] * self.shape[1], dtype=bool)
        out[self.flat[self.first <= tick]] = True
        return out.reshape(self.shape)

    def cells(self, tick: int) -> set[Cell]:
        w = self.shape[1]
        return {(int(f % w), int(f // w)) for f in self.flat[self.first <= tick]}


Fields = dict[tuple[int, int, Cell], tuple[int, Cell, np.ndarray]]


def cached_field(free: np.ndarray, tr: Track, radius: int, cache: Fields | None) -> tuple[Cell, np.ndarray]:
    """`reach_field` of a track's last sighting, cut to `radius`: from `cache` ((id, seen, cell) ->
    (radius, corner, dist)) when it went that far, else grown with room to spare and kept there.
    The radius grows every tick between two images; this keeps it from being walked afresh each time."""
    if cache is None:
        return reach_field(free, tr.cell, radius)
    key = (tr.id, tr.seen, tr.cell)
    hit = cache.get(key)
    if hit is None or hit[0] < radius:
        grown = radius + max(4, radius // 2)
        corner, dist = reach_field(free, tr.cell, grown)
        hit = cache[key] = (grown, corner, dist)
    grown, (x0, y0), dist = hit
    if grown == radius:
        return (x0, y0), dist
    # the window of `radius` inside the cached one, beyond it -1
    x, y = tr.cell
    h, w = free.shape
    cx0, cy0 = max(0, x - radius), max(0, y - radius)
    cx1, cy1 = min(w, x + radius + 1), min(h, y + radius + 1)
    sub = dist[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]
    return (cx0, cy0), np.where(sub <= radius, sub, -1).astype(np.int32)


def forecast(free: np.ndarray, tracks: Iterable[Track], until: int,
             speeds: Mapping[str, int] = SPEED, cache: Fields | None = None) -> Forecast:
    """Every track's reachable cells up to tick `until`, each with the tick it may first be there
    (`cache`: see `cached_field`)."""
    free = np.asarray(free, dtype=bool)
    h, w = free.shape
    reaches = []
    flats, firsts = [], []
    for tr in tracks:
        sp = speed_of(tr.kind, speeds)
        corner, dist = cached_field(free, tr, max(until - tr.seen, 0) * sp, cache)
        reaches.append(Reach(tr.id, tr.kind, tr.cell, tr.seen, sp, corner, dist))
        ys, xs = np.nonzero(dist >= 0)
        d = dist[ys, xs].astype(np.int64)
        # reached within d steps by tick seen + ceil(d / speed); a pallet (speed 0) only on its cell
        first = tr.seen + (-(-d // sp) if sp > 0 else d)
        flats.append((ys + corner[1]).astype(np.int64) * w + xs + corner[0])
        firsts.append(first)
    if flats:
        flat = np.concatenate(flats)
        first = np.concatenate(firsts)
        order = np.lexsort((first, flat))           # by cell, earliest tick first
        flat, first = flat[order], first[order]
        keep = np.ones(flat.size, dtype=bool)
        keep[1:] = flat[1:] != flat[:-1]
        flat, first = flat[keep], first[keep]
    else:
        flat = first = np.zeros(0, dtype=np.int64)
    return Forecast((h, w), int(until), tuple(reaches), flat, first)


def _sighting(s: Any) -> Sighting:
    kind, cell = (s.kind, s.cell) if hasattr(s, "kind") else (s[0], s[1])
    return Sighting(str(kind), (int(cell[0]), int(cell[1])))


def _compatible(track_kind: str, kind: str) -> bool:
    return track_kind == kind or UNKNOWN in (track_kind, kind)


@dataclass
class Tracker:
    """Tracks of the movers seen so far; `update` folds in one image, `forecast` looks ahead."""
    free: np.ndarray
    speeds: Mapping[str, int] = field(default_factory=lambda: dict(SPEED))
    miss_limit: int = MISS_LIMIT
    tracks: dict[int, Track] = field(default_factory=dict)
    dropped: list[tuple[int, Track]] = field(default_factory=list)   # (tick, track): for the report
    last_tick: int | None = None
    _next_id: int = 0
    _fields: Fields = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.free = np.asarray(self.free, dtype=bool)

    def update(self, tick: int, sightings: Iterable[Any], seen: np.ndarray | None = None) -> Update:
        """One image taken at `tick`: its sightings (anything with .kind and .cell, such as
        perception's, or (kind, cell) pairs), and the cells it showed (bool [h, w]; None: the
        whole floor)."""
        if self.last_tick is not None and tick < self.last_tick:
            raise ValueError(f"an image of tick {tick} after one of tick {self.last_tick}: images come in order")
        self.last_tick = tick
        seen_by = [_sighting(s) for s in sightings]
        old = list(self.tracks.values())
        fields = [cached_field(self.free, tr, max(tick - tr.seen, 0) * speed_of(tr.kind, self.speeds), self._fields)
                  for tr in old]
        pairs = self._associate(tick, old, fields, seen_by)
        matched: list[tuple[int, Cell]] = []
        taken = set()
        for j, i in pairs:
            tr, s = old[j], seen_by[i]
            dt = max(tick - tr.seen, 1)
            vel = ((s.cell[0] - tr.cell[0]) / dt, (s.cell[1] - tr.cell[1]) / dt)
            kind = s.kind if s.kind != UNKNOWN else tr.kind     # a kind once told stays told
            self.tracks[tr.id] = Track(tr.id, kind, s.cell, tick, vel, 0)
            matched.append((tr.id, s.cell))
            taken.add(j)
        new = []
        for i in sorted(set(range(len(seen_by))) - {i for _, i in pairs}):
            s = seen_by[i]
            self.tracks[self._next_id] = Track(self._next_id, s.kind, s.cell, tick)
            new.append(self._next_id)
            self._next_id += 1
        missed, dropped, unseen = [], [], []
        for j, tr in enumerate(old):
            if j in taken:
                continue
            if not self._in_view(fields[j], seen):
                unseen.append(tr.id)
                continue
            if tr.misses + 1 >= self.miss_limit:
                del self.tracks[tr.id]
                self.dropped.append((tick, tr))
                dropped.append(tr.id)
            else:
                self.tracks[tr.id] = Track(tr.id, tr.kind, tr.cell, tr.seen, tr.velocity, tr.misses + 1)
                missed.append(tr.id)
        live = {(tr.id, tr.seen, tr.cell) for tr in self.tracks.values()}
        for key in [k for k in self._fields if k not in live]:
            del self._fields[key]
        return Update(tick, tuple(matched), tuple(new), tuple(missed), tuple(dropped), tuple(unseen))

    def _associate(self, tick: int, old: list[Track], fields, seen_by: list[Sighting]) -> list[tuple[int, int]]:
        """(track index, sighting index) pairs: each sighting to a track that could be there."""
        if not old or not seen_by:
            return []
        cost = np.full((len(old), len(seen_by)), _FAR)
        for j, (tr, ((x0, y0), dist)) in enumerate(zip(old, fields)):
            dt = max(tick - tr.seen, 0)
            px, py = tr.cell[0] + tr.velocity[0] * dt, tr.cell[1] + tr.velocity[1] * dt
            for i, s in enumerate(seen_by):
                if not _compatible(tr.kind, s.kind):
                    continue
                cx, cy = s.cell[0] - x0, s.cell[1] - y0
                if 0 <= cy < dist.shape[0] and 0 <= cx < dist.shape[1] and dist[cy, cx] >= 0:
                    # nearest to where its velocity puts it; the walk's length breaks ties
                    cost[j, i] = abs(s.cell[0] - px) + abs(s.cell[1] - py) + 1e-3 * dist[cy, cx]
        rows, cols = linear_sum_assignment(cost)
        return [(int(j), int(i)) for j, i in zip(rows, cols) if cost[j, i] < _FAR]

    @staticmethod
    def _in_view(reach: tuple[Cell, np.ndarray], seen: np.ndarray | None) -> bool:
        """Whether an image showing `seen` showed every cell the track may be on."""
        if seen is None:
            return True
        (x0, y0), dist = reach
        window = np.asarray(seen, dtype=bool)[y0:y0 + dist.shape[0], x0:x0 + dist.shape[1]]
        return bool(window[dist >= 0].all())

    def forecast(self, until: int) -> Forecast:
        return forecast(self.free, self.tracks.values(), until, self.speeds, self._fields)
