"""The part of the sensor an image needs: a region of interest around a few floor cells.

An arrival image confirms a handful of robots on their goals; reading the whole
12 MP frame for them costs the world ~0.45 s of CPU to render and the UAV ~0.75 s
to perceive, on the same two cores that run the fleet's ticks. A machine-vision
camera reads out a region of its sensor alone (`CameraRequest.roi_*`), so the
image is asked for only around those cells: grown on the floor until it holds
enough surveyed landmarks to be registered by, projected through the published
calibration (lens distortion included) from the pose the vehicle holds, and
widened by what a tilt within the shutter's tolerance and the hover's tolerance
may swing out of view.
"""
from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import cv2
import numpy as np

from protocol.grid import Cell
from protocol.messages import CameraFrame

from .perception.frames import distortion, intrinsics
from .perception.registration import Landmarks, homography

MIN_LANDMARKS = 4        # in a region: one leaves yaw and scale loose, a few pin them
# ... spread at least this share of the altitude east-west and north-south: a narrow strip of
# landmarks cannot tell a sideways shift from a roll (a strip 47 m wide from 105 m placed a wall
# robot a cell off; 63 m did not; landmarks 31 m apart, 52 m apart do).
MIN_SPREAD_OF_ALT = 0.5
FULL_SHARE = 0.5         # a region over this share of the sensor: the whole image is as cheap


class Region(NamedTuple):
    x: int
    y: int
    width: int
    height: int


def region_for(cells: list[Cell], camera: CameraFrame, pose: tuple[float, float, float], cell_size_m: float,
               landmarks: Landmarks | None, margin_px: int, grid: tuple[int, int]) -> Region | None:
    """The sensor region (pixels) that shows `cells` (x, y) from a level camera at `pose` (north,
    east, altitude; yaw 0), grown until it holds MIN_LANDMARKS landmark centres (or the floor),
    plus `margin_px` each way; None when no region would be much cheaper than the whole image."""
    if not cells:
        return None
    north, east, alt = pose
    level = dataclasses.replace(camera, north_m=north, east_m=east, down_m=-alt, yaw_rad=0.0, roll_rad=0.0,
                                pitch_rad=0.0)
    H = homography(level, cell_size_m)
    K, dist = intrinsics(camera), np.array(distortion(camera))

    def on_sensor(uv: np.ndarray) -> np.ndarray:
        """Floor cells (u, v) -> where the sensor records them (the lens's distortion included)."""
        pinhole = cv2.perspectiveTransform(np.asarray(uv, np.float64).reshape(-1, 1, 2), H).reshape(-1, 2)
        rays = np.column_stack([(pinhole[:, 0] - K[0, 2]) / K[0, 0], (pinhole[:, 1] - K[1, 2]) / K[1, 1],
                                np.ones(len(pinhole))])
        return cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)[0].reshape(-1, 2)

    xs, ys = [c[0] for c in cells], [c[1] for c in cells]
    box = [min(xs) - 1, min(ys) - 1, max(xs) + 2, max(ys) + 2]       # cells, with a neighbour each way
    if landmarks is not None:
        _, centres = landmarks.table
        u, v = centres[:, 0] / cell_size_m, -centres[:, 1] / cell_size_m
        # Only landmarks the sensor holds whole, with the margin, can register the region.
        side = landmarks.size_m / cell_size_m * min(K[0, 0], K[1, 1]) * cell_size_m / max(alt, 1e-6)
        edge = margin_px + side
        px = on_sensor(np.column_stack([u, v]))
        seen = ((px[:, 0] >= edge) & (px[:, 0] < camera.width - edge) & (px[:, 1] >= edge)
                & (px[:, 1] < camera.height - edge))
        width, height = grid
        spread = MIN_SPREAD_OF_ALT * alt / cell_size_m
        while True:
            inside = seen & (u > box[0] + 1) & (u < box[2] - 1) & (v > box[1] + 1) & (v < box[3] - 1)
            few = inside.sum() < MIN_LANDMARKS
            # Spread both ways: landmarks in one line (the ring along a wall) leave the fit loose across it.
            wide = not few and np.ptp(u[inside]) >= spread
            tall = not few and np.ptp(v[inside]) >= spread
            if wide and tall:
                break
            dx = 0 if wide or (box[0] <= -2 and box[2] >= width + 2) else 2
            dy = 0 if tall or (box[1] <= -2 and box[3] >= height + 2) else 2
            if dx == dy == 0:
                return None   # too few landmarks in view for a region: the whole image
            box = [box[0] - dx, box[1] - dy, box[2] + dx, box[3] + dy]
    corners = np.array([[box[0], box[1]], [box[2], box[1]], [box[0], box[3]], [box[2], box[3]],
                        [(box[0] + box[2]) / 2, box[1]], [(box[0] + box[2]) / 2, box[3]],
                        [box[0], (box[1] + box[3]) / 2], [box[2], (box[1] + box[3]) / 2]], np.float64)
    sensor = on_sensor(corners)
    if not np.all(np.isfinite(sensor)):
        return None
    x0 = max(0, math.floor(sensor[:, 0].min()) - margin_px)
    y0 = max(0, math.floor(sensor[:, 1].min()) - margin_px)
    x1 = min(camera.width, math.ceil(sensor[:, 0].max()) + margin_px + 1)
    y1 = min(camera.height, math.ceil(sensor[:, 1].max()) + margin_px + 1)
    if x1 <= x0 or y1 <= y0 or (x1 - x0) * (y1 - y0) > FULL_SHARE * camera.width * camera.height:
        return None
    return Region(x0, y0, x1 - x0, y1 - y0)
