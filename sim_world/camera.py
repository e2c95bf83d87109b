"""The vehicle's nadir camera: renders what it sees of the warehouse floor.

Frames (shared with `uav_agent.perception`, which re-derives the same geometry
from the published `CameraFrame` fields only):
- local NED, origin at the grid's top-left corner: north = -y, east = +x;
  cell (x, y) spans east [x*c, (x+1)*c] and north [-(y+1)*c, -y*c];
- the camera looks straight down and turns with the vehicle's yaw: at yaw 0
  image "up" points north and image "right" points east;
- pinhole intrinsics fx, fy, cx, cy in OpenCV's pixel-centre convention.

A nadir view of the floor plane is a homography of it, so a frame is rendered
by drawing only the visible cells as a flat texture and warping that texture
into the image with `cv2.warpPerspective`: the cost follows the image size, not
the size of the warehouse.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np

from protocol.errors import MapError, MissionError
from protocol.grid import Cell, on_grid
from protocol.messages import CameraFrame
from scenarios.landmarks import LandmarkSet

# BGR colours. The floor is bright and colourless, shelves dark and brown, goals
# saturated green, the world outside the grid dark blue: each is separable by
# brightness or hue alone, under a lighting gradient too.
FLOOR_BGR = (215, 215, 215)
SHELF_BGR = (45, 60, 80)
OUTSIDE_BGR = (110, 45, 35)
GOAL_BGR = (60, 220, 60)
GOAL_RING_BGR = (25, 70, 25)
MARKER_QUIET_BGR = (255, 255, 255)

ARUCO_DICTIONARY = cv2.aruco.DICT_4X4_1000
MARKER_IDS = 1000          # ids 0..999 exist in DICT_4X4_1000
# A robot cell is 8 units wide: one unit of white quiet zone around a 6-unit
# marker (4x4 data bits + a 1-bit black border), so marker modules stay whole
# texture pixels and neighbouring markers never touch.
CELL_UNITS = 8
MARKER_UNITS = 6
GOAL_RADIUS = 0.38         # of a cell, the green disc
GOAL_RING = 0.07           # of a cell, the dark ring around it
MAX_TEXTURE_PX = 8192


MAX_SIDE_PX = 8192   # 67 MP: beyond any drone camera, and a frame still fits the protocol's PNG limit


@dataclass(frozen=True)
class CameraModel:
    """Pinhole intrinsics plus optional image degradations.

    fx defaults from the horizontal field of view, fy = fx (square pixels),
    (cx, cy) = the image centre. `lighting` is the fraction of brightness lost
    across the image along `lighting_angle_deg` (0 = none); `noise_std` is
    Gaussian sensor noise in grey levels; `blur_sigma` a Gaussian defocus in pixels.
    """
    width: int = 1280
    height: int = 960
    hfov_deg: float = 90.0
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    noise_std: float = 0.0
    blur_sigma: float = 0.0
    lighting: float = 0.0
    lighting_angle_deg: float = 0.0
    landmark_spacing: int = 0   # cells between the surveyed landmarks the world places (0: none)

    def __post_init__(self) -> None:
        if self.width < 16 or self.height < 16:
            raise MissionError(f"camera: image size {self.width}x{self.height} is too small (16x16 at least)")
        if self.width > MAX_SIDE_PX or self.height > MAX_SIDE_PX:
            raise MissionError(f"camera: image size {self.width}x{self.height} is too large "
                               f"({MAX_SIDE_PX} pixels per side at most)")
        if not all(math.isfinite(float(v)) for v in (self.hfov_deg, self.noise_std, self.blur_sigma, self.lighting,
                                                    self.lighting_angle_deg)):
            raise MissionError("camera: every option must be a finite number")
        if self.fx is None and not 1.0 <= self.hfov_deg <= 170.0:
            raise MissionError(f"camera: horizontal field of view {self.hfov_deg} deg is not in [1, 170]")
        fx = self.fx if self.fx is not None else (self.width / 2) / math.tan(math.radians(self.hfov_deg) / 2)
        object.__setattr__(self, "fx", float(fx))
        object.__setattr__(self, "fy", float(self.fy if self.fy is not None else fx))
        object.__setattr__(self, "cx", float(self.cx if self.cx is not None else (self.width - 1) / 2))
        object.__setattr__(self, "cy", float(self.cy if self.cy is not None else (self.height - 1) / 2))
        if not (self.fx > 0 and self.fy > 0):
            raise MissionError(f"camera: focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if self.noise_std < 0 or self.blur_sigma < 0 or not 0.0 <= self.lighting < 1.0:
            raise MissionError("camera: noise_std and blur_sigma must be >= 0 and lighting in [0, 1)")
        if self.landmark_spacing != int(self.landmark_spacing) or not (
                self.landmark_spacing == 0 or 4 <= self.landmark_spacing <= 10_000):
            raise MissionError(f"camera: landmark_spacing {self.landmark_spacing} is not 0 (none) "
                               "or a whole number of cells in [4, 10000]")
        object.__setattr__(self, "landmark_spacing", int(self.landmark_spacing))

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


class CameraPose(NamedTuple):
    north_m: float
    east_m: float
    down_m: float   # negative: above the floor
    yaw_rad: float = 0.0


@dataclass(frozen=True, eq=False)
class Scene:
    """What is physically on the floor: the grid, robots by marker id, goal markers, and the
    surveyed landmarks (on shelf tops and just outside the border; none = today's bare floor)."""
    free: np.ndarray                       # bool [height, width], True = floor
    robots: dict[int, Cell] = field(default_factory=dict)
    goals: list[Cell] = field(default_factory=list)
    landmarks: LandmarkSet | None = None

    def __post_init__(self) -> None:
        free = np.asarray(self.free)
        if free.ndim != 2 or free.size == 0 or free.dtype != bool:
            raise MapError(f"scene: the grid must be a non-empty 2-D bool array, got {free.dtype} {free.shape}")
        h, w = free.shape
        for rid, (x, y) in self.robots.items():
            if not 0 <= rid < MARKER_IDS:
                raise MapError(f"scene: robot id {rid} has no marker (DICT_4X4_1000 holds ids 0..{MARKER_IDS - 1})")
            if not on_grid(x, y, w, h):
                raise MapError(f"scene: robot {rid} at {(x, y)} is off the {w}x{h} grid")
        for x, y in self.goals:
            if not on_grid(x, y, w, h):
                raise MapError(f"scene: goal {(x, y)} is off the {w}x{h} grid")


def floor_homography(pose: CameraPose | tuple, model: CameraModel, cell_size_m: float) -> np.ndarray:
    """3x3 map from floor coordinates in cells (u = east/c, v = -north/c) to image pixels."""
    n, e, d, yaw = (tuple(pose) + (0.0,))[:4]
    if not all(math.isfinite(v) for v in (n, e, d, yaw)):
        raise MissionError(f"camera: pose {tuple(pose)} is not finite")
    if not d < 0:
        raise MissionError(f"camera: pose down={d} m is not above the floor (down must be negative)")
    if not cell_size_m > 0:
        raise MapError(f"cell size must be positive, got {cell_size_m}")
    s, co = math.sin(yaw), math.cos(yaw)
    # Rows: camera x (image right), y (image down), z (optical axis, down) in NED.
    R = np.array([[-s, co, 0.0], [-co, -s, 0.0], [0.0, 0.0, 1.0]])
    floor_to_ned = np.array([[0.0, -cell_size_m, 0.0], [cell_size_m, 0.0, 0.0], [0.0, 0.0, 0.0]])
    M = R @ floor_to_ned
    M[:, 2] -= R @ np.array([n, e, d], dtype=float)
    return model.K @ M


def _texture_ppc(image_ppc: float) -> int:
    """Texture pixels per cell: a multiple of CELL_UNITS, about 1.5x the image's
    resolution so the warp interpolates instead of skipping marker modules."""
    units = max(1, math.ceil(1.5 * image_ppc / CELL_UNITS))
    return CELL_UNITS * min(units, 24)


@lru_cache(maxsize=4096)
def _marker(robot_id: int, module_px: int) -> np.ndarray:
    dictionary = cv2.aruco.getPredefinedDictionary(ARUCO_DICTIONARY)
    img = cv2.aruco.generateImageMarker(dictionary, robot_id, MARKER_UNITS * module_px, borderBits=1)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    img.flags.writeable = False
    return img


@lru_cache(maxsize=8192)
def _landmark_marker(family: str, marker_id: int, side_px: int) -> np.ndarray:
    """A landmark's black square (border included) of exactly `side_px` texels: drawn at a whole
    number of texels per module, then area-resampled, so its size in metres is exact at any scale."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, family))
    bits = dictionary.markerSize + 2
    module = max(1, math.ceil(side_px / bits))
    img = cv2.aruco.generateImageMarker(dictionary, marker_id, bits * module, borderBits=1)
    if img.shape[0] != side_px:
        img = cv2.resize(img, (side_px, side_px), interpolation=cv2.INTER_AREA)
    img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    img.flags.writeable = False
    return img


def _draw_landmarks(tex: np.ndarray, marks: LandmarkSet, cell_size_m: float, x0: int, y0: int, ppc: int) -> None:
    """Each landmark: a white block (its quiet zone) with the black-bordered marker centred in it."""
    if not marks.landmarks:
        return
    centres = marks.centres_cells(cell_size_m)
    half = marks.block_cells / 2
    th, tw = tex.shape[:2]
    block_px = round(marks.block_cells * ppc)
    side_px = max(1, round(marks.size_m / cell_size_m * ppc))
    inset = (block_px - side_px) // 2
    for (lid, _, _), (u, v) in zip(marks.landmarks, centres):
        px, py = round((u - half - x0) * ppc), round((v - half - y0) * ppc)
        if px >= tw or py >= th or px + block_px <= 0 or py + block_px <= 0:
            continue
        block = np.empty((block_px, block_px, 3), np.uint8)
        block[:] = MARKER_QUIET_BGR
        block[inset:inset + side_px, inset:inset + side_px] = _landmark_marker(marks.family, lid, side_px)
        ox, oy = max(0, -px), max(0, -py)
        ex, ey = min(block_px, tw - px), min(block_px, th - py)
        tex[py + oy:py + ey, px + ox:px + ex] = block[oy:ey, ox:ex]


def _texture(scene: Scene, x0: int, y0: int, x1: int, y1: int, ppc: int, cell_size_m: float = 1.0) -> np.ndarray:
    h, w = scene.free.shape
    cells = scene.free[max(0, y0):min(h, y1), max(0, x0):min(w, x1)]
    colours = np.where(cells[..., None], np.uint8(FLOOR_BGR), np.uint8(SHELF_BGR)).astype(np.uint8)
    if x0 < 0 or y0 < 0 or x1 > w or y1 > h:   # the walls around the grid, where the ring of landmarks is
        colours = np.pad(colours, ((max(0, -y0), max(0, y1 - h)), (max(0, -x0), max(0, x1 - w)), (0, 0)),
                         constant_values=0)
        colours[:, :] = np.where(_inside(x0, y0, x1, y1, w, h)[..., None], colours, np.uint8(OUTSIDE_BGR))
    tex = cv2.resize(colours, (colours.shape[1] * ppc, colours.shape[0] * ppc), interpolation=cv2.INTER_NEAREST_EXACT)
    shift = 4  # sub-pixel circle centres
    for gx, gy in scene.goals:
        if x0 <= gx < x1 and y0 <= gy < y1:
            centre = (round(((gx - x0) * ppc + ppc / 2 - 0.5) * 16), round(((gy - y0) * ppc + ppc / 2 - 0.5) * 16))
            cv2.circle(tex, centre, round((GOAL_RADIUS + GOAL_RING / 2) * ppc * 16), GOAL_RING_BGR, -1, cv2.LINE_AA, shift)
            cv2.circle(tex, centre, round((GOAL_RADIUS - GOAL_RING / 2) * ppc * 16), GOAL_BGR, -1, cv2.LINE_AA, shift)
    unit = ppc // CELL_UNITS
    for rid, (rx, ry) in scene.robots.items():
        if x0 <= rx < x1 and y0 <= ry < y1:
            px, py = (rx - x0) * ppc, (ry - y0) * ppc
            tex[py:py + ppc, px:px + ppc] = MARKER_QUIET_BGR
            if unit:
                tex[py + unit:py + (CELL_UNITS - 1) * unit, px + unit:px + (CELL_UNITS - 1) * unit] = _marker(rid, unit)
            else:   # seen from so far that a module is under a texture pixel: a dark blob is all there is
                tex[py + ppc // 4:py + ppc - ppc // 4, px + ppc // 4:px + ppc - ppc // 4] = 0
    if scene.landmarks is not None:
        _draw_landmarks(tex, scene.landmarks, cell_size_m, x0, y0, ppc)
    return tex


def _inside(x0: int, y0: int, x1: int, y1: int, w: int, h: int) -> np.ndarray:
    xs, ys = np.arange(x0, x1), np.arange(y0, y1)
    return ((xs >= 0) & (xs < w))[None, :] & ((ys >= 0) & (ys < h))[:, None]


@lru_cache(maxsize=8)
def _lighting(width: int, height: int, lighting: float, angle_deg: float) -> np.ndarray:
    """Brightness factor per pixel: 1 on one side of the image, 1 - lighting on the other."""
    a = math.radians(angle_deg)
    xs = np.arange(width, dtype=np.float32) - width / 2
    ys = np.arange(height, dtype=np.float32) - height / 2
    ramp = math.cos(a) * xs[None, :] + math.sin(a) * ys[:, None]
    span = float(ramp.max() - ramp.min()) or 1.0
    gain = (1.0 - lighting * (ramp - ramp.min()) / span).astype(np.float32)
    gain = np.ascontiguousarray(np.repeat(gain[..., None], 3, axis=2))
    gain.flags.writeable = False
    return gain


NOISE_PAD = 64


@lru_cache(maxsize=2)
def _noise_bank(width: int, height: int) -> np.ndarray:
    """Unit Gaussian noise a little larger than a frame; each frame adds a window of it
    at a random offset (fresh noise per frame costs more than the rest of rendering)."""
    noise = np.random.default_rng(0).standard_normal((height + NOISE_PAD, width + NOISE_PAD, 3), dtype=np.float32)
    noise.flags.writeable = False
    return noise


def _degrade(image: np.ndarray, model: CameraModel, seed: int | None) -> np.ndarray:
    if model.lighting == 0 and model.blur_sigma == 0 and model.noise_std == 0:
        return image
    if model.blur_sigma > 0:
        # Blur before the lighting gain: the gain is a smooth ramp, so the two commute.
        image = cv2.GaussianBlur(image, (0, 0), model.blur_sigma)
    out = image.astype(np.float32)
    if model.lighting > 0:
        out *= _lighting(model.width, model.height, model.lighting, model.lighting_angle_deg)
    if model.noise_std > 0:
        dy, dx = np.random.default_rng(seed).integers(0, NOISE_PAD, size=2)
        window = _noise_bank(model.width, model.height)[dy:dy + model.height, dx:dx + model.width]
        out += model.noise_std * window
    return np.clip(out, 0, 255, out=out).astype(np.uint8)


def render(scene: Scene, pose: CameraPose | tuple, model: CameraModel, cell_size_m: float,
           seed: int | None = None) -> np.ndarray:
    """The BGR uint8 image the camera sees from `pose` (north, east, down, yaw)."""
    H = floor_homography(pose, model, cell_size_m)
    h, w = scene.free.shape
    corners = np.array([[[0, 0]], [[model.width - 1, 0]], [[0, model.height - 1]],
                        [[model.width - 1, model.height - 1]]], dtype=np.float64)
    floor = cv2.perspectiveTransform(corners, np.linalg.inv(H)).reshape(-1, 2)
    # Landmarks in the ring lie up to one block outside the grid: the texture covers them too.
    pad = scene.landmarks.block_cells if scene.landmarks is not None and scene.landmarks.landmarks else 0
    x0 = max(-pad, math.floor(floor[:, 0].min()) - 1)
    y0 = max(-pad, math.floor(floor[:, 1].min()) - 1)
    x1 = min(w + pad, math.ceil(floor[:, 0].max()) + 1)
    y1 = min(h + pad, math.ceil(floor[:, 1].max()) + 1)
    if x0 >= x1 or y0 >= y1:
        outside = np.empty((model.height, model.width, 3), np.uint8)
        outside[:] = OUTSIDE_BGR
        return _degrade(outside, model, seed)
    image_ppc = min(model.fx, model.fy) * cell_size_m / -pose[2]
    # A view of a huge floor from very high: keep the texture within OpenCV's comfort.
    ppc = max(1, min(_texture_ppc(image_ppc), MAX_TEXTURE_PX // max(x1 - x0, y1 - y0)))
    tex = _texture(scene, x0, y0, x1, y1, ppc, cell_size_m)
    # Texture pixel centre (i, j) is floor point (x0 + (i + 0.5)/ppc, y0 + (j + 0.5)/ppc) cells.
    tex_to_floor = np.array([[1 / ppc, 0, x0 + 0.5 / ppc], [0, 1 / ppc, y0 + 0.5 / ppc], [0, 0, 1]])
    image = cv2.warpPerspective(tex, H @ tex_to_floor, (model.width, model.height), flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=OUTSIDE_BGR)
    return _degrade(image, model, seed)


def camera_frame(pose: CameraPose | tuple, model: CameraModel, time_s: float, png: bytes = b"",
                 seq: int = 0) -> CameraFrame:
    """The CameraFrame message for a pose and intrinsics, carrying `png` as its image."""
    n, e, d, yaw = (tuple(pose) + (0.0,))[:4]
    return CameraFrame(width=model.width, height=model.height, fx=model.fx, fy=model.fy, cx=model.cx,
                       cy=model.cy, north_m=float(n), east_m=float(e), down_m=float(d), yaw_rad=float(yaw),
                       time_s=float(time_s), png=png, seq=seq)


def encode_frame(image: np.ndarray, pose: CameraPose | tuple, model: CameraModel, time_s: float,
                 seq: int = 0) -> CameraFrame:
    """Image + pose + intrinsics -> the CameraFrame message (lossless PNG)."""
    if image.shape[:2] != (model.height, model.width):
        raise MissionError(f"camera: image is {image.shape[1]}x{image.shape[0]}, model says {model.width}x{model.height}")
    ok, png = cv2.imencode(".png", image, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:  # pragma: no cover - OpenCV refuses only malformed arrays
        raise MissionError("camera: PNG encoding failed")
    return camera_frame(pose, model, time_s, png.tobytes(), seq)


def cell_centre_ned(cell: Cell, cell_size_m: float) -> tuple[float, float]:
    """(north, east) of a cell's centre: where to hover to look straight at it."""
    x, y = cell
    return -(y + 0.5) * cell_size_m, (x + 0.5) * cell_size_m
