"""What the sensor and the optics do to a rendered image: defocus and motion blur,
uneven lighting and vignetting (one brightness gain), and sensor noise.

Order, as light goes: blur (the optics and the exposure) before the gain (a
smooth field, so the two nearly commute) before the noise (the sensor's).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from functools import lru_cache

import cv2
import numpy as np

from .fields import upsample
from .model import CameraModel

NOISE_PAD = 64
GAIN_STEP_PX = 8         # the gain field is computed this sparsely and interpolated
MIN_MOTION_PX = 0.5      # shorter smears are below what a pixel shows


@lru_cache(maxsize=8)
def _gain(width: int, height: int, lighting: float, angle_deg: float, vignetting: float,
          cx: float, cy: float) -> np.ndarray:
    """Brightness factor per pixel, in 1/255 steps (uint8, 255 = 1): a linear lighting ramp (1 on
    one side, 1 - lighting on the other) times a radial vignetting falloff (1 at the principal
    point, 1 - vignetting at the farthest corner, in r^2 as a lens's cos^4 law is near the axis).
    A step of 1/255 is under one grey level on the brightest floor. Computed every GAIN_STEP_PX
    and interpolated (`fields.upsample`): the ramp exactly, the falloff within 1e-6."""
    step = GAIN_STEP_PX
    xs = np.arange(0, width + step, step, dtype=np.float64)
    ys = np.arange(0, height + step, step, dtype=np.float64)
    gain = np.ones((len(ys), len(xs)))
    if lighting > 0:
        a = math.radians(angle_deg)
        c, s = math.cos(a), math.sin(a)
        ramp = c * (xs[None, :] - width / 2) + s * (ys[:, None] - height / 2)
        # The ramp's extremes over the image's pixels (its corners), not over the sparse grid.
        corners = [c * (x - width / 2) + s * (y - height / 2) for x in (0, width - 1) for y in (0, height - 1)]
        lo, span = min(corners), (max(corners) - min(corners)) or 1.0
        gain = 1.0 - lighting * (ramp - lo) / span
    if vignetting > 0:
        r2 = (xs[None, :] - cx) ** 2 + (ys[:, None] - cy) ** 2
        r2_max = max((x - cx) ** 2 for x in (0, width - 1)) + max((y - cy) ** 2 for y in (0, height - 1))
        gain = gain * (1.0 - vignetting * r2 / r2_max)
    full = upsample(gain.astype(np.float32), step, width, height)
    gain8 = cv2.cvtColor(np.rint(full * np.float32(255.0)).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    gain8.flags.writeable = False
    return gain8


NOISE_ROWS = 128          # the bank is drawn this many rows at a time: cache-sized, and a stop is heard between
_NOISE_BANKS: dict[tuple[int, int, float], np.ndarray] = {}


class _Abandoned(Exception):
    """A table's building was given up (its process is stopping)."""


def _noise_bank(width: int, height: int, std: float, stopped: Callable[[], bool] = lambda: False) -> np.ndarray:
    """Gaussian noise of `std` grey levels, rounded to whole levels (int16), a little larger than
    a frame; each frame adds a window of it at a random offset (fresh noise per frame costs more
    than the rest of rendering). Drawn in blocks of rows from one generator: the same values as one
    draw of the whole, in a third of the time and without a 12 MP float copy."""
    key = (width, height, std)
    bank = _NOISE_BANKS.get(key)
    if bank is not None:
        return bank
    rng = np.random.default_rng(0)
    rows, cols = height + NOISE_PAD, width + NOISE_PAD
    bank = np.empty((rows, cols, 3), np.int16)
    block = np.empty((NOISE_ROWS, cols, 3), np.float32)
    for r in range(0, rows, NOISE_ROWS):
        if stopped():
            raise _Abandoned("the noise bank")
        x = block[:min(NOISE_ROWS, rows - r)]
        rng.standard_normal(out=x, dtype=np.float32)
        x *= np.float32(std)
        np.rint(x, out=x)
        bank[r:r + len(x)] = x
    bank.flags.writeable = False
    if len(_NOISE_BANKS) >= 2:   # one camera's bank, and a second's: more would hold 70 MB each
        _NOISE_BANKS.pop(next(iter(_NOISE_BANKS)))
    return _NOISE_BANKS.setdefault(key, bank)


def prepare_degrade(model: CameraModel, stopped: Callable[[], bool] = lambda: False) -> None:
    """Build the tables `degrade` will use for this model (see `_noise_bank` for `stopped`)."""
    if model.lighting > 0 or model.vignetting > 0:
        _gain(model.width, model.height, model.lighting, model.lighting_angle_deg, model.vignetting, model.cx, model.cy)
    if model.noise_std > 0:
        try:
            _noise_bank(model.width, model.height, model.noise_std, stopped)
        except _Abandoned:
            return


def motion_kernel(dx: float, dy: float) -> np.ndarray:
    """A normalised line kernel for a smear of (dx, dy) pixels: the segment sampled every
    quarter pixel and splatted bilinearly, so sub-pixel lengths and any angle are exact."""
    length = math.hypot(dx, dy)
    half = math.ceil(length / 2) + 1
    size = 2 * half + 1
    k = np.zeros((size, size), np.float64)
    n = max(2, math.ceil(length * 4) + 1)
    for t in np.linspace(-0.5, 0.5, n):
        x, y = half + t * dx, half + t * dy
        x0, y0 = math.floor(x), math.floor(y)
        fx, fy = x - x0, y - y0
        k[y0, x0] += (1 - fx) * (1 - fy)
        k[y0, x0 + 1] += fx * (1 - fy)
        k[y0 + 1, x0] += (1 - fx) * fy
        k[y0 + 1, x0 + 1] += fx * fy
    return (k / k.sum()).astype(np.float32)


def degrade(image: np.ndarray, model: CameraModel, seed: int | None,
            motion_px: tuple[float, float] = (0.0, 0.0), origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Blur, motion, lighting and vignetting, noise; `image` is the sensor's region whose
    top-left pixel is `origin`, shaded as that part of the whole image is."""
    x0, y0 = origin
    h, w = image.shape[:2]
    moving = math.hypot(*motion_px) >= MIN_MOTION_PX
    shaded = model.lighting > 0 or model.vignetting > 0
    if not (shaded or moving or model.blur_sigma > 0 or model.noise_std > 0):
        return image
    if model.blur_sigma > 0:
        image = cv2.GaussianBlur(image, (0, 0), model.blur_sigma)
    if moving:
        image = cv2.filter2D(image, -1, motion_kernel(*motion_px), borderType=cv2.BORDER_REPLICATE)
    # Gain and noise in saturating uint8 arithmetic: one pass each, no float copy of the frame.
    if shaded:
        gain = _gain(model.width, model.height, model.lighting, model.lighting_angle_deg, model.vignetting,
                     model.cx, model.cy)[y0:y0 + h, x0:x0 + w]
        image = cv2.multiply(image, gain, scale=1 / 255.0)
    if model.noise_std > 0:
        dy, dx = np.random.default_rng(seed).integers(0, NOISE_PAD, size=2)
        window = _noise_bank(model.width, model.height, model.noise_std)[dy + y0:dy + y0 + h, dx + x0:dx + x0 + w]
        image = cv2.add(image, window, dtype=cv2.CV_8U)
    return image
