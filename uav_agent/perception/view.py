"""One frame prepared for reading: undistorted, registered, in grey."""
from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from .frames import Frame
from .registration import Registration


@dataclass(eq=False)
class View:
    frame: Frame
    image: np.ndarray             # BGR, undistorted
    gray: np.ndarray
    valid: np.ndarray | None      # pixels that came from the sensor (None: all)
    reg: Registration
    H: np.ndarray                 # floor cells -> pixels
    H_inv: np.ndarray
    ppc: float                    # pixels per cell side at the image centre
    sharpness: float              # 0..1: how much of a sharp image's fine detail survives


def to_floor(points_px, H_inv: np.ndarray) -> np.ndarray:
    return cv2.perspectiveTransform(np.asarray(points_px, np.float64).reshape(-1, 1, 2), H_inv).reshape(-1, 2)


def to_image(points_uv, H: np.ndarray) -> np.ndarray:
    return cv2.perspectiveTransform(np.asarray(points_uv, np.float64).reshape(-1, 1, 2), H).reshape(-1, 2)


def px_per_cell(H: np.ndarray, gray_shape: tuple[int, ...]) -> float:
    """Image pixels per cell side around the image centre (the local scale of H there)."""
    h, w = gray_shape[:2]
    H_inv = np.linalg.inv(H)
    centre = to_floor([[w / 2, h / 2]], H_inv)[0]
    pts = to_image([centre, centre + [1, 0], centre + [0, 1]], H)
    a, b = pts[1] - pts[0], pts[2] - pts[0]
    return float(math.sqrt(abs(a[0] * b[1] - a[1] * b[0])))


def sharpness(gray: np.ndarray, ppc: float) -> float:
    """Edge energy of the image against what a sharp floor of this scale shows.

    The ratio of the mean gradient at full resolution to the mean gradient of a
    2x-downsampled copy (upsampled back) drops as blur removes the finest detail;
    it needs no reference image, and lighting cancels in the ratio. Measured on the image's
    central quarter (a quarter of the cost): blur, noise and compression are the same all over
    a frame, and the centre is where its heaviest votes are."""
    h, w = gray.shape[:2]
    gray = gray[h // 4:h // 4 + max(8, h // 2), w // 4:w // 4 + max(8, w // 2)]
    small = cv2.resize(gray, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
    coarse = cv2.resize(small, (gray.shape[1], gray.shape[0]), interpolation=cv2.INTER_LINEAR)
    fine = _mean_abs_laplacian(gray)
    smooth = _mean_abs_laplacian(coarse)
    if fine <= 0:
        return 0.0
    return float(np.clip((fine - smooth) / fine * 2.0, 0.05, 1.0))


def _mean_abs_laplacian(gray: np.ndarray) -> float:
    # A 3x3 Laplacian of 8-bit pixels stays within +-1020, so 16-bit integers hold it exactly,
    # and the L1 norm sums it in double: a third of the memory traffic of a float image.
    return cv2.norm(cv2.Laplacian(gray, cv2.CV_16S), cv2.NORM_L1) / gray.size
