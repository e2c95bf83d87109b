"""How blurred an image is, in pixels of Gaussian sigma, from its own edges.

Re-blur estimator: a step edge blurred by sigma and blurred again by a known
sigma_r has its peak gradient lowered by sqrt(sigma^2 + sigma_r^2) / sigma; the
ratio measured at the image's strongest edges gives sigma. It needs no
reference image and cancels the edge's contrast, hence the lighting."""
from __future__ import annotations

import math

import cv2
import numpy as np

REBLUR_SIGMA = 2.0
EDGE_SHARE = 0.005     # the strongest half percent of gradient maxima are the edges measured
EDGE_QUANTILE = 0.75


def blur_sigma(gray: np.ndarray) -> float:
    """Estimated Gaussian blur of `gray` in pixels (about 0.5 for a sharp rendered image)."""
    g = gray.astype(np.float32)
    # Denoise a little first (and count it out at the end): noise would fake sharpness.
    pre = 0.7
    g = cv2.GaussianBlur(g, (0, 0), pre)
    r = cv2.GaussianBlur(g, (0, 0), REBLUR_SIGMA)

    def grad(a: np.ndarray) -> np.ndarray:
        return cv2.magnitude(cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3))

    g1, g2 = grad(g), grad(r)
    # Local maxima of the gradient: the centres of edges.
    peak = (g1 >= cv2.dilate(g1, np.ones((3, 3), np.uint8))) & (g1 > 0)
    values = g1[peak]
    if values.size < 20:
        return 0.0
    cut = np.quantile(values, 1.0 - EDGE_SHARE) if values.size > 2000 else np.quantile(values, 0.9)
    sel = peak & (g1 >= cut)
    ratio = np.maximum(g1[sel] / np.maximum(g2[sel], 1e-6), 1.0 + 1e-6)
    # Per edge; neighbouring edges (marker modules) lower a blurred edge's estimate, so the
    # upper quartile, from the isolated edges, is the camera's blur.
    total = float(np.quantile(REBLUR_SIGMA / np.sqrt(ratio * ratio - 1.0), EDGE_QUANTILE))
    return float(math.sqrt(max(total * total - pre * pre, 0.0)))
