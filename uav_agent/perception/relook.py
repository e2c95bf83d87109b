"""Closer looks: the fewest hover points that see a set of cells from a given altitude.

Cells are binned into tiles of the footprint the camera has at that altitude
(less a margin, so each cell lies whole inside the image, and less what a tilt
of the body-fixed camera swings the footprint by), and each non-empty tile gets
one hover over the centre of its cells; the tiles are visited nearest-first
from where the vehicle is. One look per cell, as before, cost a flight per
unreadable marker. Every doubtful cell gets a tile: when that takes more than
`max_hovers`, the look rises (a wider footprint) before it drops cells.
"""
from __future__ import annotations

import math
from collections.abc import Collection, Iterable

import numpy as np

from protocol.grid import Cell

MARGIN = 0.8     # of the footprint: the rest is the overlap that keeps cells whole
MAX_HOVERS = 24  # per round of closer looks: past it, the look rises rather than fly on
RISE = 1.25      # altitude step when the cells need more hovers than that
MIN_ALT_M = 3.0
LANDMARKS_WANTED = 2   # in a closer look's view, when its cells leave room to slide for them
ROUNDS = 3       # of closer looks: the survey's gaps, then the markers they showed too small, then the rest


def hover_points(cells: Iterable[Cell], cell_size_m: float, alt_m: float, width_px: int, height_px: int,
                 fx: float, fy: float, start_ne: tuple[float, float] = (0.0, 0.0),
                 tilt_rad: float = 0.0, anchors_en: np.ndarray | None = None) -> list[tuple[float, float]]:
    """(north, east) hover points over `cells` for a nadir camera at `alt_m`, in visiting order;
    `tilt_rad`: the roll or pitch the camera may have at the shutter (either way, either axis).
    `anchors_en`: the surveyed landmarks' (east, north) centres; a hover slides, as far as its
    cells allow, to have LANDMARKS_WANTED of them in view (an image with none is placed by the
    pose estimate alone, and its cells count for little: a look at them from there changes nothing)."""
    swing = 2 * alt_m * math.tan(abs(tilt_rad))
    half_e = (MARGIN * width_px / fx * alt_m - swing) / 2
    half_n = (MARGIN * height_px / fy * alt_m - swing) / 2
    span_e = max(cell_size_m, 2 * half_e - 2 * cell_size_m)
    span_n = max(cell_size_m, 2 * half_n - 2 * cell_size_m)
    view = ((width_px / fx * alt_m - swing) / 2 - cell_size_m, (height_px / fy * alt_m - swing) / 2 - cell_size_m)
    tiles: dict[tuple[int, int], list[Cell]] = {}
    for x, y in cells:
        east, south = (x + 0.5) * cell_size_m, (y + 0.5) * cell_size_m
        tiles.setdefault((math.floor(east / span_e), math.floor(south / span_n)), []).append((x, y))
    points = []
    for members in tiles.values():
        xs = [x for x, _ in members]
        ys = [y for _, y in members]
        # Where the hover may be with every cell whole inside, a cell clear of the edge.
        east = ((max(xs) + 2) * cell_size_m - half_e, (min(xs) - 1) * cell_size_m + half_e)
        south = ((max(ys) + 2) * cell_size_m - half_n, (min(ys) - 1) * cell_size_m + half_n)
        points.append(_placed(east, south, view, anchors_en))
    ordered, here = [], start_ne
    while points:
        nxt = min(points, key=lambda p: math.hypot(p[0] - here[0], p[1] - here[1]))
        points.remove(nxt)
        ordered.append(nxt)
        here = nxt
    return ordered


def _placed(east: tuple[float, float], south: tuple[float, float], view: tuple[float, float],
            anchors_en: np.ndarray | None) -> tuple[float, float]:
    """(north, east) of a hover within the allowed east and south ranges: the middle, unless a
    point in range sees more landmarks (up to LANDMARKS_WANTED), then the nearest such to the middle."""
    mid_e, mid_s = sum(east) / 2, sum(south) / 2
    if anchors_en is None or not len(anchors_en):
        return -mid_s, mid_e

    def seen(e: float, s: float) -> int:
        inside = (np.abs(anchors_en[:, 0] - e) <= view[0]) & (np.abs(-anchors_en[:, 1] - s) <= view[1])
        return min(LANDMARKS_WANTED, int(inside.sum()))

    best = (seen(mid_e, mid_s), 0.0, mid_e, mid_s)
    if best[0] >= LANDMARKS_WANTED or east[1] < east[0] or south[1] < south[0]:
        return -mid_s, mid_e
    for e in np.linspace(east[0], east[1], 9):
        for s in np.linspace(south[0], south[1], 9):
            n, d = seen(e, s), math.hypot(e - mid_e, s - mid_s)
            if (n, -d) > (best[0], -best[1]):
                best = (n, d, float(e), float(s))
    return -best[3], best[2]


def closer_look(cells: Collection[Cell], cell_size_m: float, alt_m: float, max_alt_m: float, camera,
                start_ne: tuple[float, float] = (0.0, 0.0), tilt_rad: float = 0.0,
                max_hovers: int = MAX_HOVERS, anchors_en: np.ndarray | None = None
                ) -> tuple[float, list[tuple[float, float]]]:
    """(altitude, hover points) that see every one of `cells`: from `alt_m`, rising in steps up
    to `max_alt_m` while that takes more than `max_hovers`; at `max_alt_m` the nearest
    `max_hovers` only (the next round sees the rest). `camera`: width, height, fx, fy."""
    alt = alt_m
    while True:
        points = hover_points(cells, cell_size_m, alt, camera.width, camera.height, camera.fx, camera.fy,
                              start_ne, tilt_rad, anchors_en)
        if len(points) <= max_hovers or alt >= max_alt_m:
            return alt, points[:max_hovers]
        alt = min(max_alt_m, alt * RISE)


def plan_round(model, known: Collection[int] | None, for_map: bool, attempt: int, survey_alt_m: float,
               cell_size_m: float, camera, landmarks=None, start_ne: tuple[float, float] = (0.0, 0.0),
               tilt_rad: float = 0.0, survey_images: int = 0) -> tuple[list[Cell], list[tuple[float, float, float]]]:
    """Round `attempt` (1, 2, ...) of closer looks at what `model` leaves in doubt: (the cells,
    the hovers (north, east, altitude)); no cells, no hovers. Cells no image saw only need
    seeing: they are looked at from the survey's height, as the rest of the floor was. The
    others need detail: each round halves the survey's altitude for them, but stays high
    enough to keep landmarks in view to register by. A round takes at most MAX_HOVERS images,
    or as many as the survey did (`survey_images`) if that is more: a blurred camera's low
    survey has small footprints, and a closer look should cost no more than the survey did."""
    targets = doubts(model, known, for_map)
    if not targets:
        return [], []
    unseen = {c for c in targets if not model.seen[c[1], c[0]]}
    detail = [c for c in targets if c not in unseen]
    hovers = detail_hovers(detail, attempt, survey_alt_m, cell_size_m, camera, landmarks, start_ne, tilt_rad,
                           survey_images) if detail else []
    here = hovers[-1][:2] if hovers else start_ne
    anchors = _anchors(landmarks)
    cap = max(MAX_HOVERS, survey_images)
    if unseen:
        alt, points = closer_look(sorted(unseen), cell_size_m, survey_alt_m, survey_alt_m, camera, here, tilt_rad,
                                  cap, anchors)
        hovers += [(n, e, alt) for n, e in points]
    return targets, hovers


def _anchors(landmarks) -> np.ndarray | None:
    return np.concatenate(list(landmarks.by_id.values())) if landmarks is not None and landmarks.by_id else None


def detail_hovers(cells: Collection[Cell], attempt: int, survey_alt_m: float, cell_size_m: float, camera,
                  landmarks=None, start_ne: tuple[float, float] = (0.0, 0.0), tilt_rad: float = 0.0,
                  survey_images: int = 0) -> list[tuple[float, float, float]]:
    """Hovers (north, east, altitude) that see `cells` in more detail: round `attempt` halves the
    survey's altitude for them, staying high enough to keep landmarks in view to register by."""
    keep = landmarks.view_alt_m(camera.width / camera.fx) if landmarks is not None else 0.0
    alt = min(survey_alt_m, max(MIN_ALT_M, keep, survey_alt_m / 2.0 ** attempt))
    alt, points = closer_look(cells, cell_size_m, alt, survey_alt_m, camera, start_ne, tilt_rad,
                              max(MAX_HOVERS, survey_images), _anchors(landmarks))
    return [(n, e, alt) for n, e in points]


def doubts(model, known: Collection[int] | None, for_map: bool = True) -> list[Cell]:
    """The cells a closer look should see: unreadable markers (while a known robot is missing),
    and, when the map matters, unsure cells, cells no image saw, every unreadable marker (the
    model takes its cell for floor under a robot: a shelf edge's contrast would open a wall),
    and, if fewer goals than robots were seen, the robots (one may stand on a goal and hide most of it).
    While a known robot is missing, shelf cells standing (nearly) alone in the floor too: a
    marker too blurred to show its contrast reads as a dark cell."""
    missing = set(known or ()) - set(model.robots)
    targets = set(model.unidentified) if missing or known is None or for_map else set()
    if missing:
        targets |= lone_shelves(model)
    if for_map:
        targets |= set(model.unsure)
        ys, xs = np.nonzero(~model.seen)           # beyond every image's edge (a lens, a tilt)
        targets |= {(int(x), int(y)) for x, y in zip(xs, ys)}
        if len(model.goals) < len(model.robots):
            targets |= set(model.robots.values())
    return sorted(targets)


def lone_shelves(model) -> set[Cell]:
    """Seen cells read as shelf with at least three of their four neighbours (on the grid) read
    as floor: alone, or a one-cell bump on a shelf's side (a robot in the aisle beside it)."""
    free, seen = model.free, model.seen
    pad = np.pad(free, 1, constant_values=True).astype(np.int8)
    floor_around = pad[:-2, 1:-1] + pad[2:, 1:-1] + pad[1:-1, :-2] + pad[1:-1, 2:]
    alone = seen & ~free & (floor_around >= 3)
    ys, xs = np.nonzero(alone)
    return {(int(x), int(y)) for x, y in zip(xs, ys)}
