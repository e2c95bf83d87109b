"""Smooth per-pixel fields (the lens's distortion map, the lighting and vignetting gain)
computed on a sparse grid and interpolated: at 12 MP, computing them at every pixel is
most of the CPU a camera spends before its first image."""
from __future__ import annotations

import cv2
import numpy as np


def upsample(sparse: np.ndarray, step: int, width: int, height: int) -> np.ndarray:
    """A smooth field sampled every `step` pixels (sample (i, j) at pixel (j * step, i * step)),
    interpolated bilinearly at every pixel of a width x height image: an affine warp, which
    computes the same values as remapping with the pixel grid / step without building that grid
    (two 12 MP float planes: about half the CPU before a 12 MP camera's first image)."""
    scale = np.array([[1.0 / step, 0.0, 0.0], [0.0, 1.0 / step, 0.0]])
    return cv2.warpAffine(sparse, scale, (width, height), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)
