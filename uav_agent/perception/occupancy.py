"""Floor or shelf, per cell of one view, with thresholds that adapt to the image.

The image is warped back onto the grid (an orthophoto at a few pixels per
cell); a cell's brightness is the mean of its central patch. Brightness is
albedo times illumination, and the illumination varies smoothly (a lighting
gradient, lens vignetting), so in log space it is a smooth surface plus one of
two levels. Alternately: split the cells in two by Otsu, fit a quadratic
surface to the bright (floor) cells, split the residuals again. What remains is
the albedo relative to the floor's, whatever the exposure. A view with one
class only (no contrast between the halves Otsu proposes) is all floor.
A cell's confidence is how far its residual lies from the split, as a fraction
of the distance between the two classes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .view import View

ORTHO_PPC = 8                   # orthophoto pixels per cell
BORDER_PX = 2                   # a cell this close to the image edge is not trusted
MIN_CONTRAST = math.log(1.8)    # two classes must differ at least this much in albedo (shelf ~0.3 of floor)
MARKER_STD_RATIO = 0.16         # grey std over a cell / the floor's brightness there: a black-on-white marker
MARKER_WHITE_RATIO = 0.5       # a marker's white modules against the floor's brightness there
FIT_ROUNDS = 3


@dataclass
class Cells:
    """Per-cell readings of one view over the box [x0, x0+w) x [y0, y0+h) of the grid."""
    x0: int
    y0: int
    seen: np.ndarray
    free: np.ndarray
    confidence: np.ndarray      # 0..1 per cell: how clearly floor or shelf
    marker_like: np.ndarray
    centre_weight: np.ndarray   # 1 at the image centre, falling towards the edges
    contrast: np.ndarray        # grey std over the cell / the floor's brightness there (a marker's > MARKER_STD_RATIO)


def _otsu(values: np.ndarray) -> tuple[float, float, float]:
    """(threshold, mean below, mean above) of a 1-D sample, by Otsu."""
    lo, hi = float(values.min()), float(values.max())
    if hi - lo < 1e-9:
        return lo, lo, hi
    scaled = np.round((values - lo) / (hi - lo) * 255).astype(np.uint8).reshape(-1, 1)
    t, _ = cv2.threshold(scaled, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    thr = lo + (t + 0.5) / 255 * (hi - lo)
    below, above = values[values <= thr], values[values > thr]
    return thr, float(below.mean()) if below.size else lo, float(above.mean()) if above.size else hi


def _design(px: np.ndarray, w: int, h: int) -> np.ndarray:
    x = px[:, 0] / w - 0.5
    y = px[:, 1] / h - 0.5
    return np.column_stack([np.ones_like(x), x, y, x * x, x * y, y * y])


def classify(log_luma: np.ndarray, px: np.ndarray, usable: np.ndarray, image_size: tuple[int, int]
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(free, confidence, log illumination) for cells of log brightness `log_luma` at image positions `px`;
    `usable` marks the cells that may shape the illumination fit (not markers)."""
    w, h = image_size
    A = _design(px, w, h)
    surface = np.full(log_luma.shape, float(np.median(log_luma[usable])) if usable.any() else 0.0)
    _, low, high = _otsu(log_luma[usable] if usable.any() else log_luma)
    two = high - low >= MIN_CONTRAST
    free = log_luma > (low + high) / 2 if two else np.ones(log_luma.shape, bool)
    for _ in range(FIT_ROUNDS):
        fit = free & usable
        if fit.sum() >= 12:
            coef, *_ = np.linalg.lstsq(A[fit], log_luma[fit], rcond=None)
            surface = A @ coef
        elif fit.any():
            surface = np.full(log_luma.shape, float(np.median(log_luma[fit])))
        residual = log_luma - surface
        _, low, high = _otsu(residual[usable] if usable.any() else residual)
        two = high - low >= MIN_CONTRAST
        # Split halfway between the two classes Otsu finds (one step of 2-means past it);
        # one class only: it is floor, which is what the illumination was fitted to.
        mid = (low + high) / 2
        free = residual > mid if two else np.ones(residual.shape, bool)
    if two:
        confidence = np.clip(np.abs(residual - mid) / ((high - low) / 2), 0.0, 1.0)
    else:
        confidence = np.clip(1.0 - np.abs(residual) / MIN_CONTRAST, 0.0, 1.0)
    return free, confidence, surface


def cells_in(view: View, grid: tuple[int, int]) -> Cells | None:
    img_h, img_w = view.gray.shape
    corners = [[0, 0], [img_w - 1, 0], [0, img_h - 1], [img_w - 1, img_h - 1]]
    floor = cv2.perspectiveTransform(np.array(corners, np.float64).reshape(-1, 1, 2), view.H_inv).reshape(-1, 2)
    x0, y0 = max(0, math.floor(floor[:, 0].min())), max(0, math.floor(floor[:, 1].min()))
    x1, y1 = min(grid[0], math.ceil(floor[:, 0].max())), min(grid[1], math.ceil(floor[:, 1].max()))
    if x0 >= x1 or y0 >= y1:
        return None
    # A cell is seen if its four corners project inside the image (and inside what the lens saw).
    gx, gy = np.meshgrid(np.arange(x0, x1 + 1, dtype=np.float64), np.arange(y0, y1 + 1, dtype=np.float64))
    px = cv2.perspectiveTransform(np.stack([gx, gy], -1).reshape(-1, 1, 2), view.H)
    px = px.reshape(y1 - y0 + 1, x1 - x0 + 1, 2)
    inside = ((px[..., 0] >= BORDER_PX) & (px[..., 0] <= img_w - 1 - BORDER_PX)
              & (px[..., 1] >= BORDER_PX) & (px[..., 1] <= img_h - 1 - BORDER_PX))
    if view.valid is not None:
        xi = np.clip(np.round(px[..., 0]).astype(int), 0, img_w - 1)
        yi = np.clip(np.round(px[..., 1]).astype(int), 0, img_h - 1)
        inside &= view.valid[yi, xi]
    seen = inside[:-1, :-1] & inside[1:, :-1] & inside[:-1, 1:] & inside[1:, 1:]
    if not seen.any():
        return None
    q, nx, ny = ORTHO_PPC, x1 - x0, y1 - y0
    ortho_to_floor = np.array([[1 / q, 0, x0 + 0.5 / q], [0, 1 / q, y0 + 0.5 / q], [0, 0, 1]])
    # Average the image over an orthophoto pixel's footprint first: a warp samples points, and
    # sensor noise sampled at points makes a dark shelf look as contrasted as a marker.
    spacing = view.ppc / q
    source = cv2.GaussianBlur(view.gray, (0, 0), 0.3 * spacing) if spacing > 3.0 else view.gray
    ortho = cv2.warpPerspective(source, view.H @ ortho_to_floor, (nx * q, ny * q),
                                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    cells = ortho.reshape(ny, q, nx, q).astype(np.float32)
    # Brightness from the central half only: the warp blurs cell edges into neighbours.
    luma = cells[:, q // 4: q - q // 4, :, q // 4: q - q // 4].mean(axis=(1, 3))
    # Inside the quiet zone only: a slightly misregistered shelf cell must not borrow a strip of floor.
    std = cells[:, 1:-1, :, 1:-1].std(axis=(1, 3))
    centres = (px[:-1, :-1] + px[1:, 1:]) / 2
    log_luma = np.log(luma + 1.0)
    # Provisional markers, against the image's bright level (the illumination is not
    # known yet; a dark, noisy shelf must not pass for one): the fit ignores them.
    bright = float(np.percentile(luma[seen], 90))
    rough = seen & (std > MARKER_STD_RATIO * bright)
    free = np.zeros(seen.shape, bool)
    confidence = np.zeros(seen.shape)
    illumination = np.zeros(seen.shape)
    sel = seen
    f, c, s = classify(log_luma[sel], centres[sel], ~rough[sel], (img_w, img_h))
    free[sel], confidence[sel], illumination[sel] = f, c, s
    # A marker is black on white: high contrast relative to the floor's brightness where it lies.
    # ... and its white parts are as bright as the floor there: a noisy or half-covered shelf is not.
    white = np.percentile(cells[:, 1:-1, :, 1:-1].reshape(ny, q - 2, nx, q - 2).transpose(0, 2, 1, 3)
                          .reshape(ny, nx, -1), 90, axis=2)
    contrast = std / np.exp(illumination)
    marker_like = seen & (contrast > MARKER_STD_RATIO) & (white > MARKER_WHITE_RATIO * np.exp(illumination))
    r = np.hypot((centres[..., 0] - img_w / 2) / (img_w / 2), (centres[..., 1] - img_h / 2) / (img_h / 2))
    centre_weight = np.clip(1.0 - 0.5 * r / math.sqrt(2), 0.3, 1.0)
    return Cells(x0, y0, seen, free, confidence, marker_like, centre_weight, contrast)
