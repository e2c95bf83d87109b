"""People, forklifts and pallets on the floor: found by hue, no marker to read.

The floor's contract (the world draws them so, and nothing else on the floor has these
colours both saturated and bright): a person is a hi-vis orange disc of about 0.6 cell, a
forklift a safety-yellow body nearly filling its cell with two grey forks, a pallet a magenta
square of 0.8 cell. Shelves share the person's hue but are dark, the outside is dark blue,
goals are green, robots and landmarks black and white.

As for the goal pads (`goals`), hue and saturation do not change when the light dims, and
brightness is only compared with the image's own bright level: the split does not depend on
the exposure. The pixels are gathered into the cells the view's registration puts them in,
not into blobs: two forklifts side by side, or a person beside one, blur into one blob seen
from far, but never into one cell. A cell reads as a mover when enough of it is covered,
around its centre, in one kind's hue; a cell the image cuts is left to a frame that sees it
whole.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

from protocol.grid import Cell

from .goals import histogram_percentile
from .view import View, to_floor, to_image

PERSON, FORKLIFT, PALLET = "person", "forklift", "pallet"
# OpenCV hue (0..180) of each kind: the world draws a person ~9, a forklift ~24, a pallet ~154.
# The ranges meet halfway between neighbours; 35..134 is the goals' green and the outside's blue.
HUES: dict[str, tuple[tuple[int, int], ...]] = {PERSON: ((0, 16), (170, 180)), FORKLIFT: ((17, 34),),
                                                 PALLET: ((135, 169),)}
MIN_SATURATION = 75          # a mover half-covering a pixel of grey floor still passes; floor noise stays under
# Brightness against the image's bright level, that of its colourless pixels (floor, markers' white):
# a shelf shares a person's hue and is 0.37 of the floor, a mover is as bright as the floor or more.
BRIGHT_FRACTION = 0.5
NEUTRAL_SATURATION = 40      # colourless: the floor, white and black under noise; a shelf is 112, a mover 150 and more
# Area, cells^2, of each kind's colour in its cell (drawn: a person 0.26, a forklift's body 0.53, a pallet
# 0.64; blur and the lens widen them by a pixel's fringe, which at a far view's 6 px per cell is much).
AREA_CELLS = {PERSON: (0.12, 0.8), FORKLIFT: (0.45, 1.2), PALLET: (0.3, 1.2)}
# A warm blob too small for a forklift is a person: on a goal seen from far, most of a person's few pixels
# mix with the green around it, and orange mixed with green is yellow.
FORKLIFT_MIN_AREA = AREA_CELLS[FORKLIFT][0]
# Every mover covers its cell's centre: at least MIN_CORE_COVER of the square CORE_HALF around it. What a
# neighbour's blur spills over a cell's edges (two forklifts beside a cell, seen from far) never reaches it.
CORE_HALF = 0.2
MIN_CORE_COVER = 0.5
BORDER_PX = 2

KINDS = (PERSON, FORKLIFT, PALLET)


def _hue_kinds() -> np.ndarray:
    """Each OpenCV hue's kind, as an index into KINDS (len(KINDS): none)."""
    table = np.full(256, len(KINDS), np.int64)
    for k, kind in enumerate(KINDS):
        for lo, hi in HUES[kind]:
            table[lo:hi + 1] = k
    return table


def _hue_runs() -> tuple[tuple[int, int], ...]:
    """The kinds' hue ranges merged where they meet: one inRange pass each. Today two: orange to
    yellow (a person, a forklift) and magenta to red (a pallet, a person's reddest pixels)."""
    runs: list[list[int]] = []
    for lo, hi in sorted(r for ranges in HUES.values() for r in ranges):
        if runs and lo <= runs[-1][1] + 1:
            runs[-1][1] = max(runs[-1][1], hi)
        else:
            runs.append([lo, hi])
    return tuple((lo, hi) for lo, hi in runs)


_KIND_OF_HUE = _hue_kinds()
_HUE_RUNS = _hue_runs()
_AREA_LO = np.array([AREA_CELLS[k][0] for k in KINDS] + [math.inf])   # by kind index, none last
_AREA_HI = np.array([AREA_CELLS[k][1] for k in KINDS] + [0.0])


@dataclass(frozen=True)
class MoverSighting:
    kind: str                # PERSON, FORKLIFT or PALLET
    cell: Cell


class MoverPixels(NamedTuple):
    """The mover-coloured pixels of one image, before the registration places them."""
    points: np.ndarray       # [N, 2] float64 (x, y) pixel positions
    colours: np.ndarray      # [N, 3] uint8 BGR
    shape: tuple[int, int]   # the image's (height, width)
    valid: np.ndarray | None


def mover_pixels(image: np.ndarray, valid: np.ndarray | None) -> MoverPixels:
    """The pixels of an undistorted BGR image (`valid`: its pixels from the sensor) that show
    a mover's colour. The image alone decides them, so they are found while it is registered."""
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    # The colourless pixels' bright level, not the whole image's: a view of shelves and little floor
    # would take a shelf's brown for it. Every fourth row tells it as well, at a quarter of the cost.
    neutral = cv2.calcHist([hsv[::4]], [1, 2], None, [1, 256], [0, NEUTRAL_SATURATION, 0, 256]).ravel()
    bright = histogram_percentile(neutral, 95) if neutral.sum() > 0 else 255.0
    low_v = math.ceil(BRIGHT_FRACTION * bright)
    mask = None
    for lo, hi in _HUE_RUNS:
        run = cv2.inRange(hsv, (lo, MIN_SATURATION, low_v), (hi, 255, 255))
        mask = run if mask is None else cv2.bitwise_or(mask, run, dst=mask)
    found = cv2.findNonZero(mask)
    if found is None:
        return MoverPixels(np.zeros((0, 2)), np.zeros((0, 3), np.uint8), image.shape[:2], valid)
    xy = found.reshape(-1, 2)
    if valid is not None:
        xy = xy[valid[xy[:, 1], xy[:, 0]]]
    return MoverPixels(xy.astype(np.float64), image[xy[:, 1], xy[:, 0]], image.shape[:2], valid)


def movers_from(px: MoverPixels, view: View, grid: tuple[int, int]) -> list[MoverSighting]:
    """The movers `px` of `view`'s image show, one per cell, placed by its registration."""
    if not len(px.points):
        return []
    w, h = grid
    uv = to_floor(px.points, view.H_inv)
    fx, fy = np.floor(uv[:, 0]), np.floor(uv[:, 1])
    on = (fx >= 0) & (fx < w) & (fy >= 0) & (fy < h)
    if not on.any():
        return []
    cells, index, counts = np.unique((fy[on] * w + fx[on]).astype(np.int64), return_inverse=True,
                                     return_counts=True)
    area = counts / view.ppc ** 2
    core = np.max(np.abs(uv[on] - np.column_stack([fx[on], fy[on]]) - 0.5), axis=1) <= CORE_HALF
    core_cover = np.bincount(index, weights=core, minlength=len(cells)) / (2 * CORE_HALF * view.ppc) ** 2
    keep = (area >= min(lo for lo, _ in AREA_CELLS.values())) & (core_cover >= MIN_CORE_COVER)
    if not keep.any():
        return []
    # The hue of each cell's mean colour: the few fringe pixels a neighbour's colour tints weigh little.
    colours = px.colours[on].astype(np.float64)
    bgr = np.stack([np.bincount(index, weights=colours[:, c], minlength=len(cells)) for c in range(3)], axis=1)
    mean = np.round(bgr / counts[:, None]).astype(np.uint8)
    hue = cv2.cvtColor(mean.reshape(-1, 1, 3), cv2.COLOR_BGR2HSV)[:, 0, 0]
    kinds = _KIND_OF_HUE[hue]
    # Too small for a forklift: a person (see FORKLIFT_MIN_AREA).
    kinds = np.where((kinds == KINDS.index(FORKLIFT)) & (area < FORKLIFT_MIN_AREA), KINDS.index(PERSON), kinds)
    lo, hi = _AREA_LO[kinds], _AREA_HI[kinds]
    keep &= (kinds < len(KINDS)) & (area >= lo) & (area <= hi)
    i = np.flatnonzero(keep)
    if not i.size:
        return []
    i = i[_whole(view, px, cells[i] % w, cells[i] // w)]
    return [MoverSighting(KINDS[k], (int(c % w), int(c // w))) for k, c in zip(kinds[i], cells[i])]


def _whole(view: View, px: MoverPixels, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Which cells (xs, ys) lie wholly in the image, and in what the sensor saw of it: a mover
    the image cuts shows a part, and its centre and size lie."""
    img_h, img_w = px.shape
    corners = np.stack([np.stack([xs + dx, ys + dy], axis=1) for dx in (0, 1) for dy in (0, 1)], axis=1)
    pts = to_image(corners.reshape(-1, 2).astype(np.float64), view.H).reshape(-1, 4, 2)
    inside = (np.isfinite(pts).all(axis=2) & (pts[..., 0] >= BORDER_PX) & (pts[..., 1] >= BORDER_PX)
              & (pts[..., 0] <= img_w - 1 - BORDER_PX) & (pts[..., 1] <= img_h - 1 - BORDER_PX))
    if px.valid is not None:
        xi = np.clip(np.round(np.nan_to_num(pts[..., 0])).astype(int), 0, img_w - 1)
        yi = np.clip(np.round(np.nan_to_num(pts[..., 1])).astype(int), 0, img_h - 1)
        inside &= px.valid[yi, xi]
    return inside.all(axis=1)
