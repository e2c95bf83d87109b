"""Closer looks: the fewest hover points that see a set of cells from a given altitude.

Cells are binned into tiles of the footprint the camera has at that altitude
(less a margin, so each cell lies whole inside the image), and each non-empty
tile gets one hover over the centre of its cells; the tiles are visited
nearest-first from where the vehicle is. One look per cell, as before, cost a
flight per unreadable marker.
"""
from __future__ import annotations

import math
from collections.abc import Collection, Iterable

import numpy as np

from protocol.grid import Cell

MARGIN = 0.8     # of the footprint: the rest is the overlap that keeps cells whole


def hover_points(cells: Iterable[Cell], cell_size_m: float, alt_m: float, width_px: int, height_px: int,
                 fx: float, fy: float, start_ne: tuple[float, float] = (0.0, 0.0)) -> list[tuple[float, float]]:
    """(north, east) hover points over `cells` for a nadir camera at `alt_m`, in visiting order."""
    span_e = max(cell_size_m, MARGIN * width_px / fx * alt_m - 2 * cell_size_m)
    span_n = max(cell_size_m, MARGIN * height_px / fy * alt_m - 2 * cell_size_m)
    tiles: dict[tuple[int, int], list[Cell]] = {}
    for x, y in cells:
        east, south = (x + 0.5) * cell_size_m, (y + 0.5) * cell_size_m
        tiles.setdefault((math.floor(east / span_e), math.floor(south / span_n)), []).append((x, y))
    points = []
    for members in tiles.values():
        xs = [x for x, _ in members]
        ys = [y for _, y in members]
        points.append((-(min(ys) + max(ys) + 1) / 2 * cell_size_m, (min(xs) + max(xs) + 1) / 2 * cell_size_m))
    ordered, here = [], start_ne
    while points:
        nxt = min(points, key=lambda p: math.hypot(p[0] - here[0], p[1] - here[1]))
        points.remove(nxt)
        ordered.append(nxt)
        here = nxt
    return ordered


def doubts(model, known: Collection[int] | None, for_map: bool = True) -> list[Cell]:
    """The cells a closer look should see: unreadable markers (while a known robot is missing),
    and, when the map matters, unsure cells and, if fewer goals than robots were seen, the
    robots (one may stand on a goal and hide most of it)."""
    missing = set(known or ()) - set(model.robots)
    targets = set(model.unidentified) if missing or known is None else set()
    if for_map:
        targets |= set(model.unsure)
        ys, xs = np.nonzero(~model.seen)           # beyond every image's edge (a lens, a tilt)
        targets |= {(int(x), int(y)) for x, y in zip(xs, ys)}
        if len(model.goals) < len(model.robots):
            targets |= set(model.robots.values())
    return sorted(targets)
