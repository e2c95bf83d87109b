"""Goal pads: saturated green, found by hue and saturation relative to the image.

Hue and saturation do not change when the light dims, so the split does not
depend on the exposure; brightness only has to stand clear of the image's
darkest parts (a dimmed, noisy shelf can show any hue). A robot parked on a
goal leaves only a green frame around its white body: the frame's blob is
centred on the cell like the pad's, so it reads as the same goal.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import cv2
import numpy as np

from protocol.grid import Cell, on_grid

from .view import View, to_floor

GREEN_HUE = (40, 85)             # OpenCV hue (0..180): green, away from the shelves' brown and the outside's blue
MIN_SATURATION = 70              # floor grey under heavy noise stays well below
DARK_FRACTION = 0.3              # of the image's bright level: darker pixels carry no colour to trust
GOAL_AREA_CELLS = (0.12, 1.05)   # a pad (up to ~0.92 cell^2) or the frame a robot leaves of it (~0.25)
MAX_CENTRE_OFFSET = 0.3          # of a cell: a blob's centre lies near its cell's centre
BORDER_PX = 2


class Blobs(NamedTuple):
    """Green blobs of one image, before the registration places them: connectedComponentsWithStats' output."""
    count: int
    labels: np.ndarray | None
    stats: np.ndarray | None
    centroids: np.ndarray | None
    shape: tuple[int, int]


def goal_blobs(image: np.ndarray, valid: np.ndarray | None) -> Blobs:
    """The pad-coloured blobs of an undistorted BGR image (`valid`: its pixels from the sensor).
    The image alone decides them, so they are found while the image is being registered."""
    hsv = cv2.cvtColor(image, cv2.COLOR_BGR2HSV)
    bright = histogram_percentile(cv2.calcHist([hsv], [2], None, [256], [0, 256]).ravel(), 95)
    # Whole grey levels: v >= x is v >= ceil(x). One inRange pass instead of three compares.
    low = (GREEN_HUE[0], 0, math.ceil(DARK_FRACTION * bright))
    mask = cv2.inRange(hsv, low, (GREEN_HUE[1], 255, 255))
    # The saturations of the green-hued pixels, as a histogram (gathering them costs more).
    sat_hist = cv2.calcHist([hsv], [1], mask, [256], [0, 256]).ravel()
    n = int(sat_hist.sum())
    if n == 0:
        return Blobs(0, None, None, None, image.shape[:2])
    # The split between grey-with-noise and a pad's saturation, from this image's own pixels.
    sat_thr = max(MIN_SATURATION, _otsu(sat_hist)) if n > 50 else MIN_SATURATION
    mask = cv2.inRange(hsv, (low[0], math.ceil(sat_thr), low[2]), (GREEN_HUE[1], 255, 255))
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    if valid is not None:
        mask *= valid
    return Blobs(*_components(mask), mask.shape)


def goals_from(blobs: Blobs, view: View, grid: tuple[int, int]) -> set[Cell]:
    """The goal cells `blobs` of `view`'s image show, placed by its registration."""
    img_h, img_w = blobs.shape
    goals: set[Cell] = set()
    for i in range(1, blobs.count):
        x, y, bw, bh, area = blobs.stats[i]
        if x <= BORDER_PX or y <= BORDER_PX or x + bw >= img_w - BORDER_PX or y + bh >= img_h - BORDER_PX:
            continue  # cut by the image edge, so its centroid lies; a neighbouring frame sees it whole
        if area / view.ppc ** 2 > GOAL_AREA_CELLS[1]:
            goals |= _split(blobs.labels[y:y + bh, x:x + bw] == i, x, y, view, grid)   # neighbouring pads touch
            continue
        if area / view.ppc ** 2 < GOAL_AREA_CELLS[0]:
            continue
        u, v_ = to_floor(blobs.centroids[i], view.H_inv)[0]
        cell = (math.floor(u), math.floor(v_))
        if max(abs(u - cell[0] - 0.5), abs(v_ - cell[1] - 0.5)) > MAX_CENTRE_OFFSET:
            continue
        if on_grid(*cell, *grid):
            goals.add(cell)
    return goals


def histogram_percentile(counts: np.ndarray, q: float) -> float:
    """np.percentile (linear) of the values a histogram of whole levels counts, without sorting
    the 12 million pixels it was taken from."""
    cum = np.cumsum(np.asarray(counts, np.int64))
    pos = q / 100.0 * (cum[-1] - 1)
    below = math.floor(pos)
    lo = int(np.searchsorted(cum, below, side="right"))
    hi = int(np.searchsorted(cum, min(below + 1, cum[-1] - 1), side="right"))
    return lo + (pos - below) * (hi - lo)


def _components(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """connectedComponentsWithStats (8-connected) with 16-bit labels, a third of the memory
    written at 12 MP; OpenCV refuses them past 65535 blobs (noise, never pads): then 32-bit."""
    try:
        return cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_16U)
    except cv2.error:
        return cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)


def _otsu(hist: np.ndarray) -> float:
    """Otsu's threshold of the whole levels a 256-bin histogram counts, as OpenCV's THRESH_OTSU
    computes it from the values themselves: the first level of greatest between-class variance."""
    p = np.asarray(hist, np.float64) / float(np.sum(hist))
    levels = np.arange(p.size, dtype=np.float64)
    q1 = np.cumsum(p)
    m1 = np.cumsum(levels * p)
    q2 = 1.0 - q1
    eps = float(np.finfo(np.float32).eps)
    ok = (np.minimum(q1, q2) >= eps) & (np.maximum(q1, q2) <= 1.0 - eps)
    with np.errstate(divide="ignore", invalid="ignore"):
        sigma = q1 * q2 * (m1 / q1 - (m1[-1] - m1) / q2) ** 2
    sigma = np.where(ok, sigma, 0.0)
    return float(np.argmax(sigma)) if sigma.max() > 0 else 0.0


def _split(blob: np.ndarray, x0: int, y0: int, view: View, grid: tuple[int, int]) -> set[Cell]:
    """Pads of neighbouring goal cells merged into one blob: each cell it covers for the most part."""
    ys, xs = np.nonzero(blob)
    uv = to_floor(np.column_stack([xs + x0, ys + y0]).astype(np.float64), view.H_inv)
    cells, counts = np.unique(np.floor(uv).astype(int), axis=0, return_counts=True)
    return {(int(cx), int(cy)) for (cx, cy), n in zip(cells, counts)
            if n / view.ppc ** 2 >= 0.5 and on_grid(int(cx), int(cy), *grid)}
